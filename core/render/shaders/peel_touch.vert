#version 330
// Conservative depth peeling (core/render/peeling.py): positions in the (sheared) eye frame for
// peel_touch.geom, which draws each triangle's screen rectangle.
uniform mat4 eye_from_local;
in vec3 in_position;
in vec2 in_uv;
in vec4 in_color;
out vec3 v_eye;
out vec2 v_uv;
out vec4 v_color;

#include "colour.glsl"

void main() {
    v_eye = (eye_from_local * vec4(in_position, 1.0)).xyz;
    v_uv = in_uv;
    v_color = vec4(srgb_to_linear(in_color.rgb), in_color.a);
    gl_Position = vec4(0.0, 0.0, 0.0, 1.0);  // the geometry shader places the rectangle
}
