#version 330
// A point's colour, or (POINT_ID) its index + 1 as four bytes, least significant first.
flat in vec4 v_color;
flat in int v_id;
layout(location = 0) out vec4 frag_color;
#ifdef NORMALS
// The G-buffer's second target: the point's world normal (points.vert).
flat in vec3 v_normal;
layout(location = 1) out vec4 frag_normal;
#endif

#ifdef MATERIAL
// The material G-buffer's targets, as mesh.frag's: (occlusion, roughness, metallic, 1), (linear emission, 1).
flat in vec3 v_material;
flat in vec3 v_emissive;
layout(location = 2) out vec4 frag_material;
layout(location = 3) out vec4 frag_emissive;
#endif

void main() {
#ifdef MATERIAL
    frag_material = vec4(v_material, 1.0);
    frag_emissive = vec4(v_emissive, 1.0);
#endif
#ifdef NORMALS
    frag_normal = vec4(normalize(v_normal), 1.0);
#endif
#ifdef POINT_ID
    uint id = uint(v_id) + 1u;
    frag_color = vec4(float(id & 255u), float((id >> 8) & 255u), float((id >> 16) & 255u), float((id >> 24) & 255u)) / 255.0;
#else
    frag_color = v_color;
#endif
}
