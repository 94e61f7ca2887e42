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
layout(location = 0) out vec4 frag_color;
#ifdef NORMALS
// The G-buffer's second target (float): the world shading normal of the pixel, on the viewer's
// side where the surface is seen from its back (glTF: a double-sided material's back faces have
// their normals reversed).  From NORMAL_MAP, a world-space normal texture (an impostor's normal
// pages, encoded n * 0.5 + 0.5), else the interpolated VERTEX_NORMALS (perturbed by the object's
// TANGENT_NORMAL_MAP where it has one: glTF's normalTexture, mipmapped, with the vertex tangents),
// else the flat normal of the triangle (glTF's rule where NORMAL is missing).
uniform mat4 eye_from_local;
in vec3 v_eye;
layout(location = 1) out vec4 frag_normal;
#ifdef WORLD_NORMAL_MAP
uniform sampler2D normal_texture;
#endif
#ifdef VERTEX_NORMALS
in vec3 v_normal;
#endif
#ifdef TANGENT_NORMAL_MAP
uniform sampler2D tangent_normal_map;
uniform float normal_scale;
in vec2 v_normal_uv;
in vec4 v_tangent;
#endif
#endif
#ifdef MATERIAL
// The material G-buffer's targets (float): (occlusion, roughness, metallic, 1) and (linear
// emission, 1) of the pixel, glTF's metallic-roughness material: the factors times the
// METALLIC_ROUGHNESS_MAP's G and B, 1 + strength (OCCLUSION_MAP's R - 1), the factor times the
// EMISSIVE_MAP (an sRGB texture, decoded by the GL), each over the material uv, mipmapped.
uniform float metallic_factor;
uniform float roughness_factor;
uniform float occlusion_strength;
uniform vec3 emissive_factor;
layout(location = 2) out vec4 frag_material;
layout(location = 3) out vec4 frag_emissive;
#ifdef MATERIAL_UV
in vec2 v_material_uv;
#endif
#ifdef METALLIC_ROUGHNESS_MAP
uniform sampler2D metallic_roughness_map;
#endif
#ifdef OCCLUSION_MAP
uniform sampler2D occlusion_map;
#endif
#ifdef EMISSIVE_MAP
uniform sampler2D emissive_map;
#endif
#endif

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
#ifdef NORMALS
    mat3 world_from_eye = transpose(mat3(eye_from_local));  // a rotation
    vec3 flat_eye = cross(dFdx(v_eye), dFdy(v_eye));
    flat_eye *= dot(flat_eye, v_eye) > 0.0 ? -1.0 : 1.0;  // towards the eye (at the eye frame's origin)
    vec3 n = world_from_eye * flat_eye;
#if defined(WORLD_NORMAL_MAP)
    n = texture(normal_texture, v_uv).rgb * 2.0 - 1.0;
#elif defined(VERTEX_NORMALS)
    n = normalize(v_normal);
#ifdef TANGENT_NORMAL_MAP
    {
        vec3 t = v_tangent.xyz - n * dot(n, v_tangent.xyz);
        if (dot(t, t) > 1e-24) {
            t = normalize(t);
            vec3 m = texture(tangent_normal_map, v_normal_uv).rgb * 2.0 - 1.0;
            m.xy *= normal_scale;
            vec3 mapped = t * m.x + cross(n, t) * (v_tangent.w < 0.0 ? -1.0 : 1.0) * m.y + n * m.z;
            if (dot(mapped, mapped) > 1e-24) { n = mapped; }
        }
    }
#endif
    n = gl_FrontFacing ? n : -n;
#endif
    float len = length(n);
    frag_normal = vec4(len > 0.0 ? n / len : vec3(0.0), 1.0);
#endif
#ifdef MATERIAL
    float occlusion = 1.0, roughness = roughness_factor, metallic = metallic_factor;
    vec3 emission = emissive_factor;
#ifdef METALLIC_ROUGHNESS_MAP
    vec4 mr = texture(metallic_roughness_map, v_material_uv);
    roughness *= mr.g;
    metallic *= mr.b;
#endif
#ifdef OCCLUSION_MAP
    occlusion = 1.0 + occlusion_strength * (texture(occlusion_map, v_material_uv).r - 1.0);
#endif
#ifdef EMISSIVE_MAP
    emission *= texture(emissive_map, v_material_uv).rgb;
#endif
    frag_material = vec4(occlusion, roughness, metallic, 1.0);
    frag_emissive = vec4(emission, 1.0);
#endif
}
