// farfield's 3D view of a job: the reference client of an impostor database, in three.js.
//
// What an engine does with a job's database, step by step (README "Using an impostor database
// in an engine"):
//   1. GET /v1/jobs/{id}/index.json: the cells, each with its view cell (a box), its bundle and
//      its neighbours; and GET /v1/scenes/{scene}/scene.glb, the geometry that stays geometry.
//   2. Every frame, find the cell whose box holds the camera (the lowest index where boxes share
//      a face).  A placement job's impostors depend on the view direction too: ask
//      GET /v1/jobs/{id}/lookup?x=&y=&z=&dx=&dy=&dz= when the view has changed.
//   3. When the cell changes, draw its impostor (GET .../cells/{n}/impostor.glb: unlit, alpha
//      mask 0.5, double-sided) and the geometry it does not replace, as its bundle's manifest
//      (GET .../cells/{n}/manifest.json) says, whatever the technique's name:
//        a near field in the manifest (parameters.near_field; an impostor of the whole scene
//                 around its cell, e.g. envmap): per object the face ranges [start, end) to
//                 draw, clipped to the near-field cube centred on the reference viewpoint
//                 (beyond it too in the pyramids of "open_faces"), and nothing else;
//        none     (an impostor of a part: layered, tdm, points, ldi, ...) every object not in
//                 the job's "objects" (none when the job names no objects: the impostor
//                 replaces the whole scene);
//        placement every object not in the lookup's "replaced"; where the lookup has a "pvs"
//                 (planned with visibility), only the elements it names (objects, or clusters
//                 name#k of split objects): the rest is hidden from this region.
//   4. Prefetch the neighbours' bundles (the index's "neighbours") so the next switch is instant.
//
// The page is also the dashboard's "3D view" of a job (?job=ID) and of one cell (?job=ID&cell=N:
// the camera starts at that cell's centre).  ?x=&y=&z=&dx=&dy=&dz= place the camera, ?fov= sets
// the vertical field of view in degrees (default: the job's), ?size=N draws an N x N canvas,
// ?mode=impostors|scene|split picks what is drawn, ?light=lit draws both sides lit (?azimuth=,
// ?elevation= in degrees place the light), unlit by default.  window.farfieldViewer is the hook the
// tests drive (tests/test_viewer.py, tests/test_service_lit.py).
//
// Lighting.  Unlit (the default) draws every material as glTF's KHR_materials_unlit rule does.
// Lit draws the scene's own glTF materials and a lit impostor's (channels=albedo+normal:
// metallic-roughness with a tangent-space normal map, docs/lit-impostors.md) under one directional
// light and an ambient light of farfield's lit evaluation (core/quality/lighting.py: 0.85π and
// 0.15π, y up); an unlit impostor (KHR_materials_unlit) stays unlit, as an engine draws it.
import * as THREE from "three";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";

import {api as request, fetchPlacementAlgorithms} from "./api.js";
import {octahedralImpostors} from "./octahedral-impostor.js";

const CACHED_CELLS = 64; // cells kept loaded (the active one and its neighbours always are)
const CACHED_GROUPS = 32; // what-to-draw groups kept built (a placement job makes one per lookup answer)
const LOOKUP_MS = 150; // a placement job's lookup: at most one request in flight, this often
const FACES = {"+x": [0, 1], "-x": [0, -1], "+y": [1, 1], "-y": [1, -1], "+z": [2, 1], "-z": [2, -1]}; // core/cube_faces.py
const FACE_ORDER = ["+x", "-x", "+y", "-y", "+z", "-z"];

const $ = (id) => document.getElementById(id);
const query = new URLSearchParams(location.search);
const number = (name) => (query.has(name) && query.get(name) !== "" && Number.isFinite(Number(query.get(name))) ? Number(query.get(name)) : null);

const view = {
  job: null, index: null, kind: "grid", algorithm: null, // kind: "grid" or a placement index's kind; algorithm: its GET /v1/placement-algorithms entry
  sceneRoot: null, objects: new Map(), // object name -> its meshes in the scene GLB
  clusters: {}, // a placement job's clusters of split objects: name -> {object, faces}
  bounds: new THREE.Box3(),
  cells: new Map(), // index entry by cell index
  loads: new Map(), // cell index -> Promise of {root, near} (impostor GLB root, near-field meshes)
  loadedOrder: [], // cell indices, least recently used first
  fetched: new Set(), prefetched: new Set(), // what was downloaded (the tests read both)
  groups: new Map(), // what-to-draw key -> THREE.Group, least recently used first
  groupLoads: new Map(), // key -> Promise of the group, while it is built
  updating: null, activeBounds: null, warning: null, retryAt: 0,
  activeKey: null, wantedKey: null, activeInfo: null,
  lookup: {at: 0, pose: "", answer: null},
  showImpostors: query.get("impostors") !== "0", // off: only what stays geometry (near field, kept objects)
  mode: ["impostors", "scene", "split"].includes(query.get("mode")) ? query.get("mode") : "impostors",
  lighting: query.get("light") === "lit" ? "lit" : "unlit",
  light: {azimuth: number("azimuth") ?? 60, elevation: number("elevation") ?? 35}, // degrees, y up
  error: null,
};

