#version 330
// Unlit base colour: base_color x vertex colour x texture (glTF's rule) in linear light, alpha-
// masked, written sRGB-encoded (core/colour_space.py).  The texture is an sRGB texture (decoded by
// the GL before filtering); vertex colours arrive sRGB-encoded (mesh.vert decodes them).
//
// Built twice (core/render/raster.py): with DISCARDS for what may discard fragments (an alpha cut,
// or a clip cube with open faces, which is no convex region the GL's clip planes could cut), and
// without for everything else.  A shader with no discard lets the GL test and write depth before
// shading (on llvmpipe a discard anywhere in the shader moves the depth write after it), so
// geometry drawn front to back is shaded about once per pixel.
uniform sampler2D base_texture;
uniform bool has_texture;
uniform vec4 base_color;
#ifdef DISCARDS
uniform float alpha_cutoff;  // < 0: opaque
uniform float clip_half;     // > 0: discard outside the cube of this half side around the clip centre,
uniform vec3 clip_open_pos;  // except (1) beyond the cube in the face pyramids +x, +y, +z
uniform vec3 clip_open_neg;  // and -x, -y, -z that are drawn as geometry there
#endif
in vec2 v_uv;
in vec4 v_color;
in vec3 v_clip;
out vec4 frag_color;

#include "colour.glsl"

void main() {
#ifdef DISCARDS
    vec3 a = abs(v_clip);
    float norm = max(max(a.x, a.y), a.z);
    if (clip_half > 0.0 && norm > clip_half) {
        // The face pyramid the fragment lies in: its largest coordinate and that one's sign.
        vec3 open = mix(clip_open_neg, clip_open_pos, step(0.0, v_clip));
        float here = a.x >= a.y && a.x >= a.z ? open.x : (a.y >= a.z ? open.y : open.z);
        if (here < 0.5) { discard; }
    }
#endif
    vec4 c = base_color * v_color;
    if (has_texture) { c *= texture(base_texture, v_uv); }
#ifdef DISCARDS
    if (alpha_cutoff >= 0.0 && c.a < alpha_cutoff) { discard; }
#endif
    frag_color = vec4(linear_to_srgb(c.rgb), 1.0);
}
