#version 330
// Depth peeling (core/render/peeling.py): the projection of mesh.vert, positions object-local and
// moved into the eye frame by a float64-built matrix, texture coordinates and vertex colour.
uniform mat4 eye_from_local;  // eye frame: x right, y up, z forward (depth); sheared when off-axis
uniform vec2 half_tan;
uniform vec2 depth_range;     // near, far eye depth
in vec3 in_position;
in vec2 in_uv;
in vec4 in_color;
out vec2 v_uv;
out vec4 v_color;

#include "colour.glsl"

void main() {
    vec3 e = (eye_from_local * vec4(in_position, 1.0)).xyz;
    float n = depth_range.x, f = depth_range.y;
    gl_Position = vec4(e.x / half_tan.x, e.y / half_tan.y, (f + n) / (f - n) * e.z - 2.0 * f * n / (f - n), e.z);
    v_uv = in_uv;
    v_color = vec4(srgb_to_linear(in_color.rgb), in_color.a);  // as mesh.vert
}
