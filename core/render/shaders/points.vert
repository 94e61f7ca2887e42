#version 330
// One-pixel points (core/render/points.py): mesh.vert's projection, positions relative to the
// point set's centre, colours already sRGB-encoded as the mesh shader writes them.
uniform mat4 eye_from_local;
uniform vec2 half_tan;
uniform vec2 depth_range;
in vec3 in_position;
in vec4 in_color;
out vec4 v_color;

void main() {
    vec3 e = (eye_from_local * vec4(in_position, 1.0)).xyz;
    float n = depth_range.x, f = depth_range.y;
    gl_Position = vec4(e.x / half_tan.x, e.y / half_tan.y, (f + n) / (f - n) * e.z - 2.0 * f * n / (f - n), e.z);
    gl_PointSize = 1.0;
    v_color = in_color;
}
