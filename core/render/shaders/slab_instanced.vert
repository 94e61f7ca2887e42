#version 330
// One instance per (triangle, layer) pair, already clipped to the layer's closed depth slab and
// projected to texel coordinates on the CPU in float64 (core/recording.py, slab_instances): expand
// it into its texel-aligned bounding rectangle (gl_VertexID 0..3, a triangle strip) and hand the
// clipped polygon and the triangle to slab.frag, which decides coverage exactly.  Seed 000 §3.3.2.
uniform vec2 resolution;  // texels along u and v

in vec4 i_rect;      // texel rectangle x0, y0, x1, y1 (integers, clamped to the image)
in vec4 i_poly01;    // clipped polygon, texel coordinates: vertices 0 and 1
in vec4 i_poly23;    // vertices 2 and 3
in vec4 i_poly4;     // vertex 4, vertex count, unused
in vec3 i_tri0;      // triangle vertices: texel x, texel y, 1 / depth
in vec3 i_tri1;
in vec3 i_tri2;
in vec4 i_uv01;
in vec2 i_uv2;
#ifndef NORMAL_MAP
in vec4 i_color0;
in vec4 i_color1;
in vec4 i_color2;
#endif
#if defined(NORMALS) && !defined(NORMAL_MAP) && !defined(MATERIAL_UV_OWN)
in vec3 i_normal0;   // world shading normals at the triangle's vertices, turned to the reference viewpoint's side
in vec3 i_normal1;
in vec3 i_normal2;
#endif
#ifdef NORMALS
flat out vec3 g_normal[3];
#endif
#ifdef MATERIAL_UV_OWN
// An object whose material textures have a uv of their own (core/layering/recording.py,
// material_uv_source "own"): its normals (9 floats) and that uv (6) packed into four vec4, one
// float of padding, in the three vec3 inputs' place (the 16 vertex inputs allow no more).
in vec4 i_own0;
in vec4 i_own1;
in vec4 i_own2;
in vec4 i_own3;
flat out vec2 g_muv[3];
#endif
#ifdef NORMAL_MAP
// A GL guarantees 16 vertex inputs: an object with a normal map (and no vertex colours, whose
// inputs it reuses) packs its normals (9 floats), the map's uv (6) and the tangents with their
// handedness (12) into seven vec4 (core/layering/recording.py).
in vec4 i_map0;
in vec4 i_map1;
in vec4 i_map2;
in vec4 i_map3;
in vec4 i_map4;
in vec4 i_map5;
in vec4 i_map6;
flat out vec2 g_nuv[3];
flat out vec4 g_tangent[3];
#endif

flat out vec2 g_poly[5];
flat out vec3 g_edge[5];  // inward unit normal n and offset d of each edge: n . x + d >= 0 inside
flat out vec4 g_box;      // the polygon's bounding box lo.xy, hi.xy
flat out int g_solid;     // 1 where the polygon has area, so a texel centre can lie inside it
flat out vec3 g_tri[3];
flat out vec2 g_uv[3];
flat out vec4 g_color[3];

void main() {
    // Strip order (x0, y0), (x1, y0), (x0, y1), (x1, y1); mix with a bvec selects exactly.
    bvec2 upper = bvec2((gl_VertexID & 1) != 0, (gl_VertexID & 2) != 0);
    vec2 corner = mix(i_rect.xy, i_rect.zw, upper);
    gl_Position = vec4(corner / resolution * 2.0 - 1.0, 0.0, 1.0);
    g_poly[0] = i_poly01.xy;
    g_poly[1] = i_poly01.zw;
    g_poly[2] = i_poly23.xy;
    g_poly[3] = i_poly23.zw;
    g_poly[4] = i_poly4.xy;
    // Unused slots repeat vertex 0, so the five edges p[i] -> p[(i + 1) % 5] are the polygon's
    // edges plus zero-length ones, and slab.frag can run every loop over a constant five (which
    // the compiler unrolls) instead of the vertex count.  Edge equations are made here, four times
    // per instance, rather than for every texel.
    float area = 0.0;
    vec2 lo = g_poly[0], hi = g_poly[0];
    for (int i = 0; i < 5; ++i) {
        vec2 p = g_poly[i], q = g_poly[i == 4 ? 0 : i + 1];
        area += p.x * q.y - p.y * q.x;
        lo = min(lo, p);
        hi = max(hi, p);
    }
    float orientation = area < 0.0 ? -1.0 : 1.0;
    for (int i = 0; i < 5; ++i) {
        vec2 p = g_poly[i], e = g_poly[i == 4 ? 0 : i + 1] - p;
        vec2 n = orientation * vec2(-e.y, e.x);
        float len = length(n);
        n = len > 1e-12 ? n / len : vec2(0.0);  // a zero-length edge constrains nothing
        g_edge[i] = vec3(n, -dot(n, p));
    }
    g_box = vec4(lo, hi);
    g_solid = int(i_poly4.z) >= 3 && abs(area) > 1e-12 ? 1 : 0;
    g_tri[0] = i_tri0;
    g_tri[1] = i_tri1;
    g_tri[2] = i_tri2;
    g_uv[0] = i_uv01.xy;
    g_uv[1] = i_uv01.zw;
    g_uv[2] = i_uv2;
#ifdef NORMAL_MAP
    g_color[0] = vec4(1.0);
    g_color[1] = vec4(1.0);
    g_color[2] = vec4(1.0);
    g_normal[0] = i_map0.xyz;
    g_normal[1] = vec3(i_map0.w, i_map1.xy);
    g_normal[2] = vec3(i_map1.zw, i_map2.x);
    g_nuv[0] = i_map2.yz;
    g_nuv[1] = vec2(i_map2.w, i_map3.x);
    g_nuv[2] = i_map3.yz;
    g_tangent[0] = vec4(i_map3.w, i_map4.xyz);
    g_tangent[1] = vec4(i_map4.w, i_map5.xyz);
    g_tangent[2] = vec4(i_map5.w, i_map6.xyz);
#else
    g_color[0] = i_color0;
    g_color[1] = i_color1;
    g_color[2] = i_color2;
#if defined(MATERIAL_UV_OWN)
    g_normal[0] = i_own0.xyz;
    g_normal[1] = vec3(i_own0.w, i_own1.xy);
    g_normal[2] = vec3(i_own1.zw, i_own2.x);
    g_muv[0] = i_own2.yz;
    g_muv[1] = vec2(i_own2.w, i_own3.x);
    g_muv[2] = i_own3.yz;
#elif defined(NORMALS)
    g_normal[0] = i_normal0;
    g_normal[1] = i_normal1;
    g_normal[2] = i_normal2;
#endif
#endif
}
