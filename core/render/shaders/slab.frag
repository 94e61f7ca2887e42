#version 330
// Exact coverage of one texel by the clipped polygon: conservative (the closed texel square meets
// the polygon, separating-axis test) or standard (the texel centre lies inside), then colour and
// depth from the triangle at the polygon point nearest the texel centre.  Colour is shaded in
// linear light and written sRGB-encoded (core/colour_space.py).  An alpha-cut texel takes the
// alpha-weighted mean colour of the texture under its footprint (cut_texture), never the RGB of
// transparent texels, which the source never shows.
flat in vec2 g_poly[5];   // unused slots repeat vertex 0 (slab_instanced.vert)
flat in vec3 g_edge[5];   // inward unit edge normals and offsets
flat in vec4 g_box;       // polygon bounding box
flat in int g_solid;
flat in vec3 g_tri[3];
flat in vec2 g_uv[3];
flat in vec4 g_color[3];

uniform bool conservative;
uniform vec2 slab;
uniform sampler2D base_texture;  // sRGB
uniform bool has_texture;
// Alpha-cut textures: linear colour x alpha, and alpha, mipmapped (core/render/cut_colours.py).
uniform sampler2D cut_texture;
uniform vec4 base_color;
uniform float alpha_cutoff;  // < 0: no alpha mask
// Max-alpha mip chain of the texture (core/render/alpha_mips.py): power-of-two level 0 of
// alpha_mip_size texels, alpha_mip_levels levels; texture_size is the original texture's size.
uniform sampler2D alpha_mip;
uniform bool has_alpha_mip;
uniform vec2 alpha_mip_size;
uniform int alpha_mip_levels;
uniform vec2 texture_size;

out vec4 frag_color;

#include "colour.glsl"

const float EPS = 1e-4;  // texels; errs towards covering

float cross2(vec2 a, vec2 b) { return a.x * b.y - a.y * b.x; }

// Separating axes: a convex polygon and a square are disjoint exactly when the square lies wholly
// outside one of the polygon's edge lines or outside its bounding box on x or y.  Every loop runs
// over a constant five edges (zero-length ones pass), so the compiler unrolls it.
bool square_meets_polygon(vec2 c) {
    if (any(greaterThan(g_box.xy, c + 0.5 + EPS)) || any(lessThan(g_box.zw, c - 0.5 - EPS))) { return false; }
    for (int i = 0; i < 5; ++i) {
        vec3 e = g_edge[i];
        if (dot(e.xy, c) + e.z + 0.5 * (abs(e.x) + abs(e.y)) + EPS < 0.0) { return false; }
    }
    return true;
}

bool centre_inside(vec2 c) {
    if (g_solid == 0) { return false; }
    for (int i = 0; i < 5; ++i) {
        if (dot(g_edge[i].xy, c) + g_edge[i].z < 0.0) { return false; }
    }
    return true;
}

// The point of the polygon's boundary nearest c (used when c itself lies outside the polygon).
vec2 nearest_boundary_point(vec2 c) {
    vec2 best = g_poly[0];
    float bd = 1e30;
    for (int i = 0; i < 5; ++i) {
        vec2 p = g_poly[i], q = g_poly[i == 4 ? 0 : i + 1];
        vec2 e = q - p;
        float t = dot(e, e) > 0.0 ? clamp(dot(c - p, e) / dot(e, e), 0.0, 1.0) : 0.0;
        vec2 x = p + t * e;
        float d = dot(x - c, x - c);
        if (d < bd) { bd = d; best = x; }
    }
    return best;
}

// Perspective-correct barycentrics of texel-space point x on the triangle's plane (extrapolated
// outside the triangle); w <= 0 means the point is not in front of the eye on that plane.
vec4 barycentric(vec2 x) {
    vec2 a = g_tri[0].xy, b = g_tri[1].xy, d = g_tri[2].xy;
    float area = cross2(b - a, d - a);
    vec3 bary = vec3(cross2(b - x, d - x), cross2(d - x, a - x), cross2(a - x, b - x)) / area;
    vec3 w = bary * vec3(g_tri[0].z, g_tri[1].z, g_tri[2].z);
    float wsum = w.x + w.y + w.z;
    return vec4(w / wsum, wsum);
}

// The uv of the four corners of the texel square centred at c on the triangle's plane (x-major:
// (-,-), (+,-), (-,+), (+,+)); false where they cannot be had (edge-on triangle, a corner not in
// front of the eye).
bool corner_uvs(vec2 c, out vec2 uv[4]) {
    vec2 a = g_tri[0].xy, b = g_tri[1].xy, d = g_tri[2].xy;
    if (abs(cross2(b - a, d - a)) <= 1e-9) { return false; }
    for (int k = 0; k < 4; ++k) {
        vec4 bw = barycentric(c + vec2((k & 1) == 0 ? -0.5 : 0.5, (k & 2) == 0 ? -0.5 : 0.5));
        if (!(bw.w > 0.0)) { return false; }
        uv[k] = bw.x * g_uv[0] + bw.y * g_uv[1] + bw.z * g_uv[2];
    }
    return true;
}

// The texture-space rectangle (lo, hi) under the texel square centred at c; false where it cannot
// be bounded.
bool footprint(vec2 c, out vec2 lo, out vec2 hi) {
    vec2 uv[4];
    if (!corner_uvs(c, uv)) { return false; }
    lo = min(min(uv[0], uv[1]), min(uv[2], uv[3]));
    hi = max(max(uv[0], uv[1]), max(uv[2], uv[3]));
    return true;
}

