#version 330
// The deferred shading pass of a G-buffer (core/render/deferred.py): each pixel's sRGB base colour
// and world shading normal lit by one directional light and an ambient term, in the arithmetic of
// core/quality/lighting.py's radiance (three.js r0.187 MeshStandardMaterial; see that module's
// docstring for where it departs from glTF), with geometryRoughness 0, written sRGB-encoded.
#include "colour.glsl"

uniform sampler2D albedo;   // RGBA8, the G-buffer's colour (sRGB-encoded, not decoded by the GL)
uniform sampler2D normals;  // RGBA32F, the world shading normal in xyz (zero where nothing was drawn)
uniform sampler2D dfg_lut;  // RG32F 16 x 16, core/quality/dfg.py's table: u roughness, v N.V
uniform vec3 forward;       // the camera's frame (world)
uniform vec3 right;
uniform vec3 up;
uniform vec2 half_tan;      // tan(fov / 2), both axes
uniform vec2 offset;        // the camera's window offset (Camera.offset)
uniform vec3 to_light;      // unit, toward the light
uniform vec3 irradiance;    // the light's colour x intensity (linear)
uniform vec3 ambient;       // linear irradiance (three.js AmbientLight colour x intensity)
uniform float roughness;
uniform float metallic;

in vec2 ndc;
out vec4 colour;

const float PI = 3.141592653589793;
const float MIN_ROUGHNESS = 0.045;
const float DIELECTRIC_F0 = 0.04;
const float F_AVERAGE = DIELECTRIC_F0 + (1.0 - DIELECTRIC_F0) / 21.0;

vec3 f_schlick(vec3 f0, float f90, float dot_vh) {
    float fresnel = exp2((-5.55473 * dot_vh - 6.98316) * dot_vh);
    return f0 * (1.0 - fresnel) + f90 * fresnel;
}

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    vec4 texel_colour = texelFetch(albedo, texel, 0);
    vec3 n = texelFetch(normals, texel, 0).xyz;
    vec3 base = srgb_to_linear(texel_colour.rgb);
    vec3 diffuse = base * (1.0 - metallic);
    vec3 f0 = mix(vec3(DIELECTRIC_F0), base, metallic);
    float rough = min(max(roughness, MIN_ROUGHNESS), 1.0);
    vec2 t = offset + ndc * half_tan;
    vec3 v = -normalize(forward + t.x * right + t.y * up);
    float dot_nv = clamp(dot(n, v), 0.0, 1.0);
    vec2 dfg = texture(dfg_lut, vec2(rough, dot_nv)).rg;  // (scale, bias)
    float energy = dfg.x + dfg.y;

    float dot_nl = clamp(dot(n, to_light), 0.0, 1.0);
    vec3 h = to_light + v;
    float h_length = length(h);
    h = h_length > 0.0 ? h / h_length : n;
    float dot_nh = clamp(dot(n, h), 0.0, 1.0);
    float dot_vh = clamp(dot(v, h), 0.0, 1.0);
    float alpha = max(rough, MIN_ROUGHNESS) * max(rough, MIN_ROUGHNESS);
    float a2 = alpha * alpha;
    float gv = dot_nl * sqrt(a2 + (1.0 - a2) * dot_nv * dot_nv);
    float gl = dot_nv * sqrt(a2 + (1.0 - a2) * dot_nl * dot_nl);
    float visibility = 0.5 / max(gv + gl, 1e-6);
    float denom = dot_nh * dot_nh * (a2 - 1.0) + 1.0;
    float distribution = a2 / (PI * denom * denom);
    vec3 compensation = 1.0 + f0 * (1.0 / energy - 1.0);
    vec3 specular = f_schlick(f0, 1.0, dot_vh) * (visibility * distribution) * compensation;
    float diffuse_weight = 1.0 - f_schlick(vec3(DIELECTRIC_F0), 1.0, dot_vh).x;
    vec3 direct = dot_nl * irradiance * (specular + diffuse / PI * diffuse_weight);

    float single = DIELECTRIC_F0 * dfg.x + dfg.y;
    float lost = 1.0 - energy;
    float multi = single * F_AVERAGE / (1.0 - lost * F_AVERAGE) * lost;
    vec3 indirect = ambient * diffuse / PI * (1.0 - single - multi);

    colour = vec4(linear_to_srgb(direct + indirect), texel_colour.a);
}
