#version 330
// A splat's colour; alpha 254 marks the pixel as reached by a splat (geometry writes 255).
flat in vec4 v_color;
layout(location = 0) out vec4 frag_color;
#ifdef NORMALS
// The G-buffer's second target: the sample's world normal (splats.vert).
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
    frag_color = vec4(v_color.rgb, 254.0 / 255.0);
}
