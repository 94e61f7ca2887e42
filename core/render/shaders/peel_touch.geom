#version 330
// Each triangle becomes the rectangle of pixels its projection may touch (its bounding box grown
// by a pixel), carrying its three eye-frame corners, so peel_touch.frag can test every pixel the
// triangle touches, not only those whose centre it covers.
layout(triangles) in;
layout(triangle_strip, max_vertices = 4) out;
uniform vec2 half_tan;
uniform float pixel_ndc;      // one pixel in normalised device coordinates, 2 / resolution
in vec3 v_eye[];
in vec2 v_uv[];
in vec4 v_color[];
flat out vec3 g_a;
flat out vec3 g_b;
flat out vec3 g_c;
flat out vec2 g_uv_a;
flat out vec2 g_uv_b;
flat out vec2 g_uv_c;
flat out vec4 g_color_a;
flat out vec4 g_color_b;
flat out vec4 g_color_c;

void main() {
    if (v_eye[0].z <= 0.0 || v_eye[1].z <= 0.0 || v_eye[2].z <= 0.0) { return; }  // behind the camera
    vec2 p0 = v_eye[0].xy / v_eye[0].z / half_tan;
    vec2 p1 = v_eye[1].xy / v_eye[1].z / half_tan;
    vec2 p2 = v_eye[2].xy / v_eye[2].z / half_tan;
    vec2 lo = min(min(p0, p1), p2) - vec2(pixel_ndc);
    vec2 hi = max(max(p0, p1), p2) + vec2(pixel_ndc);
    if (any(greaterThan(lo, vec2(1.0))) || any(lessThan(hi, vec2(-1.0)))) { return; }
    lo = max(lo, vec2(-1.0 - pixel_ndc));
    hi = min(hi, vec2(1.0 + pixel_ndc));
    vec2 corners[4] = vec2[4](lo, vec2(hi.x, lo.y), vec2(lo.x, hi.y), hi);
    for (int i = 0; i < 4; ++i) {
        g_a = v_eye[0]; g_b = v_eye[1]; g_c = v_eye[2];
        g_uv_a = v_uv[0]; g_uv_b = v_uv[1]; g_uv_c = v_uv[2];
        g_color_a = v_color[0]; g_color_b = v_color[1]; g_color_c = v_color[2];
        gl_PrimitiveID = gl_PrimitiveIDIn;
        gl_Position = vec4(corners[i], 0.0, 1.0);
        EmitVertex();
    }
    EndPrimitive();
}