// The mip level of the texture whose texels are as wide as the footprint (0 where unbounded).
float footprint_lod(vec2 c) {
    vec2 lo, hi;
    if (!footprint(c, lo, hi)) { return 0.0; }
    vec2 extent = (hi - lo) * texture_size;
    return log2(max(max(extent.x, extent.y), 1.0));
}

// The alpha-weighted mean linear colour of the texture around uv over the footprint, widened level
// by level while everything under it is transparent (the texel was kept for its margin).
vec3 cut_colour(vec2 uv, vec2 c) {
    float top = floor(log2(max(texture_size.x, texture_size.y)));
    vec4 sum = vec4(0.0);
    for (float level = footprint_lod(c); level <= top + 0.5; level = floor(level) + 1.0) {
        sum = textureLod(cut_texture, uv, level);
        if (sum.a > 1.0 / 512.0) { break; }
    }
    return sum.a > 0.0 ? sum.rgb / sum.a : vec3(0.0);
}

// The largest texture alpha anywhere under the texel square centred at c, plus one texture texel
// for bilinear filtering: read at most 2x2 texels of the max-alpha level whose texels are at
// least as wide as that footprint.  Returns 1 where the footprint cannot be bounded.
float footprint_alpha(vec2 c) {
    vec2 lo, hi;
    if (!footprint(c, lo, hi)) { return 1.0; }
    lo -= 1.0 / texture_size;
    hi += 1.0 / texture_size;
    vec2 extent = (hi - lo) * alpha_mip_size;
    int level = int(clamp(ceil(log2(max(max(extent.x, extent.y), 1.0))), 0.0, float(alpha_mip_levels - 1)));
    ivec2 size = max(ivec2(alpha_mip_size) >> level, ivec2(1));
    ivec2 i0 = ivec2(floor(lo * vec2(size)));
    ivec2 i1 = ivec2(floor(hi * vec2(size)));
    float best = 0.0;
    for (int y = i0.y; y <= min(i1.y, i0.y + 1); ++y) {
        for (int x = i0.x; x <= min(i1.x, i0.x + 1); ++x) {
            ivec2 at = ivec2(((x % size.x) + size.x) % size.x, ((y % size.y) + size.y) % size.y);
            best = max(best, texelFetch(alpha_mip, at, level).r);
        }
    }
    return best;
}

void main() {
    vec2 c = gl_FragCoord.xy;
    // Most covered texels have their centre inside the polygon: decide those with the cheap test
    // and run the separating-axis test and the nearest-point search only at the polygon's rim.
    vec2 x = c;
    bool shown = true;  // the texel centre shows this triangle (inside it, and passing the alpha cut)
    if (!centre_inside(c)) {
        shown = false;
        if (!conservative || !square_meets_polygon(c)) { discard; }
        x = nearest_boundary_point(c);
    }
    // Perspective-correct barycentrics of x in the projected triangle.
    vec2 a = g_tri[0].xy, b = g_tri[1].xy, d = g_tri[2].xy;
    float area = cross2(b - a, d - a);
    vec3 bary;
    if (abs(area) > 1e-9) {
        bary = vec3(cross2(b - x, d - x), cross2(d - x, a - x), cross2(a - x, b - x)) / area;
    } else {  // edge-on triangle: take the vertex nearest x
        vec3 dist = vec3(distance(a, x), distance(b, x), distance(d, x));
        bary = vec3(dist.x <= dist.y && dist.x <= dist.z, dist.y < dist.x && dist.y <= dist.z, dist.z < dist.x && dist.z < dist.y);
    }
    vec3 w = bary * vec3(g_tri[0].z, g_tri[1].z, g_tri[2].z);
    float wsum = w.x + w.y + w.z;
    vec3 pb = abs(wsum) > 0.0 ? w / wsum : vec3(1.0, 0.0, 0.0);
    float depth = clamp(1.0 / max(wsum, 1e-30), slab.x, slab.y);
    vec2 uv = pb.x * g_uv[0] + pb.y * g_uv[1] + pb.z * g_uv[2];
    // glTF's rule in linear light: factor x vertex colour x texture (vertex colours arrive sRGB).
    vec3 vertex = pb.x * srgb_to_linear(g_color[0].rgb) + pb.y * srgb_to_linear(g_color[1].rgb) + pb.z * srgb_to_linear(g_color[2].rgb);
    vec4 colour = base_color * vec4(vertex, pb.x * g_color[0].a + pb.y * g_color[1].a + pb.z * g_color[2].a);
    if (has_texture) {
        vec4 texel = textureLod(base_texture, uv, 0.0);
        if (alpha_cutoff >= 0.0 && has_alpha_mip) {
            shown = shown && colour.a * texel.a >= alpha_cutoff;
            texel.rgb = cut_colour(uv, c);
        }
        colour *= texel;
    }
    if (alpha_cutoff >= 0.0) {
        // Conservative alpha cut: keep the texel if any point under it may be opaque.
        float most = base_color.a * max(g_color[0].a, max(g_color[1].a, g_color[2].a));
        if (has_alpha_mip) { most *= footprint_alpha(c); }
        if (most < alpha_cutoff) { discard; }
    }
    // Two depth bands: a triangle the texel centre shows wins over one kept only by the
    // conservative rules (its rim or the transparent part of its texture), whatever their depths,
    // so the texel holds the colour its centre shows; within a band the nearest wins.  Only the
    // colour is read back, so the bands change no coverage.
    gl_FragDepth = 0.5 * (depth - slab.x) / max(slab.y - slab.x, 1e-30) + (shown ? 0.0 : 0.5);
    frag_color = vec4(linear_to_srgb(colour.rgb), 1.0);
}
