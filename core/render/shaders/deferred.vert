#version 330
// One triangle over the whole viewport (no vertex buffer: gl_VertexID 0, 1, 2 -> (-1, -1), (3, -1),
// (-1, 3)); ndc is the fragment's position in normalized device coordinates.
out vec2 ndc;

void main() {
    ndc = vec2(float((gl_VertexID & 1) << 2), float((gl_VertexID & 2) << 1)) - 1.0;
    gl_Position = vec4(ndc, 0.0, 1.0);
}
