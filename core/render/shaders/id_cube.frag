#version 330
// An element id (index + 1, 24 bits) as an exact RGBA8 colour: R low byte, G middle, B high.
flat in uint v_id;
out vec4 colour;
void main() {
    colour = vec4(float(v_id & 255u), float((v_id >> 8) & 255u), float((v_id >> 16) & 255u), 255.0) / 255.0;
}
