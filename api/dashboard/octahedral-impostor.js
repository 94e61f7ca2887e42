// farfield's octahedral impostor runtime for three.js (WebGL 2): an ES module with no dependency
// but three.js, to copy into an engine built on it.  docs/techniques/octahedral.md ("The GLB",
// "three.js") says what it does; core/techniques/octahedral/runtime.py and shaders/octahedral.frag
// are the reference it follows (tests/test_octahedral_threejs.py draws both and compares them).
//
//   import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";
//   import { octahedralImpostors } from "./octahedral-impostor.js";
//   const gltf = await new GLTFLoader().loadAsync("impostor.glb");
//   await octahedralImpostors(gltf);  // each card carrying FARFIELD_octahedral_impostor is replaced
//   scene.add(gltf.scene);
//
// A GLB's card primitive carries the frame grid in the extension FARFIELD_octahedral_impostor
// (in extensionsUsed, never required: a viewer without this module draws the fallback, the frame
// nearest the bake's reference viewpoint as one card).  The card may be drawn once per instance
// (EXT_mesh_gpu_instancing: GLTFLoader's InstancedMesh; one prototype's bake for many instances).
// Per draw the eye is taken into the object's frame (on the CPU, float64); the rest happens per
// instance on the GPU, in the vertex shader: the eye taken into the instance's own frame
// (instanceMatrix: rotation, uniform scale, translation) gives the view direction (the part's
// centre to the eye), which picks the three frames of its octahedral grid triangle and their
// barycentric weights (core/techniques/octahedral/mapping.py; a grid whose frames were turned, a
// moved instance's, is looked up by the view turned back: instancing.py's
// grid_rotation), and one square card through the centre faces the eye.  Per fragment the eye ray
// meets each frame (its card plane, or with depth its height field: a ray march, the parallax
// correction, ending at the opposite frame's surface where the grid has one); the colours are
// blended in linear light by weight x coverage, cut at 0.5, and the blended hit point's depth is
// written (gl_FragDepth).  The frames' axes, first texels, pages and opposite frames are a float
// data texture the shaders read.  Assumes the object's world transform and each instance's matrix
// are a rotation, a uniform scale and a translation, and a perspective camera with the standard
// (not logarithmic, not reversed) depth buffer.
import * as THREE from "three";

export const OCTAHEDRAL_EXTENSION = "FARFIELD_octahedral_impostor";
const INSIDE_HALF_SIDE = 1e3; // runtime.py: an eye inside the sphere sees a card this many radii wide
const DEPTH_LEVELS = 254; // frames.py: depth byte 1..255 = height -r..r above the card plane

// ---------------------------------------------------------------- the octahedral map (mapping.py)

/** Map coordinates [u, v] in [0, 1]² of a direction [x, y, z] (need not be unit): mapping.encode. */
export function encodeDirection(d, hemisphere) {
  const s = Math.abs(d[0]) + Math.abs(d[1]) + Math.abs(d[2]);
  let x = d[0] / s, y = d[1] / s;
  const z = d[2] / s;
  let u, v;
  if (hemisphere) {
    if (z < 0) { // below the horizon: clamped onto it (straight down onto its +x point)
      let ring = Math.abs(x) + Math.abs(y);
      if (ring === 0) { x = 1; ring = 1; }
      x /= ring; y /= ring;
    }
    u = x + y; v = x - y;
  } else if (z < 0) { // the lower half, folded over the square's corners
    u = (1 - Math.abs(y)) * (x >= 0 ? 1 : -1);
    v = (1 - Math.abs(x)) * (y >= 0 ? 1 : -1);
  } else {
    u = x; v = y;
  }
  const clamp = (t) => Math.min(1, Math.max(0, t));
  return [clamp(u * 0.5 + 0.5), clamp(v * 0.5 + 0.5)];
}

