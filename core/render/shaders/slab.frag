#version 330
#if defined(TEXTURED) && defined(ALPHA_CUT)
#extension GL_ARB_texture_gather : require
#endif
// Exact coverage of one texel by the clipped polygon: conservative (the closed texel square meets
// the polygon, separating-axis test) or standard (the texel centre lies inside), then colour and
// depth from the triangle at the polygon point nearest the texel centre.  Colour is shaded in
// linear light and written sRGB-encoded (core/colour_space.py).  An alpha-cut texel takes the
// mean colour of the texels under its footprint that pass the cut (cut_texture), never the RGB of
// texels the cut removes, which the source never shows.
//
// NORMALS (core/layering/recording.py, a layer recorded with its normal channel) writes, beside the
// colour, the world shading normal of the same point (the vertex normals interpolated with the
// same perspective-correct barycentrics, turned to the reference viewpoint's side on the CPU),
// encoded n * 0.5 + 0.5 in a second RGBA8 target.
// DEPTH_CHANNEL (with NORMALS, channel sets with depth) writes the point's depth in that target's alpha.
//
// Variants (core/recording.py::slab_variant): TEXTURED for an object with a base-colour texture,
// ALPHA_CUT for one with an alpha cut.  llvmpipe runs both sides of a branch on a uniform (the
// texture reads included, with their lanes masked off), so a branch no object of the variant can
// take is left out at compile time; the code that stays is the same.
flat in vec2 g_poly[5];   // unused slots repeat vertex 0 (slab_instanced.vert)
flat in vec3 g_edge[5];   // inward unit edge normals and offsets
flat in vec4 g_box;       // polygon bounding box
flat in int g_solid;
flat in vec3 g_tri[3];
flat in vec2 g_uv[3];
flat in vec4 g_color[3];
#ifdef NORMALS
flat in vec3 g_normal[3];
layout(location = 1) out vec4 frag_normal;
#endif
#ifdef NORMAL_MAP
// The object's tangent-space normal map (glTF normalTexture: +X along u, +Y up the image), linear,
// mipmapped: read at the level whose texels are as wide as the layer texel's footprint, so that a
// texel keeps the mean normal of the map under it (renormalised) rather than one texel's.
flat in vec2 g_nuv[3];
flat in vec4 g_tangent[3];
uniform sampler2D normal_map;
uniform vec2 normal_map_size;
uniform float normal_scale;
#endif
#ifdef MATERIAL
// MATERIAL (a layer recorded with the material channel, core/layering/recording.py): glTF's
// metallic-roughness material of the same point in a third RGBA8 target, packed as glTF's ORM
// (R occlusion = 1 + strength * (R - 1), G roughness, B metallic, linear, A 1); EMISSIVE besides,
// when an object of the part emits, its linear emission (factor x sRGB-decoded texture) written
// sRGB-encoded in a fourth.  MATERIAL_MAPS for an object with a material texture: the three are
// read (a missing one bound to a 1x1 white texture) at the footprint's mip level, as the normal
// map is, at the uv MATERIAL_UV names (g_uv, g_nuv with MATERIAL_UV_NORMAL, g_muv with MATERIAL_UV_OWN).
uniform float metallic_factor;
uniform float roughness_factor;
uniform float occlusion_strength;
uniform vec3 emissive_factor;
layout(location = 2) out vec4 frag_material;
#ifdef EMISSIVE
layout(location = 3) out vec4 frag_emissive;
#endif
#ifdef MATERIAL_UV_OWN
flat in vec2 g_muv[3];  // the material uv, where it has inputs of its own (slab_instanced.vert)
#endif
#ifdef MATERIAL_MAPS
uniform sampler2D metallic_roughness_map;  // linear: G roughness, B metallic
uniform sampler2D occlusion_map;           // linear: R occlusion
uniform sampler2D emissive_map;            // sRGB
uniform vec2 metallic_roughness_size;
uniform vec2 occlusion_size;
uniform vec2 emissive_size;
#endif
#endif

