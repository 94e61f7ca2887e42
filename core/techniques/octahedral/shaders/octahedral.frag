#version 330
// The octahedral impostor's blend (core/techniques/octahedral/runtime.py, docs/techniques/octahedral.md):
// the eye ray through this fragment meets each of the three frames around the view direction,
// on the card plane through the centre (no depth) or on the frame's height field (ray marched,
// with depth: the parallax correction; a column ends at the opposite frame's surface where there
// is one); their colours are blended by the barycentric weights,
// cut at 0.5, and the blended hit point's depth is written (the pixel depth offset). Where a pixel
// spans more than a frame texel, a frame's coverage (alpha, or with depth its height) is the largest
// over the texels the pixel's footprint touches.
uniform sampler2D atlas0;         // each blended frame's page: sRGB colour, alpha 0 | 1
uniform sampler2D atlas1;
uniform sampler2D atlas2;
uniform sampler2D heights0;       // and its normal page: alpha = depth byte (0: nothing)
uniform sampler2D heights1;
uniform sampler2D heights2;
uniform mat4 eye_from_local;
uniform vec2 depth_range;
uniform vec3 eye_local;           // the eye relative to the centre, world units
uniform vec3 f_right[3];
uniform vec3 f_up[3];
uniform vec3 f_dir[3];
uniform vec2 f_origin[3];         // first texel of each frame (x right, y down)
uniform float f_weight[3];
uniform float radius;
uniform float frame_res;
uniform vec2 f_size[3];          // each frame's page, texels (width, height)
uniform sampler2D opposite0;      // the normal page of each blended frame's opposite frame (its depth)
uniform sampler2D opposite1;
uniform sampler2D opposite2;
uniform int o_valid[3];           // 1: the frame has an opposite frame (a two-sided column)
uniform vec3 o_right[3];
uniform vec3 o_up[3];
uniform vec2 o_origin[3];
uniform vec2 o_size[3];
uniform int use_depth;
uniform float pixel_angle;        // 2 tan(fov / 2) / resolution: a pixel's size per unit of distance
uniform int normal_mode;          // G-buffer normals: 0 none, 1 the normal pages', 2 the card's (facing the eye)
uniform int material_mode;        // 1: a material G-buffer (the material pages blended as the colour)
uniform sampler2D orm0;           // each blended frame's material page: occlusion, roughness, metallic (linear)
uniform sampler2D orm1;
uniform sampler2D orm2;
uniform sampler2D emission0;      // and its emissive page (sRGB: read as linear emission; black where none)
uniform sampler2D emission1;
uniform sampler2D emission2;
in vec3 v_local;
layout(location = 0) out vec4 frag_color;
layout(location = 1) out vec4 frag_normal;  // world normal (a G-buffer render; core/quality/lit.py)
layout(location = 2) out vec4 frag_material;  // occlusion, roughness, metallic (a material G-buffer)
layout(location = 3) out vec4 frag_emission;  // linear emission

#include "colour.glsl"

vec2 frame_texel(int k, vec3 p) {  // continuous texel position in frame k (0..frame_res, y down)
    return vec2((dot(p, f_right[k]) / radius * 0.5 + 0.5) * frame_res,
                (0.5 - dot(p, f_up[k]) / radius * 0.5) * frame_res);
}

bool in_frame(vec2 t) {
    return all(greaterThanEqual(t, vec2(0.0))) && all(lessThan(t, vec2(frame_res)));
}

vec4 colour_at(int k, vec2 t) {  // bilinear, linear light (an sRGB texture)
    vec2 a = f_origin[k] + t;
    vec2 uv = vec2(a.x / f_size[k].x, 1.0 - a.y / f_size[k].y);
    if (k == 0) return texture(atlas0, uv);  // GLSL 3.30 indexes sampler arrays by constants only
    if (k == 1) return texture(atlas1, uv);
    return texture(atlas2, uv);
}

vec2 page_uv(int k, vec2 t) {  // frame k's texel position t as its page's texture coordinate
    vec2 a = f_origin[k] + t;
    return vec2(a.x / f_size[k].x, 1.0 - a.y / f_size[k].y);
}

vec3 orm_at(int k, vec2 t) {  // bilinear, as the colour
    vec2 uv = page_uv(k, t);
    return (k == 0 ? texture(orm0, uv) : k == 1 ? texture(orm1, uv) : texture(orm2, uv)).rgb;
}

vec3 emission_at(int k, vec2 t) {
    vec2 uv = page_uv(k, t);
    return (k == 0 ? texture(emission0, uv) : k == 1 ? texture(emission1, uv) : texture(emission2, uv)).rgb;
}

