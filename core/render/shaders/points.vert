#version 330
// Points of a point-based impostor (core/render/points.py, seed 001 §5.3), positions relative to
// the point set's centre; colours sRGB-encoded as the mesh shader writes them.
//
// Each point is snapped to the centre of the grid cell (a pixel of the image the impostor was
// baked for) its projection falls in and drawn as a square of grid_step / pixel tangents: one
// pixel when the grid is the camera's own pixels (plain one-pixel points), a block of pixels when
// the camera's pixels subdivide the grid's (the evaluation's supersampled views and windows).
uniform mat4 eye_from_local;
uniform vec2 half_tan;
uniform vec2 depth_range;
uniform vec2 grid_origin;    // a grid corner, in the (sheared) eye-frame tangents of this camera
uniform float grid_step;     // the grid's pixel, tangents
uniform float point_size;    // grid_step in this camera's pixels
in vec3 in_position;
in vec4 in_color;
flat out vec4 v_color;
flat out int v_id;
#ifdef NORMALS
// A G-buffer render (core/render/points.py): each point's world normal (POINT_NORMALS), else the
// normal of a sprite facing the viewer (facing: minus the camera's forward axis, world).
flat out vec3 v_normal;
#ifdef POINT_NORMALS
in vec3 in_normal;
#else
uniform vec3 facing;
#endif
#endif

#ifdef APPEARANCE
// §5.3: "the texture coordinates of a point are calculated as the intersection of a viewing ray to
// the point with the sampling plane"; bilinear inside the point's tile of the page.
uniform vec3 eye_local;      // the camera's eye, relative to the point set's centre
uniform vec4 plane;          // normal (xyz), offset (w): the sampling plane, local coordinates
uniform vec4 rect_u;         // xyz / w: the rectangle's coordinate along u is dot(s, xyz) + w
uniform vec4 rect_v;
uniform vec2 tile;           // texels of a tile along u and v
uniform vec2 page_size;
uniform sampler2D page;        // sRGB texels, sampled (and filtered) as linear light
in vec2 in_tile;             // the tile's first texel in the page; x < 0: one colour (in_color)
#include "colour.glsl"
#endif

#ifdef MATERIAL
// A material G-buffer (core/render/points.py): each point's occlusion, roughness, metallic and
// linear emission, decoded on the CPU from its ORM and sRGB emission bytes.
in vec3 in_material;
in vec3 in_emissive;
flat out vec3 v_material;
flat out vec3 v_emissive;
#endif

void main() {
    vec3 e = (eye_from_local * vec4(in_position, 1.0)).xyz;
    float n = depth_range.x, f = depth_range.y;
    vec2 t = e.xy / e.z;
    vec2 snapped = grid_origin + (floor((t - grid_origin) / grid_step) + 0.5) * grid_step;
    gl_Position = vec4(snapped.x / half_tan.x * e.z, snapped.y / half_tan.y * e.z, (f + n) / (f - n) * e.z - 2.0 * f * n / (f - n), e.z);
    gl_PointSize = point_size;
    v_id = gl_VertexID;
    v_color = in_color;
#ifdef NORMALS
#ifdef POINT_NORMALS
    v_normal = in_normal;
#else
    v_normal = facing;
#endif
#endif
#ifdef APPEARANCE
    if (in_tile.x >= 0.0) {
        vec3 d = in_position - eye_local;
        vec3 s = eye_local + (plane.w - dot(plane.xyz, eye_local)) / dot(plane.xyz, d) * d;
        vec2 a = vec2(dot(s, rect_u.xyz) + rect_u.w, dot(s, rect_v.xyz) + rect_v.w);
        vec2 texel = in_tile + clamp(a * tile, vec2(0.5), tile - 0.5);
        vec4 c = textureLod(page, texel / page_size, 0.0);
        v_color = vec4(linear_to_srgb(c.rgb), c.a);
    }
#endif
#ifdef MATERIAL
    v_material = in_material;
    v_emissive = in_emissive;
#endif
}