// ---------------------------------------------------------------- API

async function api(path, {binary = false} = {}) {
  // api.js's call (the dashboard's key), its error naming the path
  try {
    return await request(path, {binary});
  } catch (error) {
    let detail = error.status && !error.body ? `${error.status} ${error.statusText}` : error.message;
    if (error.status === 401) detail += " (enter an API key on the dashboard first)";
    throw new Error(`${path}: ${detail}`);
  }
}

async function parseGlb(buffer) {
  // A card carrying FARFIELD_octahedral_impostor is drawn by the module the service ships
  // (octahedral-impostor.js: the three frames around the view direction blended), not as its fallback.
  const gltf = await new GLTFLoader().parseAsync(buffer, "");
  await octahedralImpostors(gltf);
  return gltf.scene;
}

// ---------------------------------------------------------------- drawing

const canvas = $("viewer-canvas");
const renderer = new THREE.WebGLRenderer({canvas, antialias: false, alpha: true, premultipliedAlpha: false, preserveDrawingBuffer: true});
renderer.setPixelRatio(query.has("size") ? 1 : window.devicePixelRatio);
renderer.setClearColor(0x000000, 0);
renderer.toneMapping = THREE.NoToneMapping;
renderer.outputColorSpace = THREE.SRGBColorSpace;
const camera = new THREE.PerspectiveCamera(60, 1, 0.1, 1000);
const runtimeScene = new THREE.Scene();
const sourceScene = new THREE.Scene();

// ---------------------------------------------------------------- lighting

const DIRECT_INTENSITY = 0.85 * Math.PI; // core/quality/lighting.py's DIRECT_INTENSITY and AMBIENT
const AMBIENT_INTENSITY = 0.15 * Math.PI;
function lightRig() {
  const rig = new THREE.Group();
  const sun = new THREE.DirectionalLight(0xffffff, DIRECT_INTENSITY);
  rig.add(sun, sun.target, new THREE.AmbientLight(0xffffff, AMBIENT_INTENSITY));
  rig.userData.sun = sun;
  return rig;
}
const rigs = [lightRig(), lightRig()]; // the runtime's and the source scene's (an object has one parent)
sourceScene.add(rigs[1]);

function placeLight() {
  const a = (view.light.azimuth * Math.PI) / 180, e = (view.light.elevation * Math.PI) / 180;
  // toward the light; azimuth 0 along +x, 90° along up × x = -z, as core/quality/lighting.py's default_lights
  const direction = new THREE.Vector3(Math.cos(e) * Math.cos(a), Math.sin(e), -Math.cos(e) * Math.sin(a));
  const centre = view.bounds.isEmpty() ? new THREE.Vector3() : view.bounds.getCenter(new THREE.Vector3());
  for (const rig of rigs) {
    rig.userData.sun.position.copy(centre).add(direction);
    rig.userData.sun.target.position.copy(centre);
    rig.userData.sun.target.updateMatrixWorld(true);
  }
}

const shading = new WeakMap(); // mesh -> {lit, unlit}: its material (or materials) each way

const unlitLooks = new WeakMap(); // a lit material -> its unlit look, made once (the clones of a cell share it)
function unlitOf(material) {
  if (material.isMeshBasicMaterial || material.isShaderMaterial) return material; // a runtime's own program (octahedral-impostor.js) stays
  if (!unlitLooks.has(material)) unlitLooks.set(material, unlit(material));
  return unlitLooks.get(material);
}

function shadeBoth(mesh, lit, unlitMaterial) {
  // Register ``mesh``'s two looks and give it the current one.
  shading.set(mesh, {lit, unlit: unlitMaterial});
  mesh.material = view.lighting === "lit" ? lit : unlitMaterial;
}

function applyLighting(root) {
  root.traverse((node) => {
    const looks = node.isMesh && shading.get(node);
    if (looks) node.material = looks[view.lighting];
  });
}

function setLighting(lighting) {
  view.lighting = lighting === "lit" ? "lit" : "unlit";
  applyLighting(sourceScene);
  applyLighting(runtimeScene);
  for (const group of view.groups.values()) applyLighting(group);
  $("viewer-light").checked = view.lighting === "lit";
  for (const id of ["viewer-azimuth", "viewer-elevation"]) $(id).disabled = view.lighting !== "lit";
}

function unlit(material) {
  // farfield draws unlit (glTF's KHR_materials_unlit rule: base colour = map x colour x vertex
  // colour); a glTF BLEND material is drawn as a mask at 0.5, as farfield's loader does.
  const m = material || {};
  return new THREE.MeshBasicMaterial({
    map: m.map || null, color: m.color ? m.color.clone() : new THREE.Color(1, 1, 1), vertexColors: !!m.vertexColors,
    alphaTest: m.alphaTest || (m.transparent ? 0.5 : 0), side: THREE.DoubleSide, transparent: false,
  });
}