vec3 normal_at(int k, vec2 t) {  // the normal page's world normal, nearest texel
    ivec2 a = ivec2(floor(f_origin[k] + clamp(t, vec2(0.0), vec2(frame_res - 0.5))));
    ivec2 at = ivec2(a.x, int(f_size[k].y) - 1 - a.y);
    vec3 n = (k == 0 ? texelFetch(heights0, at, 0).rgb : k == 1 ? texelFetch(heights1, at, 0).rgb : texelFetch(heights2, at, 0).rgb);
    return n * 2.0 - 1.0;
}

float height_at(int k, vec2 t) {  // the surface's height above the card plane; -1e30 where none
    if (!in_frame(t)) return -1e30;
    ivec2 a = ivec2(floor(f_origin[k] + t));
    ivec2 at = ivec2(a.x, int(f_size[k].y) - 1 - a.y);
    float level = (k == 0 ? texelFetch(heights0, at, 0).a : k == 1 ? texelFetch(heights1, at, 0).a : texelFetch(heights2, at, 0).a) * 255.0;
    if (level < 0.5) return -1e30;
    return ((level - 1.0) / 254.0 * 2.0 - 1.0) * radius;
}

float footprint(vec3 p, float dn) {  // the side of a square of frame texels holding a pixel's beam at p
    // (a pixel's side turned by any angle: sqrt(2); seen along a frame dn = cos away: 1 / dn)
    return length(p - eye_local) * pixel_angle / (2.0 * radius / frame_res) * 1.41421356 / max(-dn, 0.1);
}

vec4 footprint_scan(int k, vec2 t, float side, float h, bool depth, bool mean) {
    // the texels of frame k within the footprint (side texels a side) at t that hold the part (with
    // depth: whose surface is at height h or above): their linear colour and count summed, each
    // weighted by its share of the footprint (mean), or (0, 0, 0, 1) at the first one (else 0)
    vec2 lo = max(t - 0.5 * side, vec2(0.0)), hi = min(t + 0.5 * side, vec2(frame_res - 1e-3));
    if (any(greaterThan(lo, hi))) return vec4(0.0);
    ivec2 a0 = ivec2(floor(f_origin[k] + lo)), a1 = ivec2(floor(f_origin[k] + hi));
    int rows = int(f_size[k].y);
    float need = depth ? max(ceil((h / radius * 0.5 + 0.5) * 254.0) + 1.0, 1.0) - 0.5 : 0.5;  // the least byte at height h
    vec4 sum = vec4(0.0);
    for (int y = a0.y; y <= a1.y; ++y)
        for (int x = a0.x; x <= a1.x; ++x) {
            ivec2 at = ivec2(x, rows - 1 - y);
            vec4 c = k == 0 ? texelFetch(atlas0, at, 0) : k == 1 ? texelFetch(atlas1, at, 0) : texelFetch(atlas2, at, 0);
            float level = depth ? (k == 0 ? texelFetch(heights0, at, 0).a : k == 1 ? texelFetch(heights1, at, 0).a : texelFetch(heights2, at, 0).a)
                                : c.a;
            if (level * 255.0 >= need) {
                if (!mean) return vec4(0.0, 0.0, 0.0, 1.0);
                vec2 cover = max(min(vec2(x, y) + 1.0, f_origin[k] + hi) - max(vec2(x, y), f_origin[k] + lo), vec2(0.0));
                sum += (cover.x * cover.y + 1e-6) * vec4(c.rgb, 1.0);  // weighted by the texel's share of the footprint
            }
        }
    return sum;
}

bool footprint_hit(int k, vec2 t, float side, float h, bool depth) {
    return footprint_scan(k, t, side, h, depth, false).a > 0.0;
}

bool under_surface(int k, vec3 p, float dn) {  // p at or below frame k's surface (over the pixel's footprint where it spans more than a texel)
    float side = footprint(p, dn);
    if (side <= 1.0) return dot(p, f_dir[k]) <= height_at(k, frame_texel(k, p));
    return footprint_hit(k, frame_texel(k, p), side, dot(p, f_dir[k]), true);
}

float bottom_at(int k, vec3 p) {  // the column's bottom: the opposite frame's surface, as a height along f_dir[k]
    if (o_valid[k] == 0) return -1e30;
    vec2 t = vec2((dot(p, o_right[k]) / radius * 0.5 + 0.5) * frame_res, (0.5 - dot(p, o_up[k]) / radius * 0.5) * frame_res);
    if (!in_frame(t)) return -1e30;
    ivec2 a = ivec2(floor(o_origin[k] + t));
    ivec2 at = ivec2(a.x, int(o_size[k].y) - 1 - a.y);
    float level = (k == 0 ? texelFetch(opposite0, at, 0).a : k == 1 ? texelFetch(opposite1, at, 0).a : texelFetch(opposite2, at, 0).a) * 255.0;
    if (level < 0.5) return -1e30;  // the opposite frame saw nothing here: a one-sided column
    return -((level - 1.0) / 254.0 * 2.0 - 1.0) * radius;
}

