#version 330
// Standard perspective rasterisation of object-local positions: eye_from_local is built in float64
// on the CPU (camera-relative), so large world offsets cancel before the float32 narrowing.
uniform mat4 eye_from_local;  // eye frame: x right, y up, z forward (depth)
uniform vec2 half_tan;
uniform vec2 depth_range;     // near, far eye depth
uniform vec3 clip_offset;     // object origin minus the clip cube's centre (float64-built)
uniform float plane_half;     // > 0: the GL's six clip planes cut the geometry to the cube of this
                              // half side around the clip centre (raster.py enables them)
in vec3 in_position;
in vec2 in_uv;
in vec4 in_color;
out vec2 v_uv;
out vec4 v_color;
out vec3 v_clip;              // position relative to the clip cube's centre
out float gl_ClipDistance[6];

#include "colour.glsl"

void main() {
    vec3 e = (eye_from_local * vec4(in_position, 1.0)).xyz;
    float n = depth_range.x, f = depth_range.y;
    gl_Position = vec4(e.x / half_tan.x, e.y / half_tan.y, (f + n) / (f - n) * e.z - 2.0 * f * n / (f - n), e.z);
    v_uv = in_uv;
    v_color = vec4(srgb_to_linear(in_color.rgb), in_color.a);  // interpolated in linear light
    v_clip = in_position + clip_offset;
    // Inside the cube every distance is >= 0; the GL cuts each triangle where one turns negative.
    float h = plane_half > 0.0 ? plane_half : 3.0e38;
    gl_ClipDistance[0] = h - v_clip.x;
    gl_ClipDistance[1] = h + v_clip.x;
    gl_ClipDistance[2] = h - v_clip.y;
    gl_ClipDistance[3] = h + v_clip.y;
    gl_ClipDistance[4] = h - v_clip.z;
    gl_ClipDistance[5] = h + v_clip.z;
}
