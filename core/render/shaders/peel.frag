#version 330
// One pass of depth peeling: the nearest surface behind the previous layer at each pixel.  Back
// faces are kept (no culling), alpha-cut texels are not surfaces (glTF's MASK rule on the base
// colour's alpha: factor x vertex alpha x texture alpha).  Writes (window depth, eye depth,
// object index, primitive index + 1); the depth test keeps the nearest.
uniform sampler2D previous;   // RGBA32F hits of the previous layer; r = window depth (-1: first pass, 2: ray done)
uniform sampler2D base_texture;
uniform bool has_texture;
uniform vec4 base_color;
uniform float alpha_cutoff;   // < 0: opaque
uniform float object_index;
in vec2 v_uv;
in float v_alpha;
out vec4 hit;

void main() {
    float before = texelFetch(previous, ivec2(gl_FragCoord.xy), 0).r;
    if (gl_FragCoord.z <= before) { discard; }
    if (alpha_cutoff >= 0.0) {
        float a = base_color.a * v_alpha;
        if (has_texture) { a *= texture(base_texture, v_uv).a; }
        if (a < alpha_cutoff) { discard; }
    }
    hit = vec4(gl_FragCoord.z, 1.0 / gl_FragCoord.w, object_index, float(gl_PrimitiveID) + 1.0);
}