void main() {
    vec3 ray = normalize(v_local - eye_local);
    vec3 rgb = vec3(0.0);
    vec3 normal = vec3(0.0);
    vec3 orm = vec3(0.0), emission = vec3(0.0);
    float weight = 0.0, along = 0.0;
    for (int k = 0; k < 3; ++k) {
        if (f_weight[k] <= 0.0) continue;
        float dn = dot(ray, f_dir[k]);
        if (dn > -1e-6) continue;  // the ray does not go into this frame's image
        float e0 = dot(eye_local, f_dir[k]);
        float t;
        float alpha;
        vec3 c;
        if (use_depth == 0) {
            t = -e0 / dn;  // the card plane through the centre
            vec2 tx = frame_texel(k, eye_local + t * ray);
            float side = footprint(eye_local + t * ray, dn);
            if (!in_frame(tx) && side <= 1.0) continue;  // a wider footprint may reach the frame's edge
            vec4 s = colour_at(k, clamp(tx, vec2(0.0), vec2(frame_res)));
            alpha = in_frame(tx) ? s.a : 0.0;
            c = s.rgb;
            if (side > 1.0 && alpha < 0.5) {  // not covered at the point: the mean colour of the covered texels over the footprint
                vec4 m = footprint_scan(k, tx, side, 0.0, false, true);
                if (m.a > 0.0) {
                    alpha = 1.0;
                    c = m.rgb / m.a;
                }
            }
        } else {
            float t_top = (radius - e0) / dn, t_bottom = (-radius - e0) / dn;
            vec3 lateral = (ray - dn * f_dir[k]) * (t_bottom - t_top);
            int steps = clamp(int(ceil(length(lateral) / radius * 0.5 * frame_res * 2.0)) + 2, 2, 1024);
            float before = t_top;
            bool hit = false;
            for (int s = 1; s <= steps; ++s) {
                float ts = mix(t_top, t_bottom, float(s) / float(steps));
                vec3 p = eye_local + ts * ray;
                if (under_surface(k, p, dn)) {
                    float lo = before, hi = ts;  // the crossing lies between: bisect
                    for (int b = 0; b < 8; ++b) {
                        float mid = 0.5 * (lo + hi);
                        vec3 q = eye_local + mid * ray;
                        if (under_surface(k, q, dn)) hi = mid; else lo = mid;
                    }
                    vec3 q = eye_local + hi * ray;
                    // Two-sided: a crossing under the column's bottom (the opposite frame's surface,
                    // less a depth step) passes beneath the part there; march on.
                    if (dot(q, f_dir[k]) >= bottom_at(k, q) - 2.0 * radius / 254.0) {
                        t = hi;
                        hit = true;
                        break;
                    }
                }
                before = ts;
            }
            if (!hit) continue;
            alpha = 1.0;
            vec3 q = eye_local + t * ray;
            float side = footprint(q, dn);
            bool held = height_at(k, frame_texel(k, q)) > -1e29;  // the hit's own texel holds the part
            vec4 m = side > 1.0 && !held ? footprint_scan(k, frame_texel(k, q), side, dot(q, f_dir[k]), true, true) : vec4(0.0);
            c = m.a > 0.0 ? m.rgb / m.a : colour_at(k, frame_texel(k, q)).rgb;  // else far: the mean of the texels it hit
        }
        rgb += f_weight[k] * alpha * c;
        vec2 at = frame_texel(k, eye_local + t * ray);
        if (normal_mode == 1) normal += f_weight[k] * alpha * normal_at(k, at);
        if (material_mode == 1) {
            orm += f_weight[k] * alpha * orm_at(k, at);
            emission += f_weight[k] * alpha * emission_at(k, at);
        }
        weight += f_weight[k] * alpha;
        along += f_weight[k] * alpha * t;
    }
    if (weight < 0.5) discard;
    vec3 p = eye_local + along / weight * ray;
    float z = (eye_from_local * vec4(p, 1.0)).z;
    float n = depth_range.x, f = depth_range.y;
    gl_FragDepth = 0.5 * ((f + n) / (f - n) - 2.0 * f * n / ((f - n) * z)) + 0.5;
    frag_color = vec4(linear_to_srgb(rgb / weight), 1.0);
    vec3 shading = normal_mode == 2 ? -ray : normal;
    bool none = normal_mode == 0 || dot(shading, shading) == 0.0;
    frag_normal = vec4(none ? vec3(0.0) : normalize(shading), 1.0);
    frag_material = vec4(orm / weight, 1.0);
    frag_emission = vec4(emission / weight, 1.0);
}