uniform bool conservative;
uniform vec2 slab;
uniform sampler2D base_texture;  // sRGB
// Alpha-cut textures: linear colour x pass, and pass (1 where the texel's alpha reaches the cut),
// mipmapped (core/render/cut_colours.py).
uniform sampler2D cut_texture;
uniform vec4 base_color;
uniform float alpha_cutoff;  // < 0: no alpha mask
// Max-alpha mip chain of the texture (core/render/alpha_mips.py), in TEXTURED ALPHA_CUT: power-of-two
// level 0 of alpha_mip_size texels, alpha_mip_levels levels; texture_size is the original texture's size.
uniform sampler2D alpha_mip;
uniform sampler2D alpha_texels;  // the texture's alpha alone (R8), for the exact walk's texel reads
uniform vec2 alpha_mip_size;
uniform int alpha_mip_levels;
uniform vec2 texture_size;
#ifdef SKIP_KNOWN
// SKIP_KNOWN (iter_views with a plan's ``known`` mask: the octahedral frames, whose samples already
// decided those texels): texels whose R is 1 are not recorded (discarded before any work).
uniform sampler2D known;
#endif

layout(location = 0) out vec4 frag_color;

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

// The mip level of a texture of ``size`` texels, mapped by the uv ``t`` at the triangle's vertices,
// whose texels are as wide as the texel square centred at c (0 where that cannot be bounded).
float footprint_level(vec2 c, vec2 t[3], vec2 size) {
    vec2 lo = vec2(1e30), hi = vec2(-1e30);
    for (int k = 0; k < 4; ++k) {
        vec4 bw = barycentric(c + vec2((k & 1) == 0 ? -0.5 : 0.5, (k & 2) == 0 ? -0.5 : 0.5));
        if (!(bw.w > 0.0)) { return 0.0; }
        vec2 at = bw.x * t[0] + bw.y * t[1] + bw.z * t[2];
        lo = min(lo, at);
        hi = max(hi, at);
    }
    vec2 extent = (hi - lo) * size;
    return log2(max(max(extent.x, extent.y), 1.0));
}

// The mip level of the texture whose texels are as wide as the footprint (0 where unbounded).
float footprint_lod(vec2 c) {
    vec2 lo, hi;
    if (!footprint(c, lo, hi)) { return 0.0; }
    vec2 extent = (hi - lo) * texture_size;
    return log2(max(max(extent.x, extent.y), 1.0));
}

// The mean linear colour of the texels around uv over the footprint that pass the cut, widened
// level by level while none under it passes (the texel was kept for its margin).  The first level
// is at most the top one: a triangle seen nearly edge-on maps the texel's corners far along its
// plane, to a footprint wider than the texture, and a loop started above the top never ran and
// left the texel black (the scrub pine's cards whose planes cross the view cell: 130 texels).
vec3 cut_colour(vec2 uv, vec2 c) {
    float top = floor(log2(max(texture_size.x, texture_size.y)));
    vec4 sum = vec4(0.0);
    for (float level = min(footprint_lod(c), top); level <= top + 0.5; level = floor(level) + 1.0) {
        sum = textureLod(cut_texture, uv, level);
        if (sum.a > 1.0 / 512.0) { break; }
    }
    return sum.a > 0.0 ? sum.rgb / sum.a : vec3(0.0);
}

// The part of the clipped polygon under the texel square centred at c (Sutherland-Hodgman against
// the square's four sides, grown by EPS): at most 9 vertices, in order; 0 where they do not meet.
int polygon_under_square(vec2 c, out vec2 part[9]) {
    vec2 cur[9];
    for (int i = 0; i < 9; ++i) { cur[i] = g_poly[min(i, 4)]; part[i] = cur[i]; }
    int n = 5;
    for (int side = 0; side < 4; ++side) {
        int axis = side >> 1;
        float sgn = (side & 1) == 0 ? 1.0 : -1.0;  // keep the points with sgn * (p[axis] - bound) >= 0
        float bound = c[axis] - sgn * (0.5 + EPS);
        int m = 0;
        for (int i = 0; i < 9; ++i) {
            if (i >= n) { break; }
            vec2 p = cur[i], q = cur[i + 1 == n ? 0 : i + 1];
            float dp = sgn * (p[axis] - bound), dq = sgn * (q[axis] - bound);
            if (dp >= 0.0 && m < 9) { part[m] = p; m += 1; }
            if ((dp >= 0.0) != (dq >= 0.0) && m < 9) { part[m] = mix(p, q, dp / (dp - dq)); m += 1; }
        }
        n = m;
        for (int i = 0; i < 9; ++i) { cur[i] = part[i]; }
    }
    return n;
}