/** The unit direction [x, y, z] of map coordinates [u, v] in [0, 1]² (inverse of encodeDirection): mapping.decode. */
export function decodeDirection(uv, hemisphere) {
  const f = [uv[0] * 2 - 1, uv[1] * 2 - 1];
  let x, y, z;
  if (hemisphere) {
    x = 0.5 * (f[0] + f[1]); y = 0.5 * (f[0] - f[1]);
    z = 1 - Math.abs(x) - Math.abs(y);
  } else {
    z = 1 - Math.abs(f[0]) - Math.abs(f[1]);
    const t = Math.max(-z, 0); // the lower half: folded back
    x = f[0] - (f[0] >= 0 ? t : -t); y = f[1] - (f[1] >= 0 ? t : -t);
  }
  const length = Math.hypot(x, y, z);
  return [x / length, y / length, z / length];
}

/** The three frames around a view direction and their barycentric weights: mapping.blend_frames
 *  (on the CPU, for a caller that wants them; the module's vertex shader does the same per instance). */
export function blendFrames(direction, n, hemisphere) {
  const [u, v] = encodeDirection(direction, hemisphere);
  const gx = u * (n - 1), gy = v * (n - 1);
  const i = Math.min(Math.floor(gx), n - 2), j = Math.min(Math.floor(gy), n - 2);
  const fx = gx - i, fy = gy - j;
  const upper = fx + fy > 1;
  const frames = [upper ? (j + 1) * n + i + 1 : j * n + i, j * n + i + 1, (j + 1) * n + i];
  const weights = upper ? [fx + fy - 1, 1 - fy, 1 - fx] : [1 - fx - fy, fx, fy];
  return {frames, weights: weights.map((w) => Math.min(1, Math.max(0, w)))};
}

// ---------------------------------------------------------------- the program (octahedral.vert/.frag)

// The frame table (frameTable): a float RGBA texture of n x 4n texels, frame f = j n + i at column
// i, rows j + k n: k = 0 (right, first texel x), 1 (up, first texel y), 2 (direction, page),
// 3 (opposite frame or -1, 0, 0, 0); axes in the card node's frame.
const TABLE_ROWS = 4;

const VERTEX = /* glsl */ `
uniform vec3 centre;            // the part's centre, the card node's frame
uniform int grid_n;
uniform int hemisphere;      // 1: the hemi-octahedral map
uniform vec3 eye_object;        // the eye in the card node's frame (before any instance's matrix), float64 on the CPU
uniform mat3 grid_from_object;  // R^T: a turned grid's frames (R d_k) are picked by the view turned back
uniform float pixel_angle;      // a pixel's side per unit of distance: 2 tan(fov / 2) / the target's height
varying vec3 v_local;           // the card point relative to the centre, the instance's frame
flat varying vec3 v_eye;        // the eye relative to the centre, the instance's frame
flat varying ivec3 v_frames;    // the three blended frames
flat varying vec3 v_weights;    // and their weights
flat varying mat4 v_clip;       // clip space from the instance's frame

vec2 encode_direction(vec3 d) { // mapping.encode
  vec3 p = d / (abs(d.x) + abs(d.y) + abs(d.z));
  vec2 uv = p.xy;
  if (hemisphere == 1) {
    if (p.z < 0.0) { // below the horizon: clamped onto it (straight down onto its +x point)
      float ring = abs(p.x) + abs(p.y);
      uv = ring == 0.0 ? vec2(1.0, 0.0) : p.xy / ring;
    }
    uv = vec2(uv.x + uv.y, uv.x - uv.y);
  } else if (p.z < 0.0) { // the lower half, folded over the square's corners
    uv = (1.0 - abs(p.yx)) * vec2(p.x >= 0.0 ? 1.0 : -1.0, p.y >= 0.0 ? 1.0 : -1.0);
  }
  return clamp(uv * 0.5 + 0.5, 0.0, 1.0);
}

void main() {
#ifdef USE_INSTANCING
  mat4 view_from_object = modelViewMatrix * instanceMatrix;
  // the eye in the instance's frame: instanceMatrix (s R, t) undone, x = R^T (y - t) / s (exact for the identity)
  mat3 linear = mat3(instanceMatrix);
  vec3 eye = transpose(linear) * (eye_object - instanceMatrix[3].xyz) / dot(linear[0], linear[0]) - centre;
#else
  mat4 view_from_object = modelViewMatrix;
  vec3 eye = eye_object - centre;
#endif
  // the card: through the centre, facing the eye, covering the sphere's silhouette (runtime.card_corners)
  float distance = length(eye);
  vec3 w = -eye / distance;
  vec3 hint = abs(w.z) < 0.99 ? vec3(0.0, 0.0, 1.0) : vec3(0.0, 1.0, 0.0);
  vec3 a = normalize(cross(w, hint));
  vec3 b = cross(a, w);
  // grown by a pixel: a part smaller than a pixel still meets a pixel centre
  float half_side = (distance > radius * 1.0001 ? radius * distance / sqrt(distance * distance - radius * radius)
                                                : ${INSIDE_HALF_SIDE.toFixed(1)} * radius) + distance * pixel_angle;
  v_local = half_side * (position.x * a + position.y * b);
  v_eye = eye;
  // the three frames around the view direction and their weights (mapping.blend_frames)
  vec2 g = encode_direction(grid_from_object * eye) * float(grid_n - 1);
  ivec2 cell = min(ivec2(floor(g)), ivec2(grid_n - 2));
  vec2 f = g - vec2(cell);
  int i = cell.x, j = cell.y, n = grid_n;
  bool upper = f.x + f.y > 1.0;
  v_frames = ivec3(upper ? (j + 1) * n + i + 1 : j * n + i, j * n + i + 1, (j + 1) * n + i);
  v_weights = clamp(upper ? vec3(f.x + f.y - 1.0, 1.0 - f.y, 1.0 - f.x) : vec3(1.0 - f.x - f.y, f.x, f.y), 0.0, 1.0);
  v_clip = projectionMatrix * view_from_object;
  gl_Position = v_clip * vec4(centre + v_local, 1.0);
}`;

