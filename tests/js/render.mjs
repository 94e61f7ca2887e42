// farfield's three.js harness (tests/threejs.py drives it): load a glTF/GLB, OBJ (+MTL) or PLY
// file with three.js's own loaders and draw it unlit from a farfield camera.
//
// Every material becomes a MeshBasicMaterial (glTF's KHR_materials_unlit rule: base colour =
// map x color x vertex colour) keeping map, color, opacity, vertexColors, alphaTest and side, drawn
// opaque (alpha 1 where drawn); no tone mapping, sRGB output, no antialiasing.  Sidedness is the
// source's as three.js's loaders read it: glTF's doubleSided (DoubleSide or FrontSide), FrontSide for
// OBJ (OBJLoader's and MTLLoader's default) and PLY, unless spec.sides === "both" (DoubleSide, as
// farfield draws a file loaded with --sides both).
// Colour spaces are three.js's own (glTF factors and COLOR_0 linear, textures sRGB; MTL and PLY
// colours sRGB).  window.farfieldRender(spec) returns the canvas's RGBA bytes, bottom row first,
// as base64.
//
// Two optional modes (the default above is unchanged when neither is asked for):
// spec.lit = {lights: [{direction, color, intensity}], ambient: [r, g, b]} draws every material as a
//   MeshStandardMaterial (glTF's own, cloned; any other converted with roughness 1, metalness 0, its normalMap kept,
//   keeping map, color, alphaMap, opacity, vertexColors, alphaTest and side), lit by one
//   THREE.DirectionalLight per light (direction: unit, from the surface toward the light, world;
//   color: linear RGB; intensity: three.js's) and an AmbientLight of linear colour `ambient`, no
//   environment, no tone mapping, sRGB output (farfield.core.quality.lighting shades the same way).
// spec.octahedral === true draws a GLB's FARFIELD_octahedral_impostor cards with farfield's three.js
//   module (api/dashboard/octahedral-impostor.js, its own ShaderMaterial, left as it is), not their
//   fallback card.
// spec.occluder = {centre, normal, size} adds an opaque square (unlit magenta, both sides) of side
//   `size` through `centre` facing `normal` (world): what writes depth meets it where it lies.
// spec.output === "normal" draws each pixel's world-space shading normal n (after the material's
//   normalMap and normalScale, flipped on back faces of double-sided materials) as n * 0.5 + 0.5,
//   written raw (no sRGB encoding), keeping alphaTest, map alpha and side.
import * as THREE from "three";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";
import { KTX2Loader } from "three/addons/loaders/KTX2Loader.js";
import { MeshoptDecoder } from "three/addons/libs/meshopt_decoder.module.js";
import { MTLLoader } from "three/addons/loaders/MTLLoader.js";
import { OBJLoader } from "three/addons/loaders/OBJLoader.js";
import { PLYLoader } from "three/addons/loaders/PLYLoader.js";
import { octahedralImpostors } from "/dashboard/octahedral-impostor.js";

const canvas = document.createElement("canvas");
document.body.appendChild(canvas);
const renderer = new THREE.WebGLRenderer({
  canvas, antialias: false, alpha: true, premultipliedAlpha: false, preserveDrawingBuffer: true,
});
renderer.setPixelRatio(1);
renderer.setClearColor(0x000000, 0);
renderer.toneMapping = THREE.NoToneMapping;
renderer.outputColorSpace = THREE.SRGBColorSpace;
const gl = renderer.getContext();
// compressed GLBs (core/impostor/glb_compression.py): KTX2 pages through three.js's Basis Universal
// transcoder (its own wasm, from the pinned package) and meshopt geometry through its decoder
const ktx2 = new KTX2Loader().setTranscoderPath("/three/examples/jsm/libs/basis/").detectSupport(renderer);

const loaded = new Map();  // key of (url, options) -> Object3D

function unmipped(texture) {
  // spec.mipmaps === false: the texture sampled without mipmaps (farfield's own renderer samples
  // linearly from the full-size image), to tell the sampler's part in a difference.
  if (!texture) return null;
  const plain = texture.clone();
  plain.minFilter = THREE.LinearFilter;
  plain.generateMipmaps = false;
  plain.needsUpdate = true;
  return plain;
}

function unlit(material, spec) {
  // An OBJ material with a texture takes the texture's colour alone when spec.mapReplacesColor
  // (as Blender's importer draws it); by default three.js's own rule, which is the MTL
  // specification's and farfield's: Kd x map_Kd.
  const color = material.color ? material.color.clone() : new THREE.Color(1, 1, 1);
  if (spec.mapReplacesColor && material.map) color.setRGB(1, 1, 1);
  let alphaTest = material.alphaTest || 0;
  if (spec.alphaCutoff !== null && spec.alphaCutoff !== undefined) alphaTest = spec.alphaCutoff;
  else if (material.transparent) alphaTest = 0.5;  // glTF BLEND drawn as a mask at 0.5, as farfield does
  return new THREE.MeshBasicMaterial({
    map: spec.mipmaps === false ? unmipped(material.map) : material.map || null,
    // MTLLoader's map_d (three.js reads an alpha map's green channel)
    alphaMap: spec.mipmaps === false ? unmipped(material.alphaMap) : material.alphaMap || null,
    color,
    opacity: material.opacity === undefined ? 1 : material.opacity,
    vertexColors: !!material.vertexColors,
    alphaTest,
    side: spec.sides === "both" ? THREE.DoubleSide : material.side === undefined ? THREE.FrontSide : material.side,
    transparent: false,
  });
}