#if defined(TEXTURED) && defined(ALPHA_CUT)  // the exact alpha walk: only an alpha-cut texture needs it
// Texture alpha of texel i, repeat-wrapped (the GL_REPEAT the renderers sample with).
float texel_alpha(ivec2 i, ivec2 size) {
    return texelFetch(alpha_texels, ((i % size) + size) % size, 0).r;
}

// The alphas of texels cell, cell + (1, 0), cell + (0, 1) and cell + (1, 1), repeat-wrapped, in one
// gather: the 2x2 block a bilinear read at the corner the four share would filter.
vec4 cell_alphas(ivec2 cell, ivec2 size) {
    ivec2 wrapped = ((cell % size) + size) % size;
    vec4 g = textureGather(alpha_texels, (vec2(wrapped) + 1.0) / vec2(size));
    return g.wzxy;  // the gather's order: (i0, j1), (i1, j1), (i1, j0), (i0, j0)
}

// The largest bilinearly filtered alpha (GL_LINEAR) on the convex polygon p[0..n), in texel units
// of the base texture (texel centres at integers + 0.5), exactly: between four texel centres the
// filter is bilinear, a saddle with no maximum inside, so the maximum lies on the polygon's edges
// (within one such cell, a quadratic: its ends or its vertex) or at a texel centre inside the
// polygon, where lines through the centres cross.  Walks the edges cell by cell and the rows of
// centres; returns -1 beyond MAX_EXACT_STEPS steps (a footprint spanning many texels).
const int MAX_EXACT_STEPS = 1024;

float exact_polygon_alpha(vec2 p[9], int n, ivec2 size, float enough) {
    float best = 0.0;
    int steps = 0;
    for (int k = 0; k < 9; ++k) {
        if (k >= n) { break; }
        vec2 a = p[k], d = p[k + 1 == n ? 0 : k + 1] - a;
        ivec2 cell = ivec2(floor(a - 0.5 + 1e-6 * sign(d)));
        float t = 0.0;
        for (int guard = 0; guard < MAX_EXACT_STEPS; ++guard) {
            steps += 1;
            if (steps > MAX_EXACT_STEPS) { return -1.0; }
            vec2 next = vec2(1e30);
            if (d.x != 0.0) { next.x = (float(cell.x) + (d.x > 0.0 ? 1.5 : 0.5) - a.x) / d.x; }
            if (d.y != 0.0) { next.y = (float(cell.y) + (d.y > 0.0 ? 1.5 : 0.5) - a.y) / d.y; }
            float end = min(min(next.x, next.y), 1.0);
            vec4 block = cell_alphas(cell, size);
            float a00 = block.x, a10 = block.y, a01 = block.z, a11 = block.w;
            // Along the edge, r(s) = a + s d - (cell + 0.5); f = a00 + bx rx + by ry + dd rx ry.
            vec2 r0 = a - (vec2(cell) + 0.5);
            float bx = a10 - a00, by = a01 - a00, dd = a00 - a10 - a01 + a11;
            for (int e = 0; e < 3; ++e) {
                float s = e == 0 ? t : end;
                if (e == 2) {  // the quadratic's vertex, where it is a maximum inside [t, end]
                    float c2 = dd * d.x * d.y;
                    float c1 = bx * d.x + by * d.y + dd * (r0.x * d.y + r0.y * d.x);
                    if (!(c2 < 0.0)) { continue; }
                    s = -c1 / (2.0 * c2);
                    if (s <= t || s >= end) { continue; }
                }
                vec2 r = r0 + s * d;
                best = max(best, a00 + bx * r.x + by * r.y + dd * r.x * r.y);
                if (best >= enough) { return best; }
            }
            if (end >= 1.0) { break; }
            if (next.x <= next.y) { cell.x += d.x > 0.0 ? 1 : -1; }
            if (next.y <= next.x) { cell.y += d.y > 0.0 ? 1 : -1; }
            t = end;
        }
    }
    // Texel centres inside the polygon, row by row.
    float lo = 1e30, hi = -1e30;
    for (int k = 0; k < 9; ++k) {
        if (k >= n) { break; }
        lo = min(lo, p[k].y);
        hi = max(hi, p[k].y);
    }
    for (int j = int(ceil(lo - 0.5)); j <= int(floor(hi - 0.5)); ++j) {
        float y = float(j) + 0.5;
        float x0 = 1e30, x1 = -1e30;
        for (int k = 0; k < 9; ++k) {
            if (k >= n) { break; }
            vec2 a = p[k], b = p[k + 1 == n ? 0 : k + 1];
            if ((a.y - y) * (b.y - y) > 0.0) { continue; }
            float x = a.y == b.y ? a.x : a.x + (y - a.y) / (b.y - a.y) * (b.x - a.x);
            float xb = a.y == b.y ? b.x : x;
            x0 = min(x0, min(x, xb));
            x1 = max(x1, max(x, xb));
        }
        for (int i = int(ceil(x0 - 0.5)); i <= int(floor(x1 - 0.5)); ++i) {
            steps += 1;
            if (steps > MAX_EXACT_STEPS) { return -1.0; }
            best = max(best, texel_alpha(ivec2(i, j), size));
            if (best >= enough) { return best; }
        }
    }
    return best;
}