/** GLSL reading page ``page`` (a uniform int or a frame's) of the colour pages (``colour<p>``:
 *  sRGB textures, filtered in linear light) and the normal pages (``normal<p>``: alpha = depth
 *  byte): GLSL ES 3.0 indexes samplers by constants alone, so each page is a branch. */
function pageReaders(pages, depth) {
  const range = [...Array(pages).keys()];
  const branches = (body) => range.map((p) => `  if (page == ${p}) return ${body(p)};`).join("\n");
  let out = range.map((p) => `uniform sampler2D colour${p};`).join("\n");
  out += `
vec2 page_size(int page) {
${branches((p) => `vec2(textureSize(colour${p}, 0))`)}
  return vec2(1.0);
}
vec4 colour_sample(int page, vec2 uv) { // bilinear; glTF textures: v = 0 is the page's top row
${branches((p) => `textureLod(colour${p}, uv, 0.0)`)}
  return vec4(0.0);
}
vec4 colour_texel(int page, ivec2 at) {
${branches((p) => `texelFetch(colour${p}, at, 0)`)}
  return vec4(0.0);
}`;
  if (depth) {
    out += "\n" + range.map((p) => `uniform sampler2D normal${p};`).join("\n");
    out += `
vec4 normal_texel(int page, ivec2 at) {
${branches((p) => `texelFetch(normal${p}, at, 0)`)}
  return vec4(0.0);
}`;
  }
  return out;
}