function nearFieldMaterial(material, near) {
  // The near field drawn inside its cube only (and in the pyramids beyond the open faces), as
  // core/render/raster.py's MeshRenderer clips it: a fragment outside both is discarded.
  const m = material.clone();
  const open = FACE_ORDER.map((f) => (near.open_faces.includes(f) ? 1 : 0));
  m.onBeforeCompile = (shader) => {
    shader.uniforms.ffCentre = {value: new THREE.Vector3(...near.centre)};
    shader.uniforms.ffHalf = {value: near.half_size};
    shader.uniforms.ffOpen = {value: open};
    shader.vertexShader = shader.vertexShader
      .replace("#include <common>", "#include <common>\nvarying vec3 ffWorld;")
      .replace("#include <project_vertex>", "#include <project_vertex>\nffWorld = (modelMatrix * vec4(transformed, 1.0)).xyz;");
    shader.fragmentShader = shader.fragmentShader
      .replace("#include <common>", "#include <common>\nvarying vec3 ffWorld;\nuniform vec3 ffCentre;\nuniform float ffHalf;\nuniform float ffOpen[6];")
      .replace("void main() {", `void main() {
  vec3 ffP = ffWorld - ffCentre;
  vec3 ffA = abs(ffP);
  bool ffKeep = max(ffA.x, max(ffA.y, ffA.z)) <= ffHalf;
  ffKeep = ffKeep || (ffOpen[0] > 0.5 && ffP.x >= max(ffA.y, ffA.z)) || (ffOpen[1] > 0.5 && -ffP.x >= max(ffA.y, ffA.z));
  ffKeep = ffKeep || (ffOpen[2] > 0.5 && ffP.y >= max(ffA.x, ffA.z)) || (ffOpen[3] > 0.5 && -ffP.y >= max(ffA.x, ffA.z));
  ffKeep = ffKeep || (ffOpen[4] > 0.5 && ffP.z >= max(ffA.x, ffA.y)) || (ffOpen[5] > 0.5 && -ffP.z >= max(ffA.x, ffA.y));
  if (!ffKeep) discard;`);
  };
  m.customProgramCacheKey = () => "farfield-near-field";
  return m;
}

function faceRanges(geometry, ranges) {
  // A geometry drawing only the faces [start, end) of ``ranges`` (its attributes shared).
  const count = ranges.reduce((n, [a, b]) => n + 3 * (b - a), 0);
  const source = geometry.index ? geometry.index.array : null;
  const out = source instanceof Uint16Array ? new Uint16Array(count) : new Uint32Array(count);
  let o = 0;
  for (const [a, b] of ranges) {
    if (source) out.set(source.subarray(3 * a, 3 * b), o);
    else for (let i = 3 * a; i < 3 * b; i++) out[o + i - 3 * a] = i;
    o += 3 * (b - a);
  }
  const part = new THREE.BufferGeometry();
  for (const [name, attribute] of Object.entries(geometry.attributes)) part.setAttribute(name, attribute);
  part.setIndex(new THREE.BufferAttribute(out, 1));
  return part;
}

function objectMesh(mesh, geometry = mesh.geometry, material = null) {
  // A copy of a scene mesh (its buffers shared) with ``material``, or with the mesh's own two looks.
  const copy = new THREE.Mesh(geometry, material || mesh.material);
  const looks = shading.get(mesh);
  if (!material && looks) shadeBoth(copy, looks.lit, looks.unlit);
  copy.matrixAutoUpdate = false;
  copy.matrix.copy(mesh.matrixWorld);
  copy.matrixWorld.copy(mesh.matrixWorld);
  return copy;
}

// ---------------------------------------------------------------- the database

async function loadJob(jobId) {
  view.job = await api(`/v1/jobs/${encodeURIComponent(jobId)}`);
  $("viewer-title").textContent = `job ${view.job.id} · ${view.job.technique || view.job.params?.technique || ""}`;
  const [index, sceneGlb] = await Promise.all([
    api(`/v1/jobs/${encodeURIComponent(jobId)}/index.json`),
    api(`/v1/scenes/${encodeURIComponent(view.job.scene_id)}/scene.glb`, {binary: true}),
  ]);
  view.index = index;
  // A placement's index has its algorithm's kind (GET /v1/placement-algorithms: "index_kind"); any other is a grid's.
  const algorithms = index.kind ? (await fetchPlacementAlgorithms()).algorithms : new Map();
  view.algorithm = [...algorithms.values()].find((a) => a.index_kind === index.kind) || null;
  view.kind = view.algorithm ? index.kind : "grid";
  for (const cell of index.cells || []) view.cells.set(cell.index, cell);
  if (view.algorithm && !view.algorithm.images) view.clusters = (await api(`/v1/jobs/${encodeURIComponent(jobId)}/clusters`)).clusters;
  view.sceneRoot = await parseGlb(sceneGlb);
  view.sceneRoot.updateMatrixWorld(true);
  view.sceneRoot.traverse((node) => {
    if (!node.isMesh) return;
    const own = node.material;
    shadeBoth(node, own, Array.isArray(own) ? own.map(unlitOf) : unlitOf(own));
    const name = node.userData.farfield_object ?? node.name;
    if (!view.objects.has(name)) view.objects.set(name, []);
    view.objects.get(name).push(node);
  });
  view.bounds.setFromObject(view.sceneRoot);
  sourceScene.add(view.sceneRoot);
  placeLight();
}