// The largest texture alpha that bilinear filtering gives to a point of the triangle inside this
// texel and this layer's slab.  That part of the triangle is the polygon under the texel square;
// its texture footprint is the convex polygon of its vertices' UVs (a plane maps convex polygons
// to convex ones).  Exact where the footprint spans few texels (exact_polygon_alpha); else read,
// row by row, exactly the texels of one level of alpha_mip whose squares meet the footprint, the
// finest level at which they are about MAX_FOOTPRINT_TEXELS at most (level 0 holds each texel's
// largest filtered alpha on its square, core/render/alpha_mips.py), which errs by at most one
// texel of that level.  Footprints of grazing triangles are long, thin and diagonal: a bounding
// box or coarse texels would take in texture many texels across them, texels of the layer pixels
// away from any opaque point (as an earlier, coarser read did).  Returns 1 where the footprint
// cannot be bounded.  It stops at the first alpha reaching ``enough`` (the texel is kept whatever
// the rest is: only the cut reads it), returning that alpha.
const int MAX_FOOTPRINT_TEXELS = 1024;

float footprint_alpha(vec2 c, float enough) {
    vec2 a = g_tri[0].xy, b = g_tri[1].xy, d = g_tri[2].xy;
    if (abs(cross2(b - a, d - a)) <= 1e-9) { return 1.0; }
    vec2 part[9];
    int n = polygon_under_square(c, part);
    if (n == 0) { part[0] = nearest_boundary_point(c); n = 1; }
    ivec2 size0 = textureSize(alpha_texels, 0);
    vec2 texels[9];  // base texture texel units
    vec2 uv[9];  // level-0 alpha_mip texel units
    vec2 lo = vec2(1e30), hi = vec2(-1e30);
    for (int k = 0; k < 9; ++k) {
        if (k >= n) { break; }
        vec4 bw = barycentric(part[k]);
        if (!(bw.w > 0.0)) { return 1.0; }
        vec2 at = bw.x * g_uv[0] + bw.y * g_uv[1] + bw.z * g_uv[2];
        texels[k] = at * vec2(size0);
        uv[k] = at * alpha_mip_size;
        lo = min(lo, uv[k]);
        hi = max(hi, uv[k]);
    }
    // The walk steps through at least max(|dx|, |dy|) - 1 cells along each edge: where they pass
    // MAX_EXACT_STEPS (with a margin) it would give up, so it is not started (a footprint of many
    // texels: an octahedral frame's texel over a leaf card's texture).
    float least = 0.0;
    for (int k = 0; k < 9; ++k) {
        if (k >= n) { break; }
        vec2 e = abs(texels[k + 1 == n ? 0 : k + 1] - texels[k]);
        least += max(max(e.x, e.y) - 1.0, 0.0);
    }
    if (least <= float(MAX_EXACT_STEPS + 8)) {
        float exact = exact_polygon_alpha(texels, n, size0, enough - 1.0 / 256.0);
        // One step of 8-bit filter weights (a fixed-point GL_LINEAR) above the exact value.
        if (exact >= 0.0) { return exact + 1.0 / 256.0; }
    }
    // The level: texels met ~ area / side^2 + perimeter / side + rows.
    float area = 0.0, perimeter = 0.0;
    for (int k = 0; k < 9; ++k) {
        if (k >= n) { break; }
        vec2 q = uv[k + 1 == n ? 0 : k + 1];
        area += cross2(uv[k], q);
        perimeter += distance(uv[k], q);
    }
    area = 0.5 * abs(area);
    int level = 0;
    for (; level < alpha_mip_levels - 1; ++level) {
        float side = float(1 << level);
        if (area / (side * side) + 2.0 * perimeter / side + (hi.y - lo.y) / side + 4.0 <= float(MAX_FOOTPRINT_TEXELS)) { break; }
    }
    ivec2 size = max(ivec2(alpha_mip_size) >> level, ivec2(1));
    vec2 side = alpha_mip_size / vec2(size);  // a level texel, in level-0 texels
    float best = 0.0;
    int fetched = 0;
    for (int y = int(floor(lo.y / side.y)); y <= int(floor(hi.y / side.y)); ++y) {
        // The footprint's x extent within this row's closed band: its edges clipped to the band.
        float y0 = float(y) * side.y, y1 = y0 + side.y;
        float x0 = 1e30, x1 = -1e30;
        for (int k = 0; k < 9; ++k) {
            if (k >= n) { break; }
            vec2 p = uv[k], e = uv[k + 1 == n ? 0 : k + 1] - p;
            float t0 = 0.0, t1 = 1.0;
            if (e.y != 0.0) {
                float ta = (y0 - p.y) / e.y, tb = (y1 - p.y) / e.y;
                t0 = max(t0, min(ta, tb));
                t1 = min(t1, max(ta, tb));
            } else if (p.y < y0 || p.y > y1) {
                continue;
            }
            if (t0 > t1) { continue; }
            float xa = p.x + t0 * e.x, xb = p.x + t1 * e.x;
            x0 = min(x0, min(xa, xb));
            x1 = max(x1, max(xa, xb));
        }
        if (x0 > x1) { continue; }
        for (int x = int(floor(x0 / side.x)); x <= int(floor(x1 / side.x)); ++x) {
            fetched += 1;
            if (fetched > 4 * MAX_FOOTPRINT_TEXELS) { return 1.0; }
            ivec2 at = ivec2(((x % size.x) + size.x) % size.x, ((y % size.y) + size.y) % size.y);
            best = max(best, texelFetch(alpha_mip, at, level).r);
            if (best >= enough) { return best; }
        }
    }
    return best;
}
#endif

