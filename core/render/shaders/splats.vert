#version 330
// The samples of a layered depth image drawn as depth-tested square splats (core/render/splats.py,
// seed 004 §4): each as wide as its LDI pixel's footprint seen from this camera, in whole pixels
// (1..8), positions relative to the splats' centre; colours sRGB-encoded as the mesh shader writes them.
uniform mat4 eye_from_local;
uniform vec2 half_tan;
uniform vec2 depth_range;
uniform float pixel_tan;     // this camera's pixel, tangents
in vec3 in_position;
in vec4 in_color;
in float in_extent;          // the LDI pixel's footprint at the sample, world units
flat out vec4 v_color;
#ifdef NORMALS
// A G-buffer render (core/render/splats.py): each sample's world normal (SPLAT_NORMALS), else the
// normal of a sprite facing the viewer (facing: minus the camera's forward axis, world).
flat out vec3 v_normal;
#ifdef SPLAT_NORMALS
in vec3 in_normal;
#else
uniform vec3 facing;
#endif
#endif

#ifdef MATERIAL
// A material G-buffer (core/render/splats.py): each sample's occlusion, roughness, metallic and
// linear emission, decoded on the CPU from its ORM and sRGB emission bytes.
in vec3 in_material;
in vec3 in_emissive;
flat out vec3 v_material;
flat out vec3 v_emissive;
#endif

void main() {
    vec3 e = (eye_from_local * vec4(in_position, 1.0)).xyz;
    float n = depth_range.x, f = depth_range.y;
    gl_Position = vec4(e.x / half_tan.x, e.y / half_tan.y, (f + n) / (f - n) * e.z - 2.0 * f * n / (f - n), e.z);
    gl_PointSize = clamp(ceil(in_extent / (e.z * pixel_tan) - 1e-6), 1.0, 8.0);
    v_color = in_color;
#ifdef NORMALS
#ifdef SPLAT_NORMALS
    v_normal = in_normal;
#else
    v_normal = facing;
#endif
#endif
#ifdef MATERIAL
    v_material = in_material;
    v_emissive = in_emissive;
#endif
}