function cellHolds(vc, p) {
  // Whether view cell ``vc`` holds p, as core/viewcells.py's contains: a box (closed), or the
  // outside of a sphere (an octahedral impostor's cell: at least its radius from the centre; a
  // hemisphere's, not below the horizontal plane through the centre, world +z up).
  if (vc?.kind === "box") return p.x >= vc.lo[0] && p.x <= vc.hi[0] && p.y >= vc.lo[1] && p.y <= vc.hi[1] && p.z >= vc.lo[2] && p.z <= vc.hi[2];
  if (vc?.kind === "outside-sphere") {
    const d = [p.x - vc.centre[0], p.y - vc.centre[1], p.z - vc.centre[2]];
    return Math.hypot(...d) >= vc.radius * (1 - 1e-12) && (!vc.hemisphere || d[2] >= -1e-12 * vc.radius);
  }
  return false;
}

function cellCentre(vc) {
  // Where the view starts in a cell: a box's centre; outside a sphere, its nearest distance 45°
  // above the horizon towards +x (core/viewcells.py's SphereOutsideCell.center).
  if (vc.kind === "box") return vc.lo.map((l, i) => 0.5 * (l + vc.hi[i]));
  return [vc.centre[0] + vc.radius * Math.SQRT1_2, vc.centre[1], vc.centre[2] + vc.radius * Math.SQRT1_2];
}

function cellAt(p) {
  // The cell that holds p (boxes are closed: the lowest index where they share a face), as
  // core/impostor/database.py's find; a cell without a result too (the caller says so).  Shaft
  // view cells (explicit cells of a part job) are not looked up here.
  let best = null;
  for (const cell of view.cells.values()) {
    if (cellHolds(cell.viewcell, p) && (best === null || cell.index < best.index)) best = cell;
  }
  return best;
}

function loadCell(n, prefetch = false) {
  // The impostor GLB of cell n and its manifest, once.  A manifest with a near field
  // (parameters.near_field: an impostor of the whole scene around its cell) brings the geometry
  // drawn with it; without one, the impostor replaces objects and the rest of the scene is drawn.
  if (!view.loads.has(n)) {
    const base = `/v1/jobs/${encodeURIComponent(view.job.id)}/cells/${n}`;
    view.loads.set(n, (async () => {
      const [glb, manifest] = await Promise.all([api(`${base}/impostor.glb`, {binary: true}), api(`${base}/manifest.json`)]);
      const root = await parseGlb(glb);
      (prefetch ? view.prefetched : view.fetched).add(n);
      const near = manifest.parameters?.near_field;
      return {root, near: near ? nearField(near) : null};
    })());
    view.loads.get(n).catch(() => { // a failed load is tried again next time
      view.loads.delete(n);
      view.loadedOrder = view.loadedOrder.filter((i) => i !== n);
    });
  }
  view.loadedOrder = view.loadedOrder.filter((i) => i !== n).concat([n]);
  return view.loads.get(n);
}

function cellTechnique(n) {
  const cell = view.cells.get(n);
  return cell?.technique || view.index.technique || view.job.technique;
}

function nearField(near) {
  const meshes = [];
  for (const {name, faces} of near.objects) {
    for (const mesh of view.objects.get(name) || []) {
      const clipped = (m) => (Array.isArray(m) ? m.map((one) => nearFieldMaterial(one, near)) : nearFieldMaterial(m, near));
      const looks = shading.get(mesh);
      const part = objectMesh(mesh, faceRanges(mesh.geometry, faces), clipped(looks.unlit));
      shadeBoth(part, clipped(looks.lit), part.material);
      part.userData.ownsIndex = part.userData.ownsMaterial = true; // freed with the cell
      meshes.push(part);
    }
  }
  return meshes;
}

function keptObjects(replaced, visible = null) {
  // Every element of the scene not in ``replaced`` (a Set of names), as meshes sharing the scene's
  // buffers: a whole object, or an object less the clusters of it that are replaced.  ``visible``
  // (a Set of element names: a lookup's potentially visible set, or null): only those are kept.
  const hidden = new Map(); // object name -> face ranges of its replaced (or not visible) clusters
  const cut = (name) => {
    const cluster = view.clusters[name];
    if (!cluster) return;
    if (!hidden.has(cluster.object)) hidden.set(cluster.object, []);
    hidden.get(cluster.object).push(...cluster.faces);
  };
  for (const name of replaced) cut(name);
  const split = new Set(Object.values(view.clusters).map((c) => c.object));
  if (visible) for (const name of Object.keys(view.clusters)) if (!visible.has(name) && !replaced.has(name)) cut(name);
  const meshes = [];
  for (const [name, list] of view.objects) {
    if (replaced.has(name)) continue;
    if (visible && !split.has(name) && !visible.has(name)) continue; // outside the region's PVS
    for (const mesh of list) {
      const cut = hidden.get(name);
      if (!cut) { meshes.push(objectMesh(mesh)); continue; }
      const faces = (mesh.geometry.index ? mesh.geometry.index.count : mesh.geometry.attributes.position.count) / 3;
      const kept = complement(cut, faces);
      if (!kept.length) continue;
      const part = objectMesh(mesh, faceRanges(mesh.geometry, kept));
      part.userData.ownsIndex = true; // freed with its group
      meshes.push(part);
    }
  }
  return meshes;
}