const FRAGMENT = /* glsl */ `
uniform highp sampler2D frame_table;
uniform int grid_n;
uniform vec3 centre;
uniform float radius;
uniform float frame_res;
uniform float pixel_angle;
varying vec3 v_local;
flat varying vec3 v_eye;
flat varying ivec3 v_frames;
flat varying vec3 v_weights;
flat varying mat4 v_clip;

struct Frame {
  vec3 right, up, dir;
  vec2 origin; // its first texel (x right, y down)
  int page;
  int opposite; // the frame looking the opposite way, -1 where none
};

Frame frame_of(int f) {
  ivec2 at = ivec2(f % grid_n, f / grid_n);
  vec4 r0 = texelFetch(frame_table, at, 0), r1 = texelFetch(frame_table, at + ivec2(0, grid_n), 0);
  vec4 r2 = texelFetch(frame_table, at + ivec2(0, 2 * grid_n), 0), r3 = texelFetch(frame_table, at + ivec2(0, 3 * grid_n), 0);
  return Frame(r0.xyz, r1.xyz, r2.xyz, vec2(r0.w, r1.w), int(r2.w + 0.5), int(floor(r3.x + 0.5)));
}

vec2 frame_texel(Frame f, vec3 p) {
  return vec2((dot(p, f.right) / radius * 0.5 + 0.5) * frame_res, (0.5 - dot(p, f.up) / radius * 0.5) * frame_res);
}

bool in_frame(vec2 t) {
  return all(greaterThanEqual(t, vec2(0.0))) && all(lessThan(t, vec2(frame_res)));
}

vec4 colour_at(Frame f, vec2 t) { return colour_sample(f.page, (f.origin + t) / page_size(f.page)); }

float footprint(vec3 p, float dn) { // the side of a square of frame texels holding a pixel's beam at p
  // (a pixel's side turned by any angle: sqrt(2); seen along a frame dn = cos away: 1 / dn)
  return length(p - v_eye) * pixel_angle / (2.0 * radius / frame_res) * 1.41421356 / max(-dn, 0.1);
}

#ifdef USE_DEPTH
float level_of(vec4 texel, float covered);
#endif

// The texels of frame f within the footprint (side texels a side) at t that hold the part (with
// depth: whose surface is at height h or above): their linear colour and count summed, each
// weighted by its share of the footprint (mean), or (0, 0, 0, 1) at the first one (else 0); where a
// pixel spans more than a texel.
vec4 footprint_scan(Frame f, vec2 t, float side, float h, bool mean) {
  vec2 lo = max(t - 0.5 * side, vec2(0.0)), hi = min(t + 0.5 * side, vec2(frame_res - 1e-3));
  if (any(greaterThan(lo, hi))) return vec4(0.0);
  ivec2 a0 = ivec2(floor(f.origin + lo)), a1 = ivec2(floor(f.origin + hi));
#ifdef USE_DEPTH
  float need = max(ceil((h / radius * 0.5 + 0.5) * ${DEPTH_LEVELS.toFixed(1)}) + 1.0, 1.0) - 0.5; // the least byte at height h
#endif
  vec4 sum = vec4(0.0);
  for (int y = a0.y; y <= a1.y; ++y)
    for (int x = a0.x; x <= a1.x; ++x) {
      ivec2 at = ivec2(x, y);
      vec4 c = colour_texel(f.page, at);
#ifdef USE_DEPTH
      bool held = level_of(normal_texel(f.page, at), c.a) >= need;
#else
      bool held = c.a >= 0.5;
#endif
      if (held) {
        if (!mean) return vec4(0.0, 0.0, 0.0, 1.0);
        vec2 cover = max(min(vec2(x, y) + 1.0, f.origin + hi) - max(vec2(x, y), f.origin + lo), vec2(0.0));
        sum += (cover.x * cover.y + 1e-6) * vec4(c.rgb, 1.0);  // weighted by the texel's share of the footprint
      }
    }
  return sum;
}

bool footprint_hit(Frame f, vec2 t, float side, float h) { return footprint_scan(f, t, side, h, false).a > 0.0; }

#ifdef USE_DEPTH
// A texel holds a surface where its colour's alpha says so (its depth byte is then 1..255, 0
// elsewhere): the same as the depth byte's 0 for PNG pages, and robust where a KTX2 page's codec
// turns a 0 into a few levels (a surface at the slab's bottom that is not there).
float level_of(vec4 texel, float covered) { return covered < 0.5 ? 0.0 : max(texel.a * 255.0, 1.0); }

float level_at(Frame f, vec2 t) { // the depth byte where frame f saw the part, 0 where it saw nothing
  if (!in_frame(t)) return 0.0;
  ivec2 at = ivec2(floor(f.origin + t));
  return level_of(normal_texel(f.page, at), colour_texel(f.page, at).a);
}

float height_at(Frame f, vec2 t) { // the surface's height above the card plane; -1e30 where none
  float level = level_at(f, t);
  if (level < 0.5) return -1e30;
  return ((level - 1.0) / ${DEPTH_LEVELS.toFixed(1)} * 2.0 - 1.0) * radius;
}

bool under_surface(Frame f, vec3 p, float dn) { // p at or below f's surface (over the pixel's footprint where it spans more than a texel)
  float side = footprint(p, dn);
  if (side <= 1.0) return dot(p, f.dir) <= height_at(f, frame_texel(f, p));
  return footprint_hit(f, frame_texel(f, p), side, dot(p, f.dir));
}

float bottom_at(Frame o, bool valid, vec3 p) { // the column's bottom: the opposite frame's surface, as a height along the frame's direction
  if (!valid) return -1e30;
  float level = level_at(o, frame_texel(o, p));
  if (level < 0.5) return -1e30; // the opposite frame saw nothing here: a one-sided column
  return -((level - 1.0) / ${DEPTH_LEVELS.toFixed(1)} * 2.0 - 1.0) * radius;
}
#endif

void main() {
  vec3 ray = normalize(v_local - v_eye);
  vec3 rgb = vec3(0.0);
  float weight = 0.0, along = 0.0;
  for (int k = 0; k < 3; ++k) {
    float wk = v_weights[k];
    if (wk <= 0.0) continue;
    Frame f = frame_of(v_frames[k]);
    float dn = dot(ray, f.dir);
    if (dn > -1e-6) continue; // the ray does not go into this frame's image
    float e0 = dot(v_eye, f.dir);
    float t;
    float alpha;
    vec3 c;
#ifndef USE_DEPTH
    t = -e0 / dn; // the card plane through the centre
    vec2 tx = frame_texel(f, v_eye + t * ray);
    float side = footprint(v_eye + t * ray, dn);
    if (!in_frame(tx) && side <= 1.0) continue; // a wider footprint may reach the frame's edge
    vec4 s = colour_at(f, clamp(tx, vec2(0.0), vec2(frame_res)));
    alpha = in_frame(tx) ? s.a : 0.0;
    c = s.rgb;
    if (side > 1.0 && alpha < 0.5) { // not covered at the point: the mean colour of the covered texels over the footprint
      vec4 m = footprint_scan(f, tx, side, 0.0, true);
      if (m.a > 0.0) {
        alpha = 1.0;
        c = m.rgb / m.a;
      }
    }
#else
    // the height field: march from the slab's top to its bottom, half a texel a step, then bisect
    bool two_sided = f.opposite >= 0;
    Frame o = frame_of(two_sided ? f.opposite : v_frames[k]);
    float t_top = (radius - e0) / dn, t_bottom = (-radius - e0) / dn;
    vec3 lateral = (ray - dn * f.dir) * (t_bottom - t_top);
    int steps = clamp(int(ceil(length(lateral) / radius * 0.5 * frame_res * 2.0)) + 2, 2, 1024);
    float before = t_top;
    bool hit = false;
    for (int s = 1; s <= steps; ++s) {
      float ts = mix(t_top, t_bottom, float(s) / float(steps));
      vec3 p = v_eye + ts * ray;
      if (under_surface(f, p, dn)) {
        float lo = before, hi = ts;
        for (int b = 0; b < 8; ++b) {
          float mid = 0.5 * (lo + hi);
          vec3 q = v_eye + mid * ray;
          if (under_surface(f, q, dn)) hi = mid; else lo = mid;
        }
        vec3 q = v_eye + hi * ray;
        // two-sided: a crossing under the column's bottom (less a depth step) passes beneath the part
        if (dot(q, f.dir) >= bottom_at(o, two_sided, q) - 2.0 * radius / ${DEPTH_LEVELS.toFixed(1)}) {
          t = hi;
          hit = true;
          break;
        }
      }
      before = ts;
    }
    if (!hit) continue;
    alpha = 1.0;
    vec3 q = v_eye + t * ray;
    float side = footprint(q, dn);
    bool held = level_at(f, frame_texel(f, q)) > 0.5; // the hit's own texel holds the part
    vec4 m = side > 1.0 && !held ? footprint_scan(f, frame_texel(f, q), side, dot(q, f.dir), true) : vec4(0.0);
    c = m.a > 0.0 ? m.rgb / m.a : colour_at(f, frame_texel(f, q)).rgb; // else far: the mean of the texels it hit
#endif
    rgb += wk * alpha * c;
    weight += wk * alpha;
    along += wk * alpha * t;
  }
  if (weight < 0.5) discard;
  vec3 p = v_eye + along / weight * ray; // the blended hit point: its depth is written
  vec4 clip = v_clip * vec4(centre + p, 1.0);
  gl_FragDepth = 0.5 * clip.z / clip.w + 0.5;
  gl_FragColor = vec4(rgb / weight, 1.0);
  #include <colorspace_fragment>
}`;

