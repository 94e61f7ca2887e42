#version 330
// A splat's colour; alpha 254 marks the pixel as reached by a splat (geometry writes 255).
flat in vec4 v_color;
layout(location = 0) out vec4 frag_color;
#ifdef NORMALS
// The G-buffer's second target: the sample's world normal (splats.vert).
flat in vec3 v_normal;
layout(location = 1) out vec4 frag_normal;
#endif

void main() {
#ifdef NORMALS
    frag_normal = vec4(normalize(v_normal), 1.0);
#endif
    frag_color = vec4(v_color.rgb, 254.0 / 255.0);
}