function complement(ranges, count) {
  // The ranges [start, end) of 0..count not covered by ``ranges``.
  const out = [];
  let at = 0;
  for (const [a, b] of [...ranges].sort((p, q) => p[0] - q[0])) {
    if (a > at) out.push([at, a]);
    at = Math.max(at, b);
  }
  if (at < count) out.push([at, count]);
  return out;
}

function release(mesh) {
  // What a near-field or kept-faces mesh owns: its index (its attributes are the scene's, shared:
  // taken off first so that dispose() leaves their GPU buffers alone) and, for the near field, its
  // clipping materials.
  if (mesh.userData.ownsIndex) {
    for (const name of Object.keys(mesh.geometry.attributes)) mesh.geometry.deleteAttribute(name);
    mesh.geometry.dispose();
  }
  if (mesh.userData.ownsMaterial) {
    const looks = shading.get(mesh);
    for (const m of (looks ? [looks.lit, looks.unlit] : [mesh.material]).flat()) m.dispose();
  }
}

function dropGroup(key) {
  const group = view.groups.get(key);
  view.groups.delete(key);
  view.groupLoads.delete(key);
  if (group) for (const child of group.children) if (child.isMesh && child.userData.ownsIndex && !child.userData.ownsMaterial) release(child);
}

function evict(keep, active) {
  // Impostors beyond CACHED_CELLS and groups beyond CACHED_GROUPS, least recently used first,
  // never those in ``keep`` (cells) or the ``active`` group.
  while (view.loadedOrder.length > CACHED_CELLS) {
    const victim = view.loadedOrder.find((n) => !keep.has(n));
    if (victim === undefined) break;
    view.loadedOrder = view.loadedOrder.filter((n) => n !== victim);
    const load = view.loads.get(victim);
    view.loads.delete(victim);
    for (const [key, group] of view.groups) if (key !== active && group.userData.cells.includes(victim)) dropGroup(key);
    if (!load) continue;
    load.then(({root, near}) => {
      root.traverse((node) => {
        if (!node.isMesh) return;
        if (node.isOctahedralImpostor) { node.dispose(); return; }
        node.geometry.dispose();
        for (const m of [].concat(node.material)) { m.map?.dispose(); m.normalMap?.dispose(); unlitLooks.get(m)?.dispose(); m.dispose(); }
      });
      for (const mesh of near || []) release(mesh);
    }).catch(() => {});
  }
  for (const key of [...view.groups.keys()]) {
    if (view.groups.size <= CACHED_GROUPS) break;
    if (key !== active) dropGroup(key);
  }
}

function groupFor(key, cells, replaced, visible = null) {
  // What to draw for one cell (grid) or one lookup answer (placement): impostors + kept geometry;
  // built once per key (the promise is shared while it builds).
  if (view.groups.has(key)) {
    const group = view.groups.get(key);
    view.groups.delete(key); // most recently used last
    view.groups.set(key, group);
    for (const n of cells) loadCell(n); // their recency too (loaded: no download)
    return Promise.resolve(group);
  }
  if (!view.groupLoads.has(key)) {
    const building = (async () => {
      const loaded = await Promise.all(cells.map((n) => loadCell(n)));
      const group = new THREE.Group();
      group.userData.cells = cells;
      for (const {root, near} of loaded) {
        const impostor = root.clone(); // shares the impostor's geometry and textures
        impostor.userData.impostor = true;
        impostor.traverse((node) => {
          if (!node.isMesh) return;
          const own = node.material;
          shadeBoth(node, own, Array.isArray(own) ? own.map(unlitOf) : unlitOf(own));
        });
        impostor.visible = view.showImpostors;
        group.add(impostor);
        if (near) for (const mesh of near) group.add(mesh);
      }
      // a bundle with a near field replaces the whole scene but its near field: nothing more is kept
      if (replaced && !loaded.some(({near}) => near)) for (const mesh of keptObjects(replaced, visible)) group.add(mesh);
      group.userData.bounds = new THREE.Box3().setFromObject(group); // impostors may reach past the scene
      view.groups.set(key, group);
      return group;
    })();
    view.groupLoads.set(key, building);
    building.then(() => view.groupLoads.delete(key), () => view.groupLoads.delete(key));
  }
  return view.groupLoads.get(key);
}

// ---------------------------------------------------------------- what the camera needs

function gridWanted() {
  const cell = cellAt(camera.position);
  if (cell === null) return {key: "outside", info: "outside every view cell: drawing the source scene", outside: true};
  if (!cell.bundle) return {key: `no result ${cell.index}`, info: `cell ${cell.index} has no result (${cell.state}): drawing the source scene`, outside: true};
  // What the impostor replaces: the job's objects (all when it names none), or, for a cell whose
  // bundle brings its near field, everything (groupFor decides once the bundle is loaded).
  const replaced = new Set(view.job.params?.objects || view.objects.keys());
  return {key: `cell ${cell.index}`, cells: [cell.index], replaced, info: `cell ${cell.index} (${cellTechnique(cell.index)})`, cell: cell.index, neighbours: cell.neighbours || []};
}