// ---------------------------------------------------------------- the grid, read from a GLB

function prepared(texture, colour) {
  // A page as the reference samples it: colour bilinear in linear light, normal/depth texels
  // exactly (nearest); no mipmaps (a frame's cell would bleed into its neighbours' beyond the padding).
  const t = texture.clone();
  t.colorSpace = colour ? THREE.SRGBColorSpace : THREE.NoColorSpace;
  t.minFilter = t.magFilter = colour ? THREE.LinearFilter : THREE.NearestFilter;
  t.wrapS = t.wrapT = THREE.ClampToEdgeWrapping;
  t.generateMipmaps = false;
  t.needsUpdate = true;
  return t;
}

function oppositeFrames(axes, count) {
  // Each frame's opposite frame (direction -d; float32 axes), -1 where none (runtime.py).
  const opposite = new Int32Array(count).fill(-1);
  for (let a = 0; a < count; a++) {
    for (let b = 0; b < count; b++) {
      const dot = axes[9 * a + 6] * axes[9 * b + 6] + axes[9 * a + 7] * axes[9 * b + 7] + axes[9 * a + 8] * axes[9 * b + 8];
      if (dot < -1 + 1e-5) { opposite[a] = b; break; }
    }
  }
  return opposite;
}

/** The rotation R (a THREE.Matrix3) that carries the grid's own frame directions (mapping.py's
 *  frame_directions) onto the frames' directions in ``axes`` (float32, 9 a frame: right, up,
 *  direction): instancing.py's grid_rotation, from two frames far from parallel; the identity
 *  where they are the grid's own (a bake in place, or a prototype's card drawn per instance). */
