// The largest texture alpha over a box of texture coordinates, from the max-alpha mip chain
// (core/render/alpha_mips.py: level 0 holds each texel's largest bilinear alpha on its square):
// the finest level at which the box spans at most two texels a side, its texels that meet the
// box (repeat wrapping).  Conservative by at most one texel of that level around the box.
uniform sampler2D alpha_mip;
uniform bool has_alpha_mip;
uniform vec2 alpha_mip_size;   // level 0, texels
uniform int alpha_mip_levels;

float box_alpha(vec2 lo, vec2 hi) {
    if (!has_alpha_mip) { return 1.0; }
    vec2 extent = (hi - lo) * alpha_mip_size;
    int level = int(clamp(ceil(log2(max(max(extent.x, extent.y), 1.0))), 0.0, float(alpha_mip_levels - 1)));
    ivec2 size = max(ivec2(alpha_mip_size) >> level, ivec2(1));
    ivec2 a = ivec2(floor(lo * vec2(size))), b = ivec2(floor(hi * vec2(size)));
    b = min(b, a + ivec2(2));  // at most 3 x 3 texels, whatever rounding did
    float best = 0.0;
    for (int y = a.y; y <= b.y; ++y) {
        for (int x = a.x; x <= b.x; ++x) {
            ivec2 t = ivec2(x, y) - size * ivec2(floor(vec2(x, y) / vec2(size)));  // repeat
            best = max(best, texelFetch(alpha_mip, t, level).r);
        }
    }
    return best;
}