void main() {
    vec2 c = gl_FragCoord.xy;
#ifdef SKIP_KNOWN
    if (texelFetch(known, ivec2(c), 0).r > 0.5) { discard; }
#endif
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
#ifdef TEXTURED
    {
        vec4 texel = textureLod(base_texture, uv, 0.0);
#ifdef ALPHA_CUT
        if (alpha_cutoff >= 0.0) {
            shown = shown && colour.a * texel.a >= alpha_cutoff;
            texel.rgb = cut_colour(uv, c);
        }
#endif
        colour *= texel;
    }
#endif
#ifdef ALPHA_CUT
    if (alpha_cutoff >= 0.0) {
        // Conservative alpha cut: keep the texel if any point under it may be opaque.
        float most = base_color.a * max(g_color[0].a, max(g_color[1].a, g_color[2].a));
#ifdef TEXTURED
        // The walk stops once the alpha keeps the texel (a little above the cut: the product's rounding).
        most *= footprint_alpha(c, most > 0.0 ? alpha_cutoff / most * (1.0 + 1e-5) : 1e30);
#endif
        if (most < alpha_cutoff) { discard; }
    }
#endif
    // Two depth bands: a triangle the texel centre shows wins over one kept only by the
    // conservative rules (its rim or the transparent part of its texture), whatever their depths,
    // so the texel holds the colour its centre shows; within a band the nearest wins.  Only the
    // colour is read back, so the bands change no coverage.
    gl_FragDepth = 0.5 * (depth - slab.x) / max(slab.y - slab.x, 1e-30) + (shown ? 0.0 : 0.5);
    frag_color = vec4(linear_to_srgb(colour.rgb), 1.0);
#ifdef MATERIAL
    // The normals' spread under the texel's footprint: |mean| of the unit normals a normal map's
    // mip averages (1 where there is none); it widens the recorded roughness (Toksvig below).
    float mean_length = 1.0;
#endif
#ifdef NORMALS
    vec3 n = pb.x * g_normal[0] + pb.y * g_normal[1] + pb.z * g_normal[2];
    float len = length(n);
    n = len > 1e-12 ? n / len : normalize(g_normal[0] + g_normal[1] + g_normal[2] + vec3(0.0, 0.0, 1e-30));
#ifdef NORMAL_MAP
    {
        vec2 nuv = pb.x * g_nuv[0] + pb.y * g_nuv[1] + pb.z * g_nuv[2];
        vec3 t = pb.x * g_tangent[0].xyz + pb.y * g_tangent[1].xyz + pb.z * g_tangent[2].xyz;
        t -= n * dot(n, t);
        if (dot(t, t) > 1e-24) {
            t = normalize(t);
            float w = pb.x * g_tangent[0].w + pb.y * g_tangent[1].w + pb.z * g_tangent[2].w;
            vec3 b = cross(n, t) * (w < 0.0 ? -1.0 : 1.0);  // as mesh.frag: the interpolated handedness's sign
            vec3 m = textureLod(normal_map, nuv, footprint_level(c, g_nuv, normal_map_size)).rgb * 2.0 - 1.0;
            m.xy *= normal_scale;
#ifdef MATERIAL
            // The material recording uploads the map as float unit normals, normal_scale applied
            // (recording.py, _unit_normal_map), so the mip's mean is the normals' true mean.
            mean_length = min(length(m), 1.0);
#endif
            vec3 mapped = t * m.x + b * m.y + n * m.z;
            if (dot(mapped, mapped) > 1e-24) { n = normalize(mapped); }
        }
    }
#endif
#ifdef DEPTH_CHANNEL
    // The depth channel (core/impostor/depth.py): the point's eye depth within the slab, 0 at its
    // near border and 1 at its far one, quantised to 8 bits by the target, in the normal's alpha.
    frag_normal = vec4(n * 0.5 + 0.5, (depth - slab.x) / max(slab.y - slab.x, 1e-30));
#else
    frag_normal = vec4(n * 0.5 + 0.5, 1.0);
#endif
#endif
#ifdef MATERIAL
    {
        float occlusion = 1.0;
        float roughness = roughness_factor;
        float metallic = metallic_factor;
        vec3 emission = emissive_factor;
#ifdef MATERIAL_MAPS
        vec2 t3[3];
#if defined(MATERIAL_UV_NORMAL)
        t3[0] = g_nuv[0]; t3[1] = g_nuv[1]; t3[2] = g_nuv[2];
#elif defined(MATERIAL_UV_OWN)
        t3[0] = g_muv[0]; t3[1] = g_muv[1]; t3[2] = g_muv[2];
#else
        t3[0] = g_uv[0]; t3[1] = g_uv[1]; t3[2] = g_uv[2];
#endif
        vec2 muv = pb.x * t3[0] + pb.y * t3[1] + pb.z * t3[2];
        vec4 mr = textureLod(metallic_roughness_map, muv, footprint_level(c, t3, metallic_roughness_size));
        roughness *= mr.g;
        metallic *= mr.b;
        occlusion = 1.0 + occlusion_strength * (textureLod(occlusion_map, muv, footprint_level(c, t3, occlusion_size)).r - 1.0);
        emission *= textureLod(emissive_map, muv, footprint_level(c, t3, emissive_size)).rgb;
#endif
        // Toksvig (2005, "Mipmapping normal maps") in the von Mises-Fisher form of Neubelt and
        // Pettineo (2013, "Crafting a next-gen material pipeline for The Order: 1886"): a mean of
        // unit normals of length r fits a vMF lobe of sharpness kappa ~ r (3 - r^2) / (1 - r^2)
        // (Banerjee et al. 2005), a Beckmann/GGX lobe of alpha^2 ~ 2 / kappa, whose width adds to
        // the material's in alpha^2 (as Filament's specular anti-aliasing adds its kernel
        // roughness): alpha = roughness^2, so roughness' = (roughness^4 + 2 / kappa)^(1/4).
        // Written as 2 (1 - r^2) / (r (3 - r^2)) rather than through kappa, which is infinite at r = 1.
        float r = max(mean_length, 1e-4);
        float spread = 2.0 * (1.0 - r * r) / (r * (3.0 - r * r));
        float alpha = roughness * roughness;
        roughness = min(sqrt(sqrt(alpha * alpha + spread)), 1.0);
        frag_material = vec4(clamp(occlusion, 0.0, 1.0), clamp(roughness, 0.0, 1.0), clamp(metallic, 0.0, 1.0), 1.0);
#ifdef EMISSIVE
        frag_emissive = vec4(linear_to_srgb(clamp(emission, 0.0, 1.0)), 1.0);
#endif
    }
#endif
}