export function gridRotation(axes, n, hemisphere) {
  const own = (f) => decodeDirection([(f % n) / (n - 1), Math.floor(f / n) / (n - 1)], hemisphere);
  const found = (f) => [axes[9 * f + 6], axes[9 * f + 7], axes[9 * f + 8]];
  const count = n * n;
  let moved = false;
  for (let f = 0; f < count && !moved; f++) {
    const [d, e] = [own(f), found(f)];
    moved = Math.abs(d[0] - e[0]) + Math.abs(d[1] - e[1]) + Math.abs(d[2] - e[2]) > 1e-5;
  }
  if (!moved) return new THREE.Matrix3();
  const vector = (v) => new THREE.Vector3(...v);
  let other = 1, best = -1;
  for (let f = 1; f < count; f++) {
    const across = vector(own(0)).cross(vector(own(f))).length();
    if (across > best) { best = across; other = f; }
  }
  const basis = (u, v) => { // an orthonormal basis of the two directions, as a matrix's columns
    const e1 = vector(u).normalize();
    const e2 = vector(v).addScaledVector(e1, -e1.dot(vector(v))).normalize();
    return new THREE.Matrix3().set(...[0, 1, 2].flatMap((row) => [e1, e2, new THREE.Vector3().crossVectors(e1, e2)].map((e) => e.getComponent(row))));
  };
  const from = basis(own(0), own(other)), to = basis(found(0), found(other));
  return to.multiply(from.transpose());
}

