#version 330
// Conservative depth peeling, the pixels a triangle touches but whose centre it does not cover
// (those come from peel.frag): if the triangle's projection meets the pixel's square, its sample is
// the triangle's point whose projection is nearest the pixel centre, lifted onto the triangle with
// perspective-correct weights, shaded there as mesh.frag would.  Peeled like peel.frag on that
// point's depth (gl_FragDepth).  Alpha-cut texels: the sample stays when the texture passes the
// cut at any point of an 8 x 8 grid over the triangle's part of the pixel's square, also in a
// pixel whose centre the triangle covers on a cut texel (which peel.frag skips), so a needle
// thinner than a pixel still leaves a sample where it crosses one.  (The largest alpha of a
// max-alpha mip chain over that part, as the layered recording reads it, also kept parts where
// bilinear filtering reaches the cut only at a point: the pine's point impostor drew 740 pixels
// more than a pixel from any needle.)
uniform sampler2D previous;   // as in peel.frag
uniform sampler2D base_texture;
uniform bool has_texture;
uniform vec4 base_color;
uniform float alpha_cutoff;
uniform float object_index;
uniform vec2 half_tan;
uniform vec2 depth_range;
uniform float resolution;
uniform sampler2DArray centre_depths;  // eye depths of the pixel's centre-ray samples (<= 0: none)
uniform int centre_layers;
uniform float same_surface;   // depth tolerance per unit depth: samples this close are one surface
flat in vec3 g_a;
flat in vec3 g_b;
flat in vec3 g_c;
flat in vec2 g_uv_a;
flat in vec2 g_uv_b;
flat in vec2 g_uv_c;
flat in vec4 g_color_a;
flat in vec4 g_color_b;
flat in vec4 g_color_c;
layout(location = 0) out vec4 hit;
layout(location = 1) out vec4 colour;

#include "colour.glsl"
// Grid points per side at which a touched pixel's part of an alpha-cut triangle is tested.
const int CUT_GRID = 8;

float cross2(vec2 u, vec2 v) { return u.x * v.y - u.y * v.x; }

// Weights (of a, b) of the point of segment ab nearest q.
vec2 nearest_on_segment(vec2 q, vec2 a, vec2 b) {
    vec2 d = b - a;
    float len2 = dot(d, d);
    float s = len2 > 0.0 ? clamp(dot(q - a, d) / len2, 0.0, 1.0) : 0.0;
    return vec2(1.0 - s, s);
}