function materialOptions(material, spec) {
  // What every mode keeps of a loaded material: sampled textures, alpha test, sidedness.
  let alphaTest = material.alphaTest || 0;
  if (spec.alphaCutoff !== null && spec.alphaCutoff !== undefined) alphaTest = spec.alphaCutoff;
  else if (material.transparent) alphaTest = 0.5;  // glTF BLEND drawn as a mask at 0.5, as farfield does
  return {
    map: spec.mipmaps === false ? unmipped(material.map) : material.map || null,
    alphaMap: spec.mipmaps === false ? unmipped(material.alphaMap) : material.alphaMap || null,
    alphaTest,
    side: spec.sides === "both" ? THREE.DoubleSide : material.side === undefined ? THREE.FrontSide : material.side,
    transparent: false,
  };
}

function standard(material, spec) {
  // spec.lit or spec.output === "normal": glTF's MeshStandardMaterial as the loader made it (clone),
  // anything else as a rough dielectric with the same colour inputs.
  const options = materialOptions(material, spec);
  if (material.isMeshStandardMaterial) {
    const copy = material.clone();
    copy.setValues(options);
    return copy;
  }
  const color = material.color ? material.color.clone() : new THREE.Color(1, 1, 1);
  if (spec.mapReplacesColor && material.map) color.setRGB(1, 1, 1);
  return new THREE.MeshStandardMaterial({
    ...options,
    color,
    opacity: material.opacity === undefined ? 1 : material.opacity,
    vertexColors: !!material.vertexColors,
    roughness: 1,
    metalness: 0,
    // MTLLoader's ``norm`` (a tangent-space normal map); its ``bump`` height maps are left out, as farfield does
    normalMap: spec.mipmaps === false ? unmipped(material.normalMap) : material.normalMap || null,
    normalScale: material.normalScale ? material.normalScale.clone() : new THREE.Vector2(1, 1),
  });
}

function normalOutput(material) {
  // The standard material's own normal (normal_fragment_begin/maps: vertex normal, DoubleSide flip,
  // normal map) taken from view to world space (viewMatrix is a rotation: its transpose inverts it),
  // written as n * 0.5 + 0.5 with no colour-space conversion; alpha test and map alpha still apply.
  material.onBeforeCompile = (shader) => {
    shader.fragmentShader = shader.fragmentShader
      .replace("#include <opaque_fragment>",
        "gl_FragColor = vec4( inverseTransformDirection( normal, viewMatrix ) * 0.5 + 0.5, 1.0 );")
      .replace("#include <colorspace_fragment>", "");
  };
  material.customProgramCacheKey = () => "farfield-world-normal";
  return material;
}

function pointSized(material) {
  // A glTF POINTS primitive drawn lit or as normals: GLTFLoader gives points an unlit PointsMaterial
  // whatever the glTF material says, so three.js by itself never lights points nor shows their
  // NORMAL.  Here they get the standard material above (three.js's own BRDF, the points' NORMAL
  // attribute as its vertex normal) drawn as one-pixel points (glTF: points are 1 px).
  const key = material.customProgramCacheKey();
  const before = material.onBeforeCompile;
  material.onBeforeCompile = (shader, renderer) => {
    before.call(material, shader, renderer);
    shader.vertexShader = shader.vertexShader.replace(
      "#include <project_vertex>", "#include <project_vertex>\n\tgl_PointSize = 1.0;");
  };
  material.customProgramCacheKey = () => "farfield-point:" + key;
  return material;
}

function convertAll(root, spec) {
  // Every mesh's materials, per mode: unlit (default), lit, or world normals; points too when lit
  // or as normals (pointSized), else GLTFLoader's own PointsMaterial.
  const lit = !!spec.lit || spec.output === "normal";
  root.traverse((node) => {
    if (node.isOctahedralImpostor) return; // its own program
    if (!node.isMesh && !(node.isPoints && lit)) return;
    const hasColors = !!node.geometry.getAttribute("color");
    const one = (m) => {
      let made = lit ? standard(m || {}, spec) : unlit(m || {}, spec);
      made.vertexColors = made.vertexColors || (spec.kind === "ply" && hasColors);
      if (spec.output === "normal") made = normalOutput(made);
      if (node.isPoints) made = pointSized(made);
      return made;
    };
    node.material = Array.isArray(node.material) ? node.material.map(one) : one(node.material);
  });
  return root;
}

