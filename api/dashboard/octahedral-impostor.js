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
// nearest the bake's reference viewpoint as one card).  Per draw, the view direction (the part's
// centre to the eye, in the object's frame) picks the three frames of its octahedral grid
// triangle and their barycentric weights (core/techniques/octahedral/mapping.py); one square card
// through the centre faces the eye; per fragment the eye ray meets each frame (its card plane, or
// with depth its height field: a ray march, the parallax correction, ending at the opposite
// frame's surface where the grid has one); the colours are blended in linear light by
// weight x coverage, cut at 0.5, and the blended hit point's depth is written (gl_FragDepth).
// Assumes the object's world transform is a rotation, a uniform scale and a translation, and a
// perspective camera with the standard (not logarithmic, not reversed) depth buffer.
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

/** The three frames around a view direction and their barycentric weights: mapping.blend_frames. */
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

const VERTEX = /* glsl */ `
uniform vec3 centre;   // the part's centre, object frame
uniform vec3 card_a;   // the card's half-side vectors, object frame
uniform vec3 card_b;
varying vec3 v_local;  // relative to the centre
void main() {
  v_local = position.x * card_a + position.y * card_b;
  gl_Position = projectionMatrix * modelViewMatrix * vec4(centre + v_local, 1.0);
}`;

const FRAGMENT = /* glsl */ `
uniform mat4 projectionMatrix;
uniform mat4 modelViewMatrix;
uniform sampler2D atlas0;     // each blended frame's colour page (sRGB texture: filtered in linear light)
uniform sampler2D atlas1;
uniform sampler2D atlas2;
uniform sampler2D heights0;   // and its normal page: alpha = depth byte (0: nothing)
uniform sampler2D heights1;
uniform sampler2D heights2;
uniform sampler2D opposite0;  // the normal page of each blended frame's opposite frame
uniform sampler2D opposite1;
uniform sampler2D opposite2;
uniform sampler2D o_atlas0;   // and its colour page (alpha: where it saw the part)
uniform sampler2D o_atlas1;
uniform sampler2D o_atlas2;
uniform vec3 centre;
uniform vec3 eye_local;       // the eye relative to the centre, object frame
uniform vec3 f_right[3];
uniform vec3 f_up[3];
uniform vec3 f_dir[3];
uniform vec2 f_origin[3];     // first texel of each frame (x right, y down)
uniform vec2 f_size[3];       // its page, texels (width, height)
uniform float f_weight[3];
uniform int o_valid[3];       // 1: the frame has an opposite frame (a two-sided column)
uniform vec3 o_right[3];
uniform vec3 o_up[3];
uniform vec2 o_origin[3];
uniform vec2 o_size[3];
uniform float radius;
uniform float frame_res;
uniform int use_depth;
varying vec3 v_local;

vec2 frame_texel(int k, vec3 p) {
  return vec2((dot(p, f_right[k]) / radius * 0.5 + 0.5) * frame_res, (0.5 - dot(p, f_up[k]) / radius * 0.5) * frame_res);
}

bool in_frame(vec2 t) {
  return all(greaterThanEqual(t, vec2(0.0))) && all(lessThan(t, vec2(frame_res)));
}

vec4 colour_at(int k, vec2 t) { // bilinear; glTF textures: v = 0 is the page's top row
  vec2 uv = (f_origin[k] + t) / f_size[k];
  if (k == 0) return texture(atlas0, uv);
  if (k == 1) return texture(atlas1, uv);
  return texture(atlas2, uv);
}

// A texel holds a surface where its colour's alpha says so (its depth byte is then 1..255, 0
// elsewhere): the same as the depth byte's 0 for PNG pages, and robust where a KTX2 page's codec
// turns a 0 into a few levels (a surface at the slab's bottom that is not there).
float level_of(vec4 texel, float covered) { return covered < 0.5 ? 0.0 : max(texel.a * 255.0, 1.0); }

float height_at(int k, vec2 t) { // the surface's height above the card plane; -1e30 where none
  if (!in_frame(t)) return -1e30;
  ivec2 at = ivec2(floor(f_origin[k] + t));
  float covered = (k == 0 ? texelFetch(atlas0, at, 0) : k == 1 ? texelFetch(atlas1, at, 0) : texelFetch(atlas2, at, 0)).a;
  float level = level_of(k == 0 ? texelFetch(heights0, at, 0) : k == 1 ? texelFetch(heights1, at, 0) : texelFetch(heights2, at, 0), covered);
  if (level < 0.5) return -1e30;
  return ((level - 1.0) / ${DEPTH_LEVELS.toFixed(1)} * 2.0 - 1.0) * radius;
}

float bottom_at(int k, vec3 p) { // the column's bottom: the opposite frame's surface, as a height along f_dir[k]
  if (o_valid[k] == 0) return -1e30;
  vec2 t = vec2((dot(p, o_right[k]) / radius * 0.5 + 0.5) * frame_res, (0.5 - dot(p, o_up[k]) / radius * 0.5) * frame_res);
  if (!in_frame(t)) return -1e30;
  ivec2 at = ivec2(floor(o_origin[k] + t));
  float covered = (k == 0 ? texelFetch(o_atlas0, at, 0) : k == 1 ? texelFetch(o_atlas1, at, 0) : texelFetch(o_atlas2, at, 0)).a;
  float level = level_of(k == 0 ? texelFetch(opposite0, at, 0) : k == 1 ? texelFetch(opposite1, at, 0) : texelFetch(opposite2, at, 0), covered);
  if (level < 0.5) return -1e30; // the opposite frame saw nothing here: a one-sided column
  return -((level - 1.0) / ${DEPTH_LEVELS.toFixed(1)} * 2.0 - 1.0) * radius;
}

void main() {
  vec3 ray = normalize(v_local - eye_local);
  vec3 rgb = vec3(0.0);
  float weight = 0.0, along = 0.0;
  for (int k = 0; k < 3; ++k) {
    if (f_weight[k] <= 0.0) continue;
    float dn = dot(ray, f_dir[k]);
    if (dn > -1e-6) continue; // the ray does not go into this frame's image
    float e0 = dot(eye_local, f_dir[k]);
    float t;
    float alpha;
    vec3 c;
    if (use_depth == 0) {
      t = -e0 / dn; // the card plane through the centre
      vec2 tx = frame_texel(k, eye_local + t * ray);
      if (!in_frame(tx)) continue;
      vec4 s = colour_at(k, tx);
      alpha = s.a;
      c = s.rgb;
    } else { // the height field: march from the slab's top to its bottom, half a texel a step, then bisect
      float t_top = (radius - e0) / dn, t_bottom = (-radius - e0) / dn;
      vec3 lateral = (ray - dn * f_dir[k]) * (t_bottom - t_top);
      int steps = clamp(int(ceil(length(lateral) / radius * 0.5 * frame_res * 2.0)) + 2, 2, 1024);
      float before = t_top;
      bool hit = false;
      for (int s = 1; s <= steps; ++s) {
        float ts = mix(t_top, t_bottom, float(s) / float(steps));
        vec3 p = eye_local + ts * ray;
        if (dot(p, f_dir[k]) <= height_at(k, frame_texel(k, p))) {
          float lo = before, hi = ts;
          for (int b = 0; b < 8; ++b) {
            float mid = 0.5 * (lo + hi);
            vec3 q = eye_local + mid * ray;
            if (dot(q, f_dir[k]) <= height_at(k, frame_texel(k, q))) hi = mid; else lo = mid;
          }
          vec3 q = eye_local + hi * ray;
          // two-sided: a crossing under the column's bottom (less a depth step) passes beneath the part
          if (dot(q, f_dir[k]) >= bottom_at(k, q) - 2.0 * radius / ${DEPTH_LEVELS.toFixed(1)}) {
            t = hi;
            hit = true;
            break;
          }
        }
        before = ts;
      }
      if (!hit) continue;
      alpha = 1.0;
      c = colour_at(k, frame_texel(k, eye_local + t * ray)).rgb;
    }
    rgb += f_weight[k] * alpha * c;
    weight += f_weight[k] * alpha;
    along += f_weight[k] * alpha * t;
  }
  if (weight < 0.5) discard;
  vec3 p = eye_local + along / weight * ray; // the blended hit point: its depth is written
  vec4 clip = projectionMatrix * modelViewMatrix * vec4(centre + p, 1.0);
  gl_FragDepth = 0.5 * clip.z / clip.w + 0.5;
  gl_FragColor = vec4(rgb / weight, 1.0);
  #include <colorspace_fragment>
}`;

