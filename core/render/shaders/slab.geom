#version 330
// Clip a triangle to the layer's depth slab [slab.x, slab.y] (closed, in eye depth), project the
// clipped polygon to texel coordinates and emit its texel-aligned bounding rectangle; the fragment
// shader decides coverage exactly.  Seed 000 §3.3.2: every texel a clipped triangle touches must be
// written, and a clipping edge on a border touches the same texels from both sides because the
// closed slabs share that edge.
layout(triangles) in;
layout(triangle_strip, max_vertices = 4) out;

uniform vec2 half_tan;    // tan of the frustum's half angles along u and v
uniform vec2 resolution;  // texels along u and v
uniform vec2 slab;        // eye-depth range of this layer

in vec3 v_eye[];
in vec2 v_uv[];
in vec4 v_color[];

flat out vec2 g_poly[5];  // clipped polygon, texel coordinates
flat out int g_count;
flat out vec3 g_tri[3];   // triangle vertices: texel x, texel y, 1 / depth
flat out vec2 g_uv[3];
flat out vec4 g_color[3];

vec2 to_texel(vec3 e) {
    vec2 ndc = e.xy / (e.z * half_tan);
    return (ndc * 0.5 + 0.5) * resolution;
}

void main() {
    vec3 a[5];
    vec3 b[5];
    int na = 3;
    a[0] = v_eye[0]; a[1] = v_eye[1]; a[2] = v_eye[2];
    // Sutherland-Hodgman against z >= slab.x, then z <= slab.y.
    int nb = 0;
    for (int i = 0; i < na; ++i) {
        vec3 p = a[i], q = a[(i + 1) % na];
        bool pin = p.z >= slab.x, qin = q.z >= slab.x;
        if (pin) { b[nb++] = p; }
        if (pin != qin) { b[nb++] = mix(p, q, (slab.x - p.z) / (q.z - p.z)); }
    }
    na = 0;
    for (int i = 0; i < nb; ++i) {
        vec3 p = b[i], q = b[(i + 1) % nb];
        bool pin = p.z <= slab.y, qin = q.z <= slab.y;
        if (pin) { a[na++] = p; }
        if (pin != qin) { a[na++] = mix(p, q, (slab.y - p.z) / (q.z - p.z)); }
    }
    if (na == 0) { return; }

    vec2 lo = vec2(1e30), hi = vec2(-1e30);
    vec2 poly[5];
    for (int i = 0; i < 5; ++i) {
        if (i < na) {
            poly[i] = to_texel(a[i]);
            lo = min(lo, poly[i]);
            hi = max(hi, poly[i]);
        } else {
            poly[i] = poly[0];
        }
    }
    // Texels whose closed square meets [lo, hi]: from floor(lo) to floor(hi) inclusive, and one more
    // where a bound lies exactly on a texel edge.  Clamp to the image.
    vec2 x0 = clamp(floor(lo) - vec2(lessThanEqual(fract(lo), vec2(0.0))), vec2(0.0), resolution);
    vec2 x1 = clamp(floor(hi) + 1.0, vec2(0.0), resolution);
    if (x0.x >= x1.x || x0.y >= x1.y) { return; }
    vec2 ndc0 = x0 / resolution * 2.0 - 1.0;
    vec2 ndc1 = x1 / resolution * 2.0 - 1.0;

    vec2 corners[4] = vec2[4](vec2(ndc0.x, ndc0.y), vec2(ndc1.x, ndc0.y), vec2(ndc0.x, ndc1.y), vec2(ndc1.x, ndc1.y));
    for (int k = 0; k < 4; ++k) {
        for (int i = 0; i < 5; ++i) { g_poly[i] = poly[i]; }
        g_count = na;
        for (int i = 0; i < 3; ++i) {
            g_tri[i] = vec3(to_texel(v_eye[i]), 1.0 / v_eye[i].z);
            g_uv[i] = v_uv[i];
            g_color[i] = v_color[i];
        }
        gl_Position = vec4(corners[k], 0.0, 1.0);
        EmitVertex();
    }
    EndPrimitive();
}
