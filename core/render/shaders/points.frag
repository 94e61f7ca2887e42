#version 330
// A point's colour, or (POINT_ID) its index + 1 as four bytes, least significant first.
flat in vec4 v_color;
flat in int v_id;
out vec4 frag_color;

void main() {
#ifdef POINT_ID
    uint id = uint(v_id) + 1u;
    frag_color = vec4(float(id & 255u), float((id >> 8) & 255u), float((id >> 16) & 255u), float((id >> 24) & 255u)) / 255.0;
#else
    frag_color = v_color;
#endif
}