async function load(spec) {
  const key = JSON.stringify([spec.url, spec.mtl, spec.alphaCutoff, spec.mapReplacesColor, spec.mipmaps, spec.sides,
    !!spec.lit, spec.output || "color", !!spec.octahedral]);
  if (loaded.has(key)) return loaded.get(key);
  let root;
  if (spec.kind === "gltf") {
    const gltf = await new GLTFLoader().setKTX2Loader(ktx2).setMeshoptDecoder(MeshoptDecoder).loadAsync(spec.url);
    if (spec.octahedral) await octahedralImpostors(gltf);
    root = gltf.scene;
  } else if (spec.kind === "obj") {
    const obj = new OBJLoader();
    if (spec.mtl) {
      const base = spec.mtl.slice(0, spec.mtl.lastIndexOf("/") + 1);
      const materials = await new MTLLoader().setResourcePath(base).loadAsync(spec.mtl);
      materials.preload();
      await Promise.all(Object.values(materials.materials).flatMap((m) => [textureReady(m.map), textureReady(m.alphaMap), textureReady(m.normalMap)]));
      obj.setMaterials(materials);
    }
    root = await obj.loadAsync(spec.url);
  } else if (spec.kind === "ply") {
    const geometry = await new PLYLoader().loadAsync(spec.url);
    root = new THREE.Mesh(geometry, new THREE.MeshBasicMaterial());
  } else {
    throw new Error(`unknown kind ${spec.kind}`);
  }
  convertAll(root, spec);
  root.updateMatrixWorld(true);
  loaded.set(key, root);
  return root;
}

async function textureReady(texture) {
  // MTLLoader starts its image loads without a promise, and TextureLoader sets texture.image only
  // once the image has loaded: wait (up to 30 s) until the texture holds a decoded image.  Without
  // this the first render could draw the pine before its leaf texture arrived (bark only).
  if (!texture) return;
  for (let i = 0; i < 600; i++) {
    const image = texture.image;
    if (image && (image.complete === undefined || image.complete) && (image.naturalWidth || image.width)) return;
    await new Promise((resolve) => setTimeout(resolve, 50));
  }
}

function camera(c) {
  // farfield's Camera: eye, right, up, forward (unit, world), full-angle square fov, near, far.
  const cam = new THREE.PerspectiveCamera((c.fov * 180) / Math.PI, 1, c.near, c.far);
  const basis = new THREE.Matrix4().makeBasis(
    new THREE.Vector3(...c.right), new THREE.Vector3(...c.up), new THREE.Vector3(...c.forward).negate());
  cam.position.set(...c.eye);
  cam.quaternion.setFromRotationMatrix(basis);
  cam.updateMatrixWorld(true);
  return cam;
}

function base64(bytes) {
  let text = "";
  for (let i = 0; i < bytes.length; i += 0x8000) text += String.fromCharCode.apply(null, bytes.subarray(i, i + 0x8000));
  return btoa(text);
}

window.farfieldRender = async (spec) => {
  const root = await load(spec);
  const scene = new THREE.Scene();
  scene.add(root);
  if (spec.lit) {
    for (const l of spec.lit.lights) {
      // position - target is the direction toward the light; the target stays at the origin
      const light = new THREE.DirectionalLight(new THREE.Color().setRGB(...l.color, THREE.LinearSRGBColorSpace), l.intensity);
      light.position.set(...l.direction);
      scene.add(light);
    }
    scene.add(new THREE.AmbientLight(new THREE.Color().setRGB(...spec.lit.ambient, THREE.LinearSRGBColorSpace), 1));
  }
  let occluder = null;
  if (spec.occluder) {
    const o = spec.occluder;
    occluder = new THREE.Mesh(new THREE.PlaneGeometry(o.size, o.size),
      new THREE.MeshBasicMaterial({color: new THREE.Color().setRGB(1, 0, 1, THREE.LinearSRGBColorSpace), side: THREE.DoubleSide}));
    occluder.position.set(...o.centre);
    occluder.quaternion.setFromUnitVectors(new THREE.Vector3(0, 0, 1), new THREE.Vector3(...o.normal).normalize());
    occluder.updateMatrixWorld(true);
    scene.add(occluder);
  }
  const images = [];
  for (const c of spec.cameras) {
    renderer.setSize(c.resolution, c.resolution, false);
    renderer.render(scene, camera(c));
    const pixels = new Uint8Array(c.resolution * c.resolution * 4);
    gl.readPixels(0, 0, c.resolution, c.resolution, gl.RGBA, gl.UNSIGNED_BYTE, pixels);
    images.push(base64(pixels));
  }
  scene.remove(root);
  if (occluder) { occluder.geometry.dispose(); occluder.material.dispose(); }
  return images;
};

window.farfieldInfo = () => {
  const debug = gl.getExtension("WEBGL_debug_renderer_info");
  return {
    three: THREE.REVISION,
    version: gl.getParameter(gl.VERSION),
    renderer: debug ? gl.getParameter(debug.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER),
  };
};
window.farfieldReady = true;
