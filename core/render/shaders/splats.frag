#version 330
// A splat's colour; alpha 254 marks the pixel as reached by a splat (geometry writes 255).
flat in vec4 v_color;
out vec4 frag_color;

void main() {
    frag_color = vec4(v_color.rgb, 254.0 / 255.0);
}