// ---------------------------------------------------------------- the grid, read from a GLB

const BLANK = new THREE.DataTexture(new Uint8Array(4), 1, 1); // no normal page: never read
BLANK.needsUpdate = true;

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

/** The frame grid of one FARFIELD_octahedral_impostor extension (``extension``), its accessors
 *  and textures loaded through ``parser`` (a GLTFLoader's GLTFParser: ``gltf.parser``). */
export async function readGrid(parser, extension) {
  const accessor = async (index) => (await parser.getDependency("accessor", index)).array;
  const textures = async (indices, colour) =>
    Promise.all((indices || []).map(async (index) => prepared(await parser.getDependency("texture", index), colour)));
  const [axes, texels, pages, colour, normal] = await Promise.all([
    accessor(extension.frames.axes), accessor(extension.frames.texels), accessor(extension.frames.pages),
    textures(extension.pages.colour, true), textures(extension.pages.normal, false),
  ]);
  return {
    n: extension.grid, hemisphere: !!extension.hemisphere, frameResolution: extension.frameResolution,
    padding: extension.padding, depth: !!extension.depth && normal.length > 0,
    centre: new THREE.Vector3(...extension.centre), radius: extension.radius,
    axes, texels, pages, colour, normal,
  };
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

function cardGeometry(grid) {
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute("position", new THREE.Float32BufferAttribute([-1, -1, 0, 1, -1, 0, 1, 1, 0, -1, 1, 0], 3));
  geometry.setIndex([0, 1, 2, 0, 2, 3]);
  if (grid) { // frustum culling: what shows lies inside the sphere
    geometry.boundingSphere = new THREE.Sphere(grid.centre.clone(), grid.radius);
    geometry.boundingBox = new THREE.Box3().setFromCenterAndSize(grid.centre, new THREE.Vector3().setScalar(2 * grid.radius));
  }
  return geometry;
}

function cardMaterial(grid) {
  const vec3s = () => [new THREE.Vector3(), new THREE.Vector3(), new THREE.Vector3()];
  const vec2s = () => [new THREE.Vector2(), new THREE.Vector2(), new THREE.Vector2()];
  const uniforms = {
    centre: {value: grid.centre.clone()}, card_a: {value: new THREE.Vector3()}, card_b: {value: new THREE.Vector3()},
    eye_local: {value: new THREE.Vector3()}, radius: {value: grid.radius}, frame_res: {value: grid.frameResolution},
    use_depth: {value: grid.depth ? 1 : 0},
    f_right: {value: vec3s()}, f_up: {value: vec3s()}, f_dir: {value: vec3s()}, f_origin: {value: vec2s()},
    f_size: {value: vec2s()}, f_weight: {value: [0, 0, 0]},
    o_valid: {value: [0, 0, 0]}, o_right: {value: vec3s()}, o_up: {value: vec3s()}, o_origin: {value: vec2s()}, o_size: {value: vec2s()},
  };
  for (let k = 0; k < 3; k++) {
    uniforms[`atlas${k}`] = {value: grid.colour[0]};
    uniforms[`heights${k}`] = {value: grid.normal[0] || BLANK};
    uniforms[`opposite${k}`] = {value: grid.normal[0] || BLANK};
    uniforms[`o_atlas${k}`] = {value: grid.colour[0]};
  }
  return new THREE.ShaderMaterial({uniforms, vertexShader: VERTEX, fragmentShader: FRAGMENT, side: THREE.DoubleSide});
}

const _eye = new THREE.Vector3();
const _w = new THREE.Vector3();
const _hint = new THREE.Vector3();

/** One octahedral impostor: a camera-facing card (a THREE.Mesh with a ShaderMaterial) that blends
 *  the three frames around the view direction.  ``grid``: what readGrid returns.  Clones share the
 *  grid, the card and the material (each draw sets the material's uniforms before it is made). */
export class OctahedralImpostor extends THREE.Mesh {
  constructor(grid = null) {
    super(cardGeometry(grid), grid ? cardMaterial(grid) : undefined);
    this.isOctahedralImpostor = true;
    this.grid = grid;
    this.opposite = grid ? oppositeFrames(grid.axes, grid.n * grid.n) : null;
    this.fallback = null; // the GLB's card this replaced (octahedralImpostors)
  }

  copy(source, recursive) {
    super.copy(source, recursive);
    this.grid = source.grid;
    this.opposite = source.opposite;
    this.fallback = source.fallback;
    return this;
  }

  /** Free the card, its program and the grid's pages (every clone shares them). */
  dispose() {
    this.geometry.dispose();
    this.material.dispose();
    for (const texture of [...(this.grid?.colour || []), ...(this.grid?.normal || [])]) texture.dispose();
  }

  onBeforeRender(renderer, scene, camera) {
    const g = this.grid;
    if (!g) return;
    const u = this.material.uniforms;
    this.worldToLocal(_eye.setFromMatrixPosition(camera.matrixWorld));
    const eye = u.eye_local.value.subVectors(_eye, g.centre);
    // the card: through the centre, facing the eye, covering the sphere's silhouette (runtime.card_corners)
    const distance = eye.length();
    _w.copy(eye).negate().divideScalar(distance);
    _hint.set(0, 0, 1);
    if (Math.abs(_w.z) >= 0.99) _hint.set(0, 1, 0);
    const a = u.card_a.value.crossVectors(_w, _hint).normalize();
    const b = u.card_b.value.crossVectors(a, _w);
    const r = g.radius;
    const half = distance > r * 1.0001 ? (r * distance) / Math.sqrt(distance * distance - r * r) : INSIDE_HALF_SIDE * r;
    a.multiplyScalar(half);
    b.multiplyScalar(half);
    const {frames, weights} = blendFrames([eye.x, eye.y, eye.z], g.n, g.hemisphere);
    const size = (page) => [g.colour[page].image.width, g.colour[page].image.height];
    for (let k = 0; k < 3; k++) {
      const f = frames[k], page = g.pages[f];
      u.f_right.value[k].fromArray(g.axes, 9 * f);
      u.f_up.value[k].fromArray(g.axes, 9 * f + 3);
      u.f_dir.value[k].fromArray(g.axes, 9 * f + 6);
      u.f_origin.value[k].set(g.texels[2 * f], g.texels[2 * f + 1]);
      u.f_size.value[k].set(...size(page));
      u.f_weight.value[k] = weights[k];
      u[`atlas${k}`].value = g.colour[page];
      u[`heights${k}`].value = g.normal[page] || BLANK;
      const o = g.depth ? this.opposite[f] : -1;
      const other = o >= 0 ? o : f;
      u.o_valid.value[k] = o >= 0 ? 1 : 0;
      u.o_right.value[k].fromArray(g.axes, 9 * other);
      u.o_up.value[k].fromArray(g.axes, 9 * other + 3);
      u.o_origin.value[k].set(g.texels[2 * other], g.texels[2 * other + 1]);
      u.o_size.value[k].set(...size(g.pages[other]));
      u[`opposite${k}`].value = g.normal[g.pages[other]] || BLANK;
      u[`o_atlas${k}`].value = g.colour[g.pages[other]];
    }
  }
}

/** Replace every card of ``gltf`` (GLTFLoader's result) that carries FARFIELD_octahedral_impostor
 *  by an OctahedralImpostor in its place (its transform, name and userData; the card it replaces
 *  as its ``fallback``).  Resolves to the impostors made (none: the GLB has no such card). */
export async function octahedralImpostors(gltf) {
  const cards = [];
  gltf.scene.traverse((node) => {
    if (node.isMesh && node.userData.gltfExtensions?.[OCTAHEDRAL_EXTENSION]) cards.push(node);
  });
  const made = [];
  for (const card of cards) {
    const grid = await readGrid(gltf.parser, card.userData.gltfExtensions[OCTAHEDRAL_EXTENSION]);
    const impostor = new OctahedralImpostor(grid);
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
