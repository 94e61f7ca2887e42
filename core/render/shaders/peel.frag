#version 330
// One pass of depth peeling: the nearest surface behind the previous layer at each pixel.  Back
// faces are kept (no culling), alpha-cut texels are not surfaces (glTF's MASK rule on the base
// colour's alpha: factor x vertex alpha x texture alpha; peel_touch.frag samples the rest of the
// pixel where the centre's texel is cut).  Writes (window depth, eye depth,
// object index, primitive index + 1) and the surface's colour there as mesh.frag shades it; the
// depth test keeps the nearest.
uniform sampler2D previous;   // RGBA32F hits of the previous layer; r = window depth (-1: first pass, 2: ray done)
uniform sampler2D base_texture;
uniform bool has_texture;
uniform vec4 base_color;
uniform float alpha_cutoff;   // < 0: opaque
uniform float object_index;
in vec2 v_uv;
in vec4 v_color;
layout(location = 0) out vec4 hit;
layout(location = 1) out vec4 colour;

#include "colour.glsl"

void main() {
    float before = texelFetch(previous, ivec2(gl_FragCoord.xy), 0).r;
    if (gl_FragCoord.z <= before) { discard; }
    vec4 c = base_color * v_color;
    if (has_texture) { c *= texture(base_texture, v_uv); }
    if (alpha_cutoff >= 0.0 && c.a < alpha_cutoff) { discard; }
    hit = vec4(gl_FragCoord.z, 1.0 / gl_FragCoord.w, object_index, float(gl_PrimitiveID) + 1.0);
    colour = vec4(linear_to_srgb(c.rgb), 1.0);
}