function frameTable(grid) {
  // the frame table the shaders read (TABLE_ROWS): see its comment above
  const n = grid.n, rows = TABLE_ROWS * n, data = new Float32Array(4 * n * rows);
  const put = (f, row, values) => data.set(values, 4 * ((row * n + Math.floor(f / n)) * n + (f % n)));
  for (let f = 0; f < n * n; f++) {
    const a = grid.axes;
    put(f, 0, [a[9 * f], a[9 * f + 1], a[9 * f + 2], grid.texels[2 * f]]);
    put(f, 1, [a[9 * f + 3], a[9 * f + 4], a[9 * f + 5], grid.texels[2 * f + 1]]);
    put(f, 2, [a[9 * f + 6], a[9 * f + 7], a[9 * f + 8], grid.pages[f]]);
    put(f, 3, [grid.depth ? grid.opposite[f] : -1, 0, 0, 0]);
  }
  const table = new THREE.DataTexture(data, n, rows, THREE.RGBAFormat, THREE.FloatType);
  table.minFilter = table.magFilter = THREE.NearestFilter;
  table.needsUpdate = true;
  return table;
}

/** The frame grid of one FARFIELD_octahedral_impostor extension (``extension``), its accessors
 *  and textures loaded through ``parser`` (a GLTFLoader's GLTFParser: ``gltf.parser``), with what
 *  the shaders read: each frame's opposite frame, the grid's rotation (gridRotation) and the frame
 *  table (a THREE.DataTexture). */
export async function readGrid(parser, extension) {
  const accessor = async (index) => (await parser.getDependency("accessor", index)).array;
  const textures = async (indices, colour) =>
    Promise.all((indices || []).map(async (index) => prepared(await parser.getDependency("texture", index), colour)));
  const [axes, texels, pages, colour, normal] = await Promise.all([
    accessor(extension.frames.axes), accessor(extension.frames.texels), accessor(extension.frames.pages),
    textures(extension.pages.colour, true), textures(extension.pages.normal, false),
  ]);
  const n = extension.grid, hemisphere = !!extension.hemisphere;
  const grid = {
    n, hemisphere, frameResolution: extension.frameResolution,
    padding: extension.padding, depth: !!extension.depth && normal.length > 0,
    centre: new THREE.Vector3(...extension.centre), radius: extension.radius,
    axes, texels, pages, colour, normal,
    opposite: oppositeFrames(axes, n * n), rotation: gridRotation(axes, n, hemisphere),
  };
  grid.table = frameTable(grid);
  return grid;
}

function cardGeometry(grid) {
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute("position", new THREE.Float32BufferAttribute([-1, -1, 0, 1, -1, 0, 1, 1, 0, -1, 1, 0], 3));
  geometry.setIndex([0, 1, 2, 0, 2, 3]);
  if (grid) { // frustum culling (each instance's, moved): what shows lies inside the sphere
    geometry.boundingSphere = new THREE.Sphere(grid.centre.clone(), grid.radius);
    geometry.boundingBox = new THREE.Box3().setFromCenterAndSize(grid.centre, new THREE.Vector3().setScalar(2 * grid.radius));
  }
  return geometry;
}

function cardMaterial(grid) {
  const uniforms = {
    centre: {value: grid.centre.clone()}, radius: {value: grid.radius}, frame_res: {value: grid.frameResolution},
    grid_n: {value: grid.n}, hemisphere: {value: grid.hemisphere ? 1 : 0},
    eye_object: {value: new THREE.Vector3()}, pixel_angle: {value: 0.0}, grid_from_object: {value: grid.rotation.clone().transpose()}, frame_table: {value: grid.table},
  };
  grid.colour.forEach((page, p) => { uniforms[`colour${p}`] = {value: page}; });
  if (grid.depth) grid.normal.forEach((page, p) => { uniforms[`normal${p}`] = {value: page}; });
  const readers = pageReaders(grid.colour.length, grid.depth);
  return new THREE.ShaderMaterial({
    uniforms, vertexShader: `uniform float radius;\n${VERTEX}`,
    fragmentShader: FRAGMENT.replace("struct Frame", `${readers}\n\nstruct Frame`),
    defines: grid.depth ? {USE_DEPTH: ""} : {}, side: THREE.DoubleSide,
  });
}

