#version 330
// An element id (index + 1, 24 bits) as an exact RGBA8 colour: R low byte, G middle, B high.
// With PEEL (core/visibility/id_cubes.py, occluder erosion): only fragments behind the layer above
// (lower_depth, not of its element lower_id) are drawn, so the depth test keeps the nearest of them:
// the next layer (which texels of it a nearby eye may see, the caller decides).
flat in uint v_id;
out vec4 colour;
#ifdef PEEL
uniform sampler2D lower_depth;
uniform usampler2D lower_id;
uniform float depth_bias;
#endif
void main() {
#ifdef PEEL
    ivec2 t = ivec2(gl_FragCoord.xy);
    float z = gl_FragCoord.z;
    if (z <= texelFetch(lower_depth, t, 0).r + depth_bias || v_id == texelFetch(lower_id, t, 0).r) discard;
#endif
    colour = vec4(float(v_id & 255u), float((v_id >> 8) & 255u), float((v_id >> 16) & 255u), 255.0) / 255.0;
}