function placementWanted() {
  const answer = view.lookup.answer;
  if (answer === null) return null;
  const cells = answer.impostors || [];
  const info = answer.cpv === null ? "under budget: drawing the geometry" : `CPV ${answer.cpv} (${answer.status}), ${cells.length} impostors`;
  // A placement planned with visibility: only its region's potentially visible set is drawn as geometry.
  const pvs = answer.pvs && answer.pvs.elements ? answer.pvs : null;
  const visible = pvs ? new Set(pvs.elements) : null;
  const culled = pvs ? `; PVS of region ${pvs.region}: ${pvs.count} of ${pvs.of} elements` : "";
  return {key: `cpv ${answer.cpv} ${cells.join(",")}${pvs ? ` pvs ${pvs.region}` : ""}`, cells, replaced: new Set(answer.replaced || []), visible, info: info + culled, cpv: answer.cpv};
}

function poseKey() {
  const d = new THREE.Vector3();
  camera.getWorldDirection(d);
  return [...camera.position.toArray(), ...d.toArray()].map((v) => v.toPrecision(6)).join(",");
}

async function lookupPlacement(force = false) {
  // Called only from doUpdate, which runs one at a time: one request in flight, answers in order.
  const pose = poseKey();
  const now = performance.now();
  if (!force && (pose === view.lookup.pose || now - view.lookup.at < LOOKUP_MS)) return;
  view.lookup.at = now;
  const d = new THREE.Vector3();
  camera.getWorldDirection(d);
  const p = camera.position;
  view.lookup.answer = await api(`/v1/jobs/${encodeURIComponent(view.job.id)}/lookup?x=${p.x}&y=${p.y}&z=${p.z}&dx=${d.x}&dy=${d.y}&dz=${d.z}`);
  view.lookup.pose = pose;
}

function update(force = false) {
  // Switch to what the camera needs; resolves when it is drawn.  One runs at a time: a forced one
  // (the tests' show: a lookup whatever the throttle) waits for the one in flight, then runs.
  if (view.updating) return force ? view.updating.catch(() => {}).then(() => update(true)) : view.updating;
  view.updating = doUpdate(force).finally(() => { view.updating = null; });
  return view.updating;
}

async function doUpdate(force) {
  if (view.algorithm && view.algorithm.images) {
    view.activeInfo = `a ${view.algorithm.name} job's LDIs are drawn by a warper (farfield walkthrough): this view shows its source scene`;
    return;
  }
  if (view.algorithm) await lookupPlacement(force);
  const wanted = view.algorithm ? placementWanted() : gridWanted();
  if (wanted === null) return;
  view.wantedKey = wanted.key;
  if (wanted.key === view.activeKey) return;
  if (wanted.outside) {
    view.activeKey = wanted.key;
    view.activeInfo = wanted.info;
    view.activeBounds = null;
    runtimeScene.clear();
    runtimeScene.add(rigs[0]);
    return;
  }
  const group = await groupFor(wanted.key, wanted.cells, wanted.replaced, wanted.visible || null);
  if (view.wantedKey !== wanted.key) return; // the camera moved on meanwhile
  runtimeScene.clear();
  runtimeScene.add(rigs[0], group);
  view.activeKey = wanted.key;
  view.activeInfo = wanted.info;
  view.activeBounds = group.userData.bounds;
  const keep = new Set(wanted.cells.concat(wanted.neighbours || []));
  for (const n of wanted.neighbours || []) if (view.cells.get(n)?.bundle) loadCell(n, true).catch(() => {});
  evict(keep, wanted.key);
}

// ---------------------------------------------------------------- camera and controls

function setDepthRange() {
  // near: a hundredth of the current cell's smallest side (as farfield.core.techniques.envmap.runtime.depth_range_for);
  // far: past the farthest corner of the scene.
  if (view.fixedDepth) return;
  const box = view.bounds.clone();
  if (view.activeBounds && !view.activeBounds.isEmpty()) box.union(view.activeBounds); // envmap layers may lie past the scene
  const corners = [];
  for (const x of [box.min.x, box.max.x]) for (const y of [box.min.y, box.max.y]) for (const z of [box.min.z, box.max.z]) corners.push(new THREE.Vector3(x, y, z));
  const far = Math.max(...corners.map((c) => c.distanceTo(camera.position)), 1e-6) * 1.5;
  const cell = view.kind === "grid" ? cellAt(camera.position) : null;
  const size = cell?.viewcell.kind === "box" ? Math.min(...cell.viewcell.hi.map((h, i) => h - cell.viewcell.lo[i])) : 0;
  camera.near = size > 0 ? 0.01 * size : far * 1e-5;
  camera.far = Math.max(far, 2 * camera.near);
}

function lookAlong(direction) {
  const d = new THREE.Vector3(...direction).normalize();
  controls.yaw = Math.atan2(d.x, -d.z);
  controls.pitch = Math.asin(Math.max(-1, Math.min(1, d.y)));
  applyControls();
}