/** The texture units one impostor's program takes: its pages' (colour, and normal with depth) and the frame table. */
function textureUnits(grid) {
  return grid.colour.length * (grid.depth ? 2 : 1) + 1;
}

/** Octahedral impostors: a camera-facing card (a THREE.InstancedMesh with a ShaderMaterial) that
 *  blends the three frames around the view direction, once per instance (``count`` instances,
 *  their matrices in ``instanceMatrix``; one, the identity, for a card drawn once).  ``grid``: what
 *  readGrid returns.  Clones share the grid, the card and the material (each draw sets the eye
 *  uniform before it is made). */
export class OctahedralImpostor extends THREE.InstancedMesh {
  constructor(grid = null, count = 1) {
    super(cardGeometry(grid), grid ? cardMaterial(grid) : undefined, count);
    this.isOctahedralImpostor = true;
    this.grid = grid;
    this.fallback = null; // the GLB's card this replaced (octahedralImpostors)
  }

  copy(source, recursive) {
    super.copy(source, recursive);
    this.grid = source.grid;
    this.fallback = source.fallback;
    return this;
  }

  /** Free the card, its program, the grid's pages and frame table (every clone shares them) and the instances' matrices. */
  dispose() {
    this.geometry.dispose();
    this.material.dispose();
    for (const texture of [...(this.grid?.colour || []), ...(this.grid?.normal || [])]) texture.dispose();
    this.grid?.table.dispose();
    return super.dispose();
  }

  onBeforeRender(renderer, scene, camera) {
    if (!this.grid) return;
    if (textureUnits(this.grid) > renderer.capabilities.maxTextures) {
      throw new Error(`an octahedral impostor of ${this.grid.colour.length} pages needs ${textureUnits(this.grid)} ` +
        `texture units; this GPU has ${renderer.capabilities.maxTextures} (bake with a larger max_page)`);
    }
    // the eye in the object's frame, in float64 (a view direction on a grid line stays on it)
    this.worldToLocal(this.material.uniforms.eye_object.value.setFromMatrixPosition(camera.matrixWorld));
    // a pixel's side per unit of distance (a perspective camera: projectionMatrix[5] = 1 / tan(fov / 2))
    const target = renderer.getRenderTarget();
    const height = target ? target.height : renderer.getDrawingBufferSize(new THREE.Vector2()).y;
    this.material.uniforms.pixel_angle.value = 2.0 / (camera.projectionMatrix.elements[5] * height);
    this.material.uniformsNeedUpdate = true; // clones share the material: upload it for this draw
  }
}

/** Replace every card of ``gltf`` (GLTFLoader's result) that carries FARFIELD_octahedral_impostor
 *  by an OctahedralImpostor in its place (its transform, name and userData, and its instances where
 *  EXT_mesh_gpu_instancing draws it more than once; the card it replaces as its ``fallback``).
 *  Resolves to the impostors made (none: the GLB has no such card). */
export async function octahedralImpostors(gltf) {
  const cards = [];
  gltf.scene.traverse((node) => {
    if (node.isMesh && node.userData.gltfExtensions?.[OCTAHEDRAL_EXTENSION]) cards.push(node);
  });
  const made = [];
  for (const card of cards) {
    const grid = await readGrid(gltf.parser, card.userData.gltfExtensions[OCTAHEDRAL_EXTENSION]);
    const impostor = new OctahedralImpostor(grid, card.isInstancedMesh ? card.count : 1);
    if (card.isInstancedMesh) impostor.instanceMatrix.copy(card.instanceMatrix);
    impostor.name = card.name;
    impostor.position.copy(card.position);
    impostor.quaternion.copy(card.quaternion);
    impostor.scale.copy(card.scale);
    impostor.userData = {...card.userData};
    impostor.fallback = card;
    for (const child of [...card.children]) impostor.add(child);
    const parent = card.parent;
    parent.children[parent.children.indexOf(card)] = impostor;
    impostor.parent = parent;
    card.parent = null;
    made.push(impostor);
  }
  gltf.scene.updateMatrixWorld(true);
  return made;
}
