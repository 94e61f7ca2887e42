#version 330
// Unlit base colour: base_color x vertex colour x texture (glTF's rule), alpha-masked.
uniform sampler2D base_texture;
uniform bool has_texture;
uniform vec4 base_color;
uniform float alpha_cutoff;  // < 0: opaque
uniform float clip_half;     // > 0: discard outside the cube of this half side around the clip centre
in vec2 v_uv;
in vec4 v_color;
in vec3 v_clip;
out vec4 frag_color;
void main() {
    if (clip_half > 0.0 && max(max(abs(v_clip.x), abs(v_clip.y)), abs(v_clip.z)) > clip_half) { discard; }
    vec4 c = base_color * v_color;
    if (has_texture) { c *= texture(base_texture, v_uv); }
    if (alpha_cutoff >= 0.0 && c.a < alpha_cutoff) { discard; }
    frag_color = vec4(c.rgb, 1.0);
}
