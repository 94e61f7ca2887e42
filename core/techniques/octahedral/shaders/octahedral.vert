#version 330
// The octahedral impostor's card (core/techniques/octahedral/runtime.py): a square through the
// part's centre facing the eye, in coordinates relative to the centre (world units), projected as
// core/render/shaders/mesh.vert projects (eye_from_local built in float64 on the CPU).
uniform mat4 eye_from_local;
uniform vec2 half_tan;
uniform vec2 depth_range;
in vec3 in_position;
out vec3 v_local;

void main() {
    vec3 e = (eye_from_local * vec4(in_position, 1.0)).xyz;
    float n = depth_range.x, f = depth_range.y;
    gl_Position = vec4(e.x / half_tan.x, e.y / half_tan.y, (f + n) / (f - n) * e.z - 2.0 * f * n / (f - n), e.z);
    v_local = in_position;
}
