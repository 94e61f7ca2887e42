#version 330
// Object-local positions (float32, relative to the object's own origin) to the recording camera's
// eye frame: x along image u, y along image v, z = depth from the reference viewpoint.
uniform mat4 eye_from_local;
in vec3 in_position;
in vec2 in_uv;
in vec4 in_color;
out vec3 v_eye;
out vec2 v_uv;
out vec4 v_color;
void main() {
    v_eye = (eye_from_local * vec4(in_position, 1.0)).xyz;
    v_uv = in_uv;
    v_color = in_color;
    gl_Position = vec4(0.0);
}
