#version 330
// Unlit base colour: base_color x vertex colour x texture (glTF's rule) in linear light, alpha-
// masked, written sRGB-encoded (core/colour_space.py).  The texture is an sRGB texture (decoded by
// the GL before filtering); vertex colours arrive sRGB-encoded (mesh.vert decodes them).
//
// Built in variants (core/render/raster.py; the defines are mesh.vert's): ALPHA_CUT for an alpha
// cut and OPEN_FACES for a clip cube with open faces (no convex region the GL's clip planes could
// cut) may discard fragments; everything else never does.  A shader with no discard lets the GL
// test and write depth before shading (on llvmpipe a discard anywhere in the shader moves the
// depth write after it), so geometry drawn front to back is shaded about once per pixel.
#ifdef TEXTURED
uniform sampler2D base_texture;
in vec2 v_uv;
#endif
#ifdef VERTEX_COLOURS
in vec4 v_color;
#endif
uniform vec4 base_color;
#ifdef ALPHA_CUT
uniform float alpha_cutoff;
#endif
#ifdef OPEN_FACES
uniform float clip_half;     // discard outside the cube of this half side around the clip centre,
uniform vec3 clip_open_pos;  // except (1) beyond the cube in the face pyramids +x, +y, +z
uniform vec3 clip_open_neg;  // and -x, -y, -z that are drawn as geometry there
in vec3 v_clip;
#endif
out vec4 frag_color;

#include "colour.glsl"

void main() {
#ifdef OPEN_FACES
    vec3 a = abs(v_clip);
    float norm = max(max(a.x, a.y), a.z);
    if (norm > clip_half) {
        // The face pyramid the fragment lies in: its largest coordinate and that one's sign.
        vec3 open = mix(clip_open_neg, clip_open_pos, step(0.0, v_clip));
        float here = a.x >= a.y && a.x >= a.z ? open.x : (a.y >= a.z ? open.y : open.z);
        if (here < 0.5) { discard; }
    }
#endif
    vec4 c = base_color;
#ifdef VERTEX_COLOURS
    c *= v_color;
#endif
#ifdef TEXTURED
    c *= texture(base_texture, v_uv);
#endif
#ifdef ALPHA_CUT
    if (c.a < alpha_cutoff) { discard; }
#endif
    frag_color = vec4(linear_to_srgb(c.rgb), 1.0);
}
