#version 330
// Unlit base colour: base_color x vertex colour x texture (glTF's rule), alpha-masked.
uniform sampler2D base_texture;
uniform bool has_texture;
uniform vec4 base_color;
uniform float alpha_cutoff;  // < 0: opaque
in vec2 v_uv;
in vec4 v_color;
out vec4 frag_color;
void main() {
    vec4 c = base_color * v_color;
    if (has_texture) { c *= texture(base_texture, v_uv); }
    if (alpha_cutoff >= 0.0 && c.a < alpha_cutoff) { discard; }
    frag_color = vec4(c.rgb, 1.0);
}