void main() {
    // Pixel centre and half pixel in image tangents (the eye frame is sheared to centre the window).
    vec2 centre = (gl_FragCoord.xy / resolution * 2.0 - 1.0) * half_tan;
    vec2 half_pixel = half_tan / resolution;
    vec2 a = g_a.xy / g_a.z, b = g_b.xy / g_b.z, c = g_c.xy / g_c.z;
    // Does the projection meet the pixel's square?  Separating axes: x, y and the three edge normals.
    vec2 lo = centre - half_pixel, hi = centre + half_pixel;
    if (max(max(a.x, b.x), c.x) < lo.x || min(min(a.x, b.x), c.x) > hi.x) { discard; }
    if (max(max(a.y, b.y), c.y) < lo.y || min(min(a.y, b.y), c.y) > hi.y) { discard; }
    float area = cross2(b - a, c - a);
    vec3 w;  // screen-space barycentric weights of the sample
    bool centre_covered = false;
    if (abs(area) > 0.0) {
        vec2 e[3] = vec2[3](b - a, c - b, a - c);
        vec2 v[3] = vec2[3](a, b, c);
        for (int i = 0; i < 3; ++i) {
            vec2 n = vec2(e[i].y, -e[i].x) * sign(area);  // outward normal
            float reach = abs(n.x) * half_pixel.x + abs(n.y) * half_pixel.y;
            if (dot(centre - v[i], n) > reach) { discard; }
        }
        w = vec3(cross2(b - centre, c - centre), cross2(c - centre, a - centre), cross2(a - centre, b - centre)) / area;
        // The centre is clearly covered: peel.frag has its sample, unless the texel there is cut,
        // and then the triangle may pass the cut elsewhere in the pixel (below).  (Near an edge the
        // GL's snapping and tie rule may have left the centre to a neighbour or to nobody: sample
        // it here too; a duplicate of a centre sample is dropped below as the same surface.)
        if (all(greaterThan(w, vec3(1e-4)))) {
            if (!(alpha_cutoff >= 0.0 && has_texture)) { discard; }
            centre_covered = true;
        }
    }
    if (!(abs(area) > 0.0) || any(lessThan(w, vec3(0.0)))) {
        // The nearest point lies on an edge (or the projection is a segment).
        vec2 ab = nearest_on_segment(centre, a, b), bc = nearest_on_segment(centre, b, c), ca = nearest_on_segment(centre, c, a);
        vec2 qab = ab.x * a + ab.y * b, qbc = bc.x * b + bc.y * c, qca = ca.x * c + ca.y * a;
        float dab = distance(qab, centre), dbc = distance(qbc, centre), dca = distance(qca, centre);
        if (dab <= dbc && dab <= dca) { w = vec3(ab.x, ab.y, 0.0); }
        else if (dbc <= dca) { w = vec3(0.0, bc.x, bc.y); }
        else { w = vec3(ca.y, 0.0, ca.x); }
    }
    // Perspective-correct: P = sum(w_i / z_i V_i) / sum(w_i / z_i).
    vec3 k = w / vec3(g_a.z, g_b.z, g_c.z);
    k /= (k.x + k.y + k.z);
    vec3 p = k.x * g_a + k.y * g_b + k.z * g_c;
    float n = depth_range.x, f = depth_range.y;
    if (p.z < n || p.z > f) { discard; }
    float window = 0.5 * ((f + n) / (f - n) - 2.0 * f * n / ((f - n) * p.z)) + 0.5;
    vec4 previous_hit = texelFetch(previous, ivec2(gl_FragCoord.xy), 0);
    if (window <= previous_hit.r) { discard; }
    // The same surface as a centre sample of this pixel, or as the touched sample peeled last: no new
    // sample (so the passes count distinct surfaces, not the triangles of one).
    float tolerance = same_surface * p.z;
    if (previous_hit.a > 0.0 && p.z - previous_hit.g <= tolerance) { discard; }
    for (int i = 0; i < centre_layers; ++i) {
        float d = texelFetch(centre_depths, ivec3(ivec2(gl_FragCoord.xy), i), 0).r;
        if (d > 0.0 && abs(d - p.z) <= tolerance) { discard; }
    }
    vec4 shade = base_color * (k.x * g_color_a + k.y * g_color_b + k.z * g_color_c);
    if (has_texture) { shade *= texture(base_texture, k.x * g_uv_a + k.y * g_uv_b + k.z * g_uv_c); }
    if (centre_covered && !(shade.a < alpha_cutoff)) { discard; }  // peel.frag's sample
    if (alpha_cutoff >= 0.0 && shade.a < alpha_cutoff) {
        // The triangle's part of the pixel's square on a CUT_GRID x CUT_GRID grid, shaded as the
        // renderer filters the texture: the sample stays if any grid point passes the cut.
        bool passes = false;
        if (has_texture && abs(area) > 0.0) {
            for (int i = 0; i < CUT_GRID && !passes; ++i) {
                for (int j = 0; j < CUT_GRID && !passes; ++j) {
                    vec2 q = centre + half_pixel * vec2((2.0 * float(i) + 1.0) / float(CUT_GRID) - 1.0, (2.0 * float(j) + 1.0) / float(CUT_GRID) - 1.0);
                    vec3 s = vec3(cross2(b - q, c - q), cross2(c - q, a - q), cross2(a - q, b - q)) / area;
                    if (any(lessThan(s, vec3(0.0)))) { continue; }
                    vec3 m = s / vec3(g_a.z, g_b.z, g_c.z);
                    m /= (m.x + m.y + m.z);
                    vec4 here = base_color * (m.x * g_color_a + m.y * g_color_b + m.z * g_color_c)
                              * textureLod(base_texture, m.x * g_uv_a + m.y * g_uv_b + m.z * g_uv_c, 0.0);
                    if (here.a >= alpha_cutoff) {  // the sample takes this point's colour
                        passes = true;
                        shade = here;
                    }
                }
            }
        }
        if (!passes) { discard; }
    }
    gl_FragDepth = window;
    hit = vec4(window, p.z, object_index, float(gl_PrimitiveID) + 1.0);
    colour = vec4(linear_to_srgb(shade.rgb), 1.0);
}