function startPose() {
  const scale = view.bounds.isEmpty() ? 1 : view.bounds.getSize(new THREE.Vector3()).length();
  controls.speed = Math.max(scale / 20, 1e-6);
  const given = ["x", "y", "z"].map(number);
  const cellIndex = number("cell");
  const known = (c) => ["box", "outside-sphere"].includes(c?.viewcell?.kind);
  const first = [...view.cells.values()].find((c) => known(c) && c.bundle);
  const cell = cellIndex !== null ? view.cells.get(cellIndex) : first;
  if (given.every((v) => v !== null)) camera.position.set(...given);
  else if (known(cell)) camera.position.set(...cellCentre(cell.viewcell));
  else if (view.index.placement?.parameters?.view_space || view.index.view_space) {
    const [lo, hi] = view.index.placement?.parameters?.view_space || view.index.view_space; // [lo, hi]
    camera.position.set(...lo.map((l, i) => 0.5 * (l + hi[i])));
  } else view.bounds.getCenter(camera.position);
  const dir = ["dx", "dy", "dz"].map(number);
  if (dir.every((v) => v !== null) && Math.hypot(...dir) > 0) lookAlong(dir);
  else {
    const towards = view.bounds.getCenter(new THREE.Vector3()).sub(camera.position);
    towards.y = 0;
    lookAlong(towards.lengthSq() > 0 ? towards.toArray() : [0, 0, -1]);
  }
  camera.fov = number("fov") ?? view.job.params?.fov_deg ?? 60;
}

const controls = {yaw: 0, pitch: 0, speed: 1, keys: new Set(), dragging: null};

function applyControls() {
  camera.quaternion.setFromEuler(new THREE.Euler(controls.pitch, -controls.yaw, 0, "YXZ"));
  camera.updateMatrixWorld(true);
}

canvas.addEventListener("pointerdown", (e) => { controls.dragging = {x: e.clientX, y: e.clientY}; canvas.setPointerCapture(e.pointerId); canvas.focus(); });
canvas.addEventListener("pointerup", () => { controls.dragging = null; });
canvas.addEventListener("pointermove", (e) => {
  if (!controls.dragging) return;
  controls.yaw += 0.005 * (e.clientX - controls.dragging.x);
  controls.pitch = Math.max(-1.55, Math.min(1.55, controls.pitch - 0.005 * (e.clientY - controls.dragging.y)));
  controls.dragging = {x: e.clientX, y: e.clientY};
  applyControls();
});
canvas.addEventListener("wheel", (e) => { e.preventDefault(); controls.speed *= e.deltaY < 0 ? 1.25 : 0.8; }, {passive: false});
window.addEventListener("keydown", (e) => controls.keys.add(e.key.toLowerCase()));
window.addEventListener("keyup", (e) => controls.keys.delete(e.key.toLowerCase()));
window.addEventListener("blur", () => controls.keys.clear());

function move(seconds) {
  const k = controls.keys;
  const step = controls.speed * seconds * (k.has("shift") ? 5 : 1);
  const forward = new THREE.Vector3(), right = new THREE.Vector3();
  camera.getWorldDirection(forward);
  right.crossVectors(forward, camera.up).normalize();
  const delta = new THREE.Vector3();
  if (k.has("w") || k.has("arrowup")) delta.add(forward);
  if (k.has("s") || k.has("arrowdown")) delta.sub(forward);
  if (k.has("d") || k.has("arrowright")) delta.add(right);
  if (k.has("a") || k.has("arrowleft")) delta.sub(right);
  if (k.has("e")) delta.y += 1;
  if (k.has("q")) delta.y -= 1;
  if (delta.lengthSq() === 0) return false;
  camera.position.addScaledVector(delta.normalize(), step);
  camera.updateMatrixWorld(true);
  return true;
}

// ---------------------------------------------------------------- frames

function size() {
  const fixed = number("size");
  if (fixed) return [fixed, fixed];
  const stage = $("viewer-stage");
  return [Math.max(1, stage.clientWidth), Math.max(1, stage.clientHeight)];
}

function draw() {
  const [w, h] = size();
  renderer.setSize(w, h, false);
  if (!query.has("size")) { canvas.style.width = `${w}px`; canvas.style.height = `${h}px`; }
  setDepthRange();
  const runtime = view.activeKey === "outside" || (view.algorithm && view.algorithm.images) ? sourceScene : runtimeScene;
  renderer.setScissorTest(view.mode === "split");
  if (view.mode === "split") {
    const half = Math.floor(w / 2);
    for (const [x, width, scene] of [[0, half, runtime], [half, w - half, sourceScene]]) {
      renderer.setViewport(x, 0, width, h);
      renderer.setScissor(x, 0, width, h);
      camera.aspect = width / h;
      camera.updateProjectionMatrix();
      renderer.render(scene, camera);
    }
  } else {
    renderer.setViewport(0, 0, w, h);
    camera.aspect = w / h;
    camera.updateProjectionMatrix();
    renderer.render(view.mode === "scene" ? sourceScene : runtime, camera);
  }
  $("viewer-labels").hidden = view.mode !== "split";
}

