#version 330
// Standard perspective rasterisation of object-local positions: eye_from_local is built in float64
// on the CPU (camera-relative), so large world offsets cancel before the float32 narrowing.
//
// Built in variants (core/render/raster.py): VERTEX_COLOURS passes the object's vertex colours,
// TEXTURED its texture coordinates, CLIP_PLANES writes the six clip distances of a closed clip
// cube (the GL cuts there), OPEN_FACES passes the position in the clip cube's frame for
// mesh.frag's discard.  What an object lacks is neither computed per vertex nor interpolated.
// NORMALS (a G-buffer render, core/render/raster.py) passes the eye-frame position, and
// VERTEX_NORMALS the object's shading normals, for mesh.frag's normal output.  MATERIAL_UV (a
// material G-buffer of an object with material textures) passes the material textures' uv.
uniform mat4 eye_from_local;  // eye frame: x right, y up, z forward (depth)
uniform vec2 half_tan;
uniform vec2 depth_range;     // near, far eye depth
#if defined(CLIP_PLANES) || defined(OPEN_FACES)
uniform vec3 clip_offset;     // object origin minus the clip cube's centre (float64-built)
#endif
#ifdef CLIP_PLANES
uniform float plane_half;     // the GL's six clip planes cut the geometry to the cube of this
                              // half side around the clip centre (raster.py enables them)
out float gl_ClipDistance[6];
#endif
in vec3 in_position;
#ifdef TEXTURED
in vec2 in_uv;
out vec2 v_uv;
#endif
#ifdef VERTEX_COLOURS
in vec4 in_color;
out vec4 v_color;
#endif
#ifdef OPEN_FACES
out vec3 v_clip;              // position relative to the clip cube's centre
#endif
#ifdef NORMALS
out vec3 v_eye;               // eye-frame position, for the flat normal where there is no other
#endif
#ifdef VERTEX_NORMALS
in vec3 in_normal;            // world shading normal (the local frame is the world's, translated)
out vec3 v_normal;
#endif
#ifdef TANGENT_NORMAL_MAP
in vec2 in_normal_uv;         // the normal map's uv
in vec4 in_tangent;           // world tangent and handedness
out vec2 v_normal_uv;
out vec4 v_tangent;
#endif
#ifdef MATERIAL_UV
in vec2 in_material_uv;       // the uv the metallic-roughness, occlusion and emissive textures share
out vec2 v_material_uv;
#endif

#include "colour.glsl"

void main() {
    vec3 e = (eye_from_local * vec4(in_position, 1.0)).xyz;
    float n = depth_range.x, f = depth_range.y;
    gl_Position = vec4(e.x / half_tan.x, e.y / half_tan.y, (f + n) / (f - n) * e.z - 2.0 * f * n / (f - n), e.z);
#ifdef NORMALS
    v_eye = e;
#endif
#ifdef VERTEX_NORMALS
    v_normal = in_normal;
#endif
#ifdef TANGENT_NORMAL_MAP
    v_normal_uv = in_normal_uv;
    v_tangent = in_tangent;
#endif
#ifdef TEXTURED
    v_uv = in_uv;
#endif
#ifdef MATERIAL_UV
    v_material_uv = in_material_uv;
#endif
#ifdef VERTEX_COLOURS
    v_color = vec4(srgb_to_linear(in_color.rgb), in_color.a);  // interpolated in linear light
#endif
#if defined(CLIP_PLANES) || defined(OPEN_FACES)
    vec3 clip = in_position + clip_offset;
#endif
#ifdef OPEN_FACES
    v_clip = clip;
#endif
#ifdef CLIP_PLANES
    // Inside the cube every distance is >= 0; the GL cuts each triangle where one turns negative.
    gl_ClipDistance[0] = plane_half - clip.x;
    gl_ClipDistance[1] = plane_half + clip.x;
    gl_ClipDistance[2] = plane_half - clip.y;
    gl_ClipDistance[3] = plane_half + clip.y;
    gl_ClipDistance[4] = plane_half - clip.z;
    gl_ClipDistance[5] = plane_half + clip.z;
#endif
}