let last = performance.now(), frames = 0, fps = 0, fpsAt = last;
function status() {
  const info = renderer.info.render;
  const loading = view.wantedKey !== view.activeKey ? ` · loading ${view.wantedKey}…` : "";
  const warning = view.warning ? ` · ${view.warning} (retrying)` : "";
  $("viewer-status").textContent = `${view.activeInfo || "…"}${loading}${warning} · ${view.fetched.size} bundles loaded, ${view.prefetched.size} prefetched · ${info.triangles.toLocaleString()} triangles · ${fps} fps`;
}

function frame(now) {
  const seconds = Math.min(0.1, (now - last) / 1000);
  last = now;
  move(seconds);
  if (!view.updating && now >= view.retryAt) {
    update().then(() => { view.warning = null; }, (error) => { // shown, and tried again in a second
      view.warning = String(error.message || error);
      view.retryAt = performance.now() + 1000;
    });
  }
  draw();
  frames += 1;
  if (now - fpsAt > 1000) { fps = Math.round((1000 * frames) / (now - fpsAt)); frames = 0; fpsAt = now; }
  status();
  if (!view.error && !window.farfieldViewer.paused) requestAnimationFrame(frame);
}

function fail(error) {
  view.error = String(error.message || error);
  $("viewer-error").textContent = view.error;
  $("viewer-error").hidden = false;
  $("viewer-status").textContent = "failed";
}

function showImpostors(shown) {
  view.showImpostors = shown;
  for (const group of view.groups.values()) for (const child of group.children) if (child.userData.impostor) child.visible = shown;
  $("viewer-impostors").checked = shown;
}
$("viewer-impostors").addEventListener("change", (e) => showImpostors(e.target.checked));

function setMode(mode) {
  view.mode = mode;
  for (const b of document.querySelectorAll("[data-mode]")) b.classList.toggle("active", b.dataset.mode === mode);
}
for (const b of document.querySelectorAll("[data-mode]")) b.addEventListener("click", () => setMode(b.dataset.mode));
$("viewer-light").addEventListener("change", (e) => setLighting(e.target.checked ? "lit" : "unlit"));
for (const [id, key] of [["viewer-azimuth", "azimuth"], ["viewer-elevation", "elevation"]]) {
  $(id).value = String(view.light[key]);
  $(id).addEventListener("input", (e) => { view.light[key] = Number(e.target.value); placeLight(); });
}

function listedTriangles(scene) {
  // Triangles of the visible meshes of ``scene``, before three.js's frustum culling.
  let count = 0;
  scene.traverseVisible((node) => {
    if (node.isMesh) count += (node.geometry.index ? node.geometry.index.count : node.geometry.attributes.position.count) / 3;
  });
  return count;
}

function base64(bytes) {
  let text = "";
  for (let i = 0; i < bytes.length; i += 0x8000) text += String.fromCharCode.apply(null, bytes.subarray(i, i + 0x8000));
  return btoa(text);
}

// The tests' hook: place a camera exactly (farfield's Camera: eye, right, up, forward, the
// full-angle square fov in radians, near, far), wait until its cell is drawn, read the pixels.
window.farfieldViewer = {
  paused: query.get("paused") === "1",
  ready: null,
  async show(c, mode = "impostors", impostors = true, lighting = null) {
    if (lighting) { // {lit: bool, azimuth, elevation}: the light as the page's controls set it
      if (lighting.azimuth !== undefined) view.light.azimuth = lighting.azimuth;
      if (lighting.elevation !== undefined) view.light.elevation = lighting.elevation;
      placeLight();
      setLighting(lighting.lit ? "lit" : "unlit");
    }
    const basis = new THREE.Matrix4().makeBasis(new THREE.Vector3(...c.right), new THREE.Vector3(...c.up), new THREE.Vector3(...c.forward).negate());
    camera.position.set(...c.eye);
    camera.quaternion.setFromRotationMatrix(basis);
    camera.fov = (c.fov * 180) / Math.PI;
    camera.near = c.near;
    camera.far = c.far;
    camera.updateMatrixWorld(true);
    view.fixedDepth = true;
    setMode(mode);
    await update(true);
    showImpostors(impostors);
    draw();
    const triangles = listedTriangles(mode === "scene" ? sourceScene : runtimeScene);
    const gl = renderer.getContext();
    const [w, h] = size();
    const pixels = new Uint8Array(w * h * 4);
    gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, pixels);
    return {pixels: base64(pixels), width: w, height: h, triangles, ...this.state()};
  },
  state() {
    return {key: view.activeKey, info: view.activeInfo, kind: view.kind, fetched: [...view.fetched].sort((a, b) => a - b),
            prefetched: [...view.prefetched].sort((a, b) => a - b), objects: view.objects.size, error: view.error};
  },
  async settled() {
    // every download started so far has ended
    await Promise.allSettled([...view.loads.values()]);
    return this.state();
  },
};

async function main() {
  const jobId = query.get("job");
  if (!jobId) throw new Error("no job: open the 3D view from a job's page (viewer.html?job=ID)");
  $("viewer-back").href = `/dashboard/#/jobs/${encodeURIComponent(jobId)}`;
  await loadJob(jobId);
  startPose();
  setMode(view.mode);
  showImpostors(view.showImpostors);
  setLighting(view.lighting);
  await update();
  requestAnimationFrame(frame);
}

window.farfieldViewer.ready = main().then(() => true, (error) => { fail(error); return false; });
