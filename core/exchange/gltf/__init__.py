"""glTF 2.0 (.glb binary, .gltf JSON) -> (k,) SceneObject: one per primitive of every mesh node of the scene, world transforms applied.

farfield reads glTF itself, following the specification (Khronos, glTF 2.0): trimesh's reader
takes sparse accessors as zeros, normalized and quantized attributes as raw integers, only
``TEXCOORD_0``, no samplers, no texture transforms, and names a mesh's second primitive with a
random suffix.  The modules of this package:

* :mod:`~farfield.core.exchange.gltf.document`: the GLB container, buffers, buffer views, images;
* :mod:`~farfield.core.exchange.gltf.accessors`: accessors (strides, normalized integers, sparse);
* :mod:`~farfield.core.exchange.gltf.materials`: materials, textures, samplers, texture transforms;
* here: the node hierarchy (matrix or TRS, float64), primitives (triangles, strips, fans;
  points and lines skipped with a warning), morph targets at their default weights,
  ``EXT_mesh_gpu_instancing`` instances, and the objects.

Shading normals: a primitive's ``NORMAL`` (float, or byte/short normalized under
``KHR_mesh_quantization``; sparse like any accessor), plus its morph targets' ``NORMAL``
displacements at the default weights and then renormalised (§3.7.2.2, "Morph Targets"), moved by
the inverse transpose of each world matrix (instances' included), so they stay perpendicular under
non-uniform scale and on the front of the winding under a mirroring transform
(:mod:`farfield.core.exchange.normals`); zero or non-finite ones are repaired with one warning per
object.  A primitive without ``NORMAL`` is shaded flat (§3.7.2.1: "When normals are not specified,
client implementations MUST calculate flat normals"): ``normals`` is None.

Object names: the node's name (else its mesh's, else ``node<i>``); a mesh of several primitives
gives ``<name>.p<k>`` for its k-th primitive; names met again (a node instanced along two paths,
two nodes of one name) get ``_1``, ``_2`` ... in traversal order; an instance of
``EXT_mesh_gpu_instancing`` gets ``@<i>``.

Extensions: ``KHR_texture_transform``, ``KHR_mesh_quantization``,
``KHR_materials_pbrSpecularGlossiness`` (its diffuse colour), ``EXT_texture_webp`` and
``EXT_mesh_gpu_instancing`` are read, and ``KHR_materials_emissive_strength`` (the emissive
factor's multiplier, :mod:`~farfield.core.exchange.gltf.materials`); the other ``KHR_materials_*``
change lighting beyond the metallic-roughness material farfield keeps, and are ignored.  A file that *requires* another extension (Draco or
meshopt compression, KTX2 textures) is refused with a message naming it.  Skins are drawn in their
bind pose, with a warning.
"""

from __future__ import annotations

import numpy as np
from trimesh.resolvers import Resolver

from farfield.core.colour_space import linear_to_srgb, srgb_to_linear
from farfield.core.errors import SceneLoadError
from farfield.core.exchange.gltf import accessors
from farfield.core.exchange.gltf.document import Buffers, array, header_json, item, split_glb
from farfield.core.exchange.gltf.materials import NEAREST, Images, Material, material
from farfield.core.exchange.limits import DEFAULT_LIMITS, SceneLimits, check_gltf
from farfield.core.exchange.normals import repair_normals, transform_normals, transform_tangents, uv_tangents
from farfield.core.scene import SceneObject, instances_of, prototype_key

EXTENSIONS = ("glb", "gltf")

__all__ = ["EXTENSIONS", "header_json", "load"]

# Extensions whose meaning farfield draws (or that do not change what it draws).
READ_EXTENSIONS = frozenset(
    {
        "KHR_texture_transform",
        "KHR_mesh_quantization",
        "KHR_materials_pbrSpecularGlossiness",
        "KHR_materials_unlit",
        "EXT_texture_webp",
        "EXT_mesh_gpu_instancing",
    }
)

_TRIANGLES, _STRIP, _FAN = 4, 5, 6
_MODE_NAMES = {0: "POINTS", 1: "LINES", 2: "LINE_LOOP", 3: "LINE_STRIP"}


def _unsupported_required(document: dict) -> list[str]:
    required = document.get("extensionsRequired", [])
    if not isinstance(required, list):
        raise SceneLoadError("glTF 'extensionsRequired' is not an array")
    names = [name if isinstance(name, str) else repr(name) for name in required]
    return sorted(name for name in names if name not in READ_EXTENSIONS and not name.startswith("KHR_materials_"))


def _node_matrix(node: dict, index: int) -> np.ndarray:
    """(4, 4) float64 local transform of a node: ``matrix`` (column-major) or T x R x S."""
    where = f"glTF node {index}"
    try:
        if "matrix" in node:
            matrix = np.array(node["matrix"], dtype=np.float64)
            if matrix.shape != (16,):
                raise SceneLoadError(f"{where}: matrix has {matrix.size} numbers, not 16")
            return matrix.reshape(4, 4).T
        translation = np.array(node.get("translation", (0.0, 0.0, 0.0)), dtype=np.float64)
        rotation = np.array(node.get("rotation", (0.0, 0.0, 0.0, 1.0)), dtype=np.float64)
        scale = np.array(node.get("scale", (1.0, 1.0, 1.0)), dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise SceneLoadError(f"{where}: transform is not numbers: {error}") from error
    if translation.shape != (3,) or rotation.shape != (4,) or scale.shape != (3,):
        raise SceneLoadError(f"{where}: translation/rotation/scale have the wrong number of values")
    x, y, z, w = (rotation / (np.linalg.norm(rotation) or 1.0)).tolist()  # unit quaternion, (x, y, z, w)
    out = np.eye(4)
    out[:3, :3] = np.array(_rotation(x, y, z, w)) * scale[None, :]
    out[:3, 3] = translation
    if not np.isfinite(out).all():
        raise SceneLoadError(f"{where}: transform is not finite")
    return out


def _rotation(x, y, z, w) -> list:
    """The rows of the rotation matrix of the unit quaternion (x, y, z, w): numbers, or arrays of
    many quaternions' components."""
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]


def _trs_matrices(translation: np.ndarray, rotation: np.ndarray, scale: np.ndarray, where: str) -> np.ndarray:
    """(n, 4, 4) float64 T x R x S of (n, 3) translations, (n, 4) quaternions (x, y, z, w;
    normalised here) and (n, 3) scales: every instance of a node at once."""
    length = np.sqrt((rotation * rotation).sum(axis=1))
    x, y, z, w = (rotation / np.where(length > 0.0, length, 1.0)[:, None]).T  # unit quaternions
    out = np.zeros((len(translation), 4, 4))
    out[:, :3, :3] = np.array(_rotation(x, y, z, w)).transpose(2, 0, 1) * scale[:, None, :]
    out[:, :3, 3] = translation
    out[:, 3, 3] = 1.0
    if not np.isfinite(out).all():
        raise SceneLoadError(f"{where}: transform is not finite")
    return out


def _instances(document: dict, buffers: Buffers, node: dict, index: int, limits: SceneLimits) -> np.ndarray | None:
    """EXT_mesh_gpu_instancing: (n, 4, 4) local matrices of the node's instances, or None."""
    extensions = node.get("extensions")
    spec = extensions.get("EXT_mesh_gpu_instancing") if isinstance(extensions, dict) else None
    if not isinstance(spec, dict) or not isinstance(spec.get("attributes"), dict):
        return None
    attributes = spec["attributes"]
    read = {key: accessors.read(document, buffers, value) for key, value in attributes.items()}
    counts = {len(v) for v in read.values()}
    if len(counts) != 1:
        raise SceneLoadError(f"glTF node {index}: EXT_mesh_gpu_instancing attributes have different counts")
    count = counts.pop()
    limits.check("glTF instances (EXT_mesh_gpu_instancing)", count, "nodes")
    # attributes other than the transform's (custom _ID ...) only count
    parts = []
    for key, default in (
        ("TRANSLATION", (0.0, 0.0, 0.0)),
        ("ROTATION", (0.0, 0.0, 0.0, 1.0)),
        ("SCALE", (1.0, 1.0, 1.0)),
    ):
        values = np.asarray(read[key], dtype=np.float64) if key in read else np.tile(default, (count, 1))
        if values.shape != (count, len(default)):
            raise SceneLoadError(f"glTF node {index}: translation/rotation/scale have the wrong number of values")
        parts.append(values)
    return _trs_matrices(*parts, f"glTF node {index}")


def _primitive_name(base: str, k: int, count: int) -> str:
    """The object name of a mesh's k-th of ``count`` primitives (module docstring)."""
    return base if count == 1 else f"{base}.p{k}"


def _mesh_use(node: dict) -> tuple:
    """What makes two nodes' objects the same prototype before any geometry is read: the mesh and
    the node's morph weights (which change its vertices)."""
    weights = node.get("weights")
    return (repr(node.get("mesh")), repr(weights) if weights is not None else None)


def _instance_count(document: dict, node: dict) -> int:
    """Instances a mesh node draws: its ``EXT_mesh_gpu_instancing`` accessors' count, else 1 (a
    malformed extension counts 1 here: reading it later says what is wrong)."""
    extensions = node.get("extensions")
    spec = extensions.get("EXT_mesh_gpu_instancing") if isinstance(extensions, dict) else None
    attributes = spec.get("attributes") if isinstance(spec, dict) else None
    if not isinstance(attributes, dict) or not attributes:
        return 1
    index = next(iter(attributes.values()))
    found = document.get("accessors")
    if (
        isinstance(index, int)
        and isinstance(found, list)
        and 0 <= index < len(found)
        and isinstance(found[index], dict)
    ):
        count = found[index].get("count")
        return count if isinstance(count, int) and count > 0 else 1
    return 1


def _faces(mode: int, indices: np.ndarray, where: str) -> np.ndarray:
    """(f, 3) int64 triangles of a primitive's vertex sequence (glTF 2.0 §3.7.2.1, topology types)."""
    n = len(indices)
    if mode == _TRIANGLES:
        return indices[: n - n % 3].reshape(-1, 3)
    if n < 3:
        return np.zeros((0, 3), dtype=np.int64)
    i = np.arange(n - 2)
    if mode == _STRIP:  # p_i, p_{i+1+i%2}, p_{i+2-i%2}
        return np.stack([indices[i], indices[i + 1 + i % 2], indices[i + 2 - i % 2]], axis=1)
    if mode == _FAN:  # p_{i+1}, p_{i+2}, p_0
        return np.stack([indices[i + 1], indices[i + 2], np.full(n - 2, indices[0])], axis=1)
    raise SceneLoadError(f"{where}: mode {mode!r} is not a glTF primitive mode")


def _shared(values: np.ndarray, dtype: type) -> np.ndarray:
    """``values`` as a read-only C-contiguous array owning its data: what :class:`SceneObject` keeps
    without copying, so the objects of a mesh's instances share it."""
    out = np.array(values, dtype=dtype, order="C")
    out.flags.writeable = False
    return out


def _vertex_colours(values: np.ndarray) -> np.ndarray:
    """(v, 4) uint8 sRGB-encoded RGBA of COLOR_0 (linear floats, (v, 3) or (v, 4))."""
    rgba = np.ones((len(values), 4))
    rgba[:, : values.shape[1]] = np.clip(values, 0.0, 1.0)
    rgba[:, :3] = linear_to_srgb(rgba[:, :3])
    return np.round(rgba * 255.0).astype(np.uint8)


class _Reader:
    """One document's objects as they are gathered (the mutable state of :func:`load`)."""

    def __init__(self, document: dict, buffers: Buffers, limits: SceneLimits) -> None:
        self.document = document
        self.buffers = buffers
        self.images = Images(buffers, limits.texel_budget())
        self.limits = limits
        self.objects: list[SceneObject] = []
        self.warnings: list[str] = []
        self.names: dict[str, int] = {}
        self.materials: dict[object, Material] = {}
        self.nearest_warned = False
        self.triangles = 0
        self.uses: dict[tuple, int] = {}  # instances per mesh use (count_uses)
        self.prototypes: dict[tuple, tuple[list, list, str]] = {}  # mesh use -> (parts, local objects, key)
        # (mesh use, primitive) -> (part, key, local object, places in objects, names, worlds): flush
        self.pending: dict[tuple, tuple] = {}

    def unique(self, name: str) -> str:
        count = self.names.get(name, 0)
        self.names[name] = count + 1
        out = name if count == 0 else f"{name}_{count}"
        while count and out in self.names:
            count += 1
            out = f"{name}_{count}"
        self.names.setdefault(out, 1)
        return out

    def material(self, index: object) -> Material:
        key = (
            index if isinstance(index, int) and not isinstance(index, bool) else None if index is None else repr(index)
        )
        if key not in self.materials:
            found = material(self.document, index, self.warnings)
            if found.blend:
                self.warnings.append(
                    f"material {found.name!r}: alphaMode BLEND is approximated as an alpha mask at {found.alpha_cutoff:g}"
                )
            if found.texture is not None and found.texture.nearest and not self.nearest_warned:
                self.nearest_warned = True
                self.warnings.append(
                    f"material {found.name!r}: sampler magFilter NEAREST ({NEAREST}) is drawn with bilinear filtering"
                )
            self.materials[key] = found
        return self.materials[key]

    def count_uses(self, roots: list[int]) -> None:
        """How many instances each mesh has (:attr:`uses`, by :func:`_mesh_use`), from the node
        hierarchy and the instancing accessors' counts alone, before any geometry is read: a mesh
        of two or more instances gives objects that keep their prototype (:class:`SceneObject`)."""
        stack = list(roots)
        while stack:
            index = stack.pop()
            node = item(self.document, "nodes", index)
            if "mesh" in node and "skin" not in node:
                key = _mesh_use(node)
                self.uses[key] = self.uses.get(key, 0) + _instance_count(self.document, node)
            children = node.get("children", [])
            if isinstance(children, list):
                stack += children

    def walk(self, roots: list[int]) -> None:
        stack = [(root, np.eye(4)) for root in reversed(roots)]
        while stack:
            index, parent = stack.pop()
            node = item(self.document, "nodes", index)
            world = parent @ _node_matrix(node, index)
            if "mesh" in node:
                if "skin" in node:
                    self.warnings.append(f"node {index}: skinning is not applied; the mesh is drawn in its bind pose")
                    world_of_mesh = np.eye(4)[None]  # a skinned mesh ignores its node's transform (glTF §3.7.3)
                else:
                    instances = _instances(self.document, self.buffers, node, index, self.limits)
                    world_of_mesh = world[None] if instances is None else world @ instances
                self.mesh(node, index, world_of_mesh)
            children = node.get("children", [])
            if isinstance(children, list):
                stack += [(child, world) for child in reversed(children)]

    def mesh(self, node: dict, index: int, worlds: np.ndarray) -> None:
        """The objects of a mesh node drawn at ``worlds`` (n, 4, 4): built now, or, for a mesh of
        several instances, named and counted now and moved at once with all the mesh's other
        instances in :meth:`flush`."""
        mesh_index = node["mesh"]
        mesh = item(self.document, "meshes", mesh_index)
        primitives = mesh.get("primitives")
        if not isinstance(primitives, list) or not primitives:
            raise SceneLoadError(f"glTF mesh {mesh_index} has no primitives")
        base = node.get("name") or mesh.get("name") or f"node{index}"
        base = str(base)
        weights = node.get("weights", mesh.get("weights"))
        use = _mesh_use(node)
        shared = "skin" not in node and self.uses.get(use, 0) > 1
        if shared and use in self.prototypes:
            parts, locals_, key = self.prototypes[use]  # read once for every node that uses the mesh
        else:
            parts = [
                self.primitive(p, f"glTF mesh {mesh_index} primitive {k}", weights) for k, p in enumerate(primitives)
            ]
            locals_, key = [], None
            if shared:  # the mesh in its own space, once: what its instances share
                locals_ = [
                    None
                    if part is None
                    else self.build(f"{_primitive_name(base, k, len(parts))}.local", part, np.eye(4))
                    for k, part in enumerate(parts)
                ]
                key = prototype_key([obj for obj in locals_ if obj is not None])
                self.prototypes[use] = (parts, locals_, key)
        many_instances = len(worlds) > 1
        for k, part in enumerate(parts):
            if part is None:
                continue
            name = _primitive_name(base, k, len(primitives))
            for i, world in enumerate(worlds):
                unique = self.unique(f"{name}@{i}" if many_instances else name)
                if key is None:
                    self.add(self.build(unique, part, world))
                    continue
                self.add(None, len(part["faces"]))  # its place, filled by flush
                pending = self.pending.setdefault((use, k), (part, key, locals_[k], [], [], []))
                pending[3].append(len(self.objects) - 1)
                pending[4].append(unique)
                pending[5].append(world)

    def flush(self) -> None:
        """The instances :meth:`mesh` left pending, each primitive's moved at once (:meth:`moved`)
        or, where it cannot be, built one by one."""
        for part, key, local, places, names, worlds in self.pending.values():
            worlds = np.stack(worlds)
            moved = self.moved(names, part, worlds, key, local)
            for i, place in enumerate(places):
                self.objects[place] = (
                    moved[i] if moved is not None else self.build(names[i], part, worlds[i], (key, worlds[i], local))
                )
        self.pending.clear()

    def primitive(self, spec: object, where: str, weights: object) -> dict | None:
        if not isinstance(spec, dict) or not isinstance(spec.get("attributes"), dict):
            raise SceneLoadError(f"{where}: has no attributes object")
        attributes = spec["attributes"]
        mode = spec.get("mode", _TRIANGLES)
        if isinstance(mode, bool) or not isinstance(mode, int):
            raise SceneLoadError(f"{where}: mode {mode!r} is not a glTF primitive mode")
        if mode in _MODE_NAMES:
            self.warnings.append(f"{where}: skipped {_MODE_NAMES[mode]} (not triangles)")
            return None
        if "POSITION" not in attributes:
            self.warnings.append(f"{where}: skipped, it has no POSITION")
            return None
        positions = accessors.read(self.document, self.buffers, attributes["POSITION"])
        if positions.shape[1] != 3:
            raise SceneLoadError(f"{where}: POSITION is not VEC3")
        count = len(positions)
        positions = positions + self.morph(spec, weights, count, where, "POSITION")
        if "indices" in spec:
            indices = accessors.read(self.document, self.buffers, spec["indices"], as_float=False, indices=True)[:, 0]
            if len(indices) and (indices.min() < 0 or indices.max() >= count):
                raise SceneLoadError(f"{where}: an index reaches vertex {int(indices.max())} of {count}")
        else:
            indices = np.arange(count, dtype=np.int64)
        faces = _faces(mode, indices, where)
        if len(faces) == 0:
            self.warnings.append(f"{where}: skipped a primitive without triangles")
            return None
        found = self.material(spec.get("material"))
        faces = _shared(faces, np.int64)  # one array for every instance of the mesh (none mirrored)
        part = {"positions": positions, "faces": faces, "material": found, "colours": None, "uv": None, "where": where}
        part["normals"] = self.normals(spec, weights, count, where)
        if "COLOR_0" in attributes:
            colours = accessors.read(self.document, self.buffers, attributes["COLOR_0"])
            if len(colours) != count or colours.shape[1] not in (3, 4):
                raise SceneLoadError(
                    f"{where}: COLOR_0 has {len(colours)} elements of {colours.shape[1]}, expected {count} of 3 or 4"
                )
            part["colours"] = _shared(_vertex_colours(colours), np.uint8)
        ref = found.texture
        if ref is not None:
            key = f"TEXCOORD_{ref.tex_coord}"
            if key not in attributes:
                self.warnings.append(
                    f"{where}: its texture uses {key}, which it does not have; using the material colour"
                )
            else:
                uv = accessors.read(self.document, self.buffers, attributes[key])
                if len(uv) != count or uv.shape[1] != 2:
                    raise SceneLoadError(f"{where}: {key} has {len(uv)} elements, expected {count} of 2")
                if ref.transform is not None:
                    uv = uv @ ref.transform[:2, :2].T + ref.transform[:2, 2]
                part["uv"] = uv
        part["normal_uv"] = part["tangents"] = None
        if found.normal is not None and part["normals"] is not None:
            self.normal_attributes(part, found.normal, attributes, count, where)
        self.material_attributes(part, found, attributes, count, where)
        return part

    def material_attributes(self, part: dict, found: Material, attributes: dict, count: int, where: str) -> None:
        """The material textures' uv into ``part`` (``material_uv``, glTF space, transformed) and
        which textures map through it (``material_keys``): the first texture's set and transform;
        a texture on another set or transform, or on a set the primitive lacks, is left out with a
        warning (its factor kept)."""
        part["material_uv"], part["material_keys"] = None, ()
        chosen, keys = None, []
        for key, ref in found.material_textures():
            set_name = f"TEXCOORD_{ref.tex_coord}"
            matrix = np.eye(3) if ref.transform is None else ref.transform
            if chosen is None:
                if set_name not in attributes:
                    self.warnings.append(f"{where}: its {key} uses {set_name}, which it does not have; ignored")
                    continue
                uv = accessors.read(self.document, self.buffers, attributes[set_name])
                if uv.ndim != 2 or uv.shape != (count, 2) or not np.isfinite(uv).all():
                    self.warnings.append(f"{where}: {set_name} of its {key} is not {count} finite pairs; ignored")
                    continue
                chosen = (ref.tex_coord, matrix)
                part["material_uv"] = uv @ matrix[:2, :2].T + matrix[:2, 2]
            elif ref.tex_coord != chosen[0] or not np.array_equal(matrix, chosen[1]):
                self.warnings.append(
                    f"material {found.name!r}: its {key} maps through other texture coordinates than its "
                    f"{keys[0]} (texCoord or KHR_texture_transform); farfield keeps one material uv, so it is "
                    "ignored (its factor kept)"
                )
                continue
            keys.append(key)
        part["material_keys"] = tuple(keys)

    def normal_attributes(self, part: dict, ref, attributes: dict, count: int, where: str) -> None:
        """The normal map's uv and ``TANGENT`` of a primitive into ``part``.  A normal map only
        shades: where its attributes do not fit, it is left out (or its tangents derived) with a
        warning, never the file refused."""
        key = f"TEXCOORD_{ref.tex_coord}"
        if key not in attributes:
            self.warnings.append(f"{where}: its normal texture uses {key}, which it does not have; ignored")
            return
        uv = accessors.read(self.document, self.buffers, attributes[key])
        if uv.ndim != 2 or uv.shape != (count, 2) or not np.isfinite(uv).all():
            self.warnings.append(
                f"{where}: {key} of its normal texture is not {count} finite pairs; the map is ignored"
            )
            return
        if ref.transform is not None:
            uv = uv @ ref.transform[:2, :2].T + ref.transform[:2, 2]
        part["normal_uv"] = uv
        if "TANGENT" in attributes:
            tangents = accessors.read(self.document, self.buffers, attributes["TANGENT"])
            if tangents.ndim == 2 and tangents.shape == (count, 4) and np.isfinite(tangents).all():
                part["tangents"] = tangents
            else:
                self.warnings.append(
                    f"{where}: TANGENT is not {count} finite VEC4 elements; tangents are derived from the uv instead"
                )

    def normals(self, spec: dict, weights: object, count: int, where: str) -> np.ndarray | None:
        """(v, 3) float64 model-space ``NORMAL`` of a primitive with its morph targets' displacements
        at the default weights (§3.7.2.2: added, then renormalised, which the object does), or None."""
        attributes = spec["attributes"]
        if "NORMAL" not in attributes:
            return None
        normals = accessors.read(self.document, self.buffers, attributes["NORMAL"])
        if normals.ndim != 2 or normals.shape != (count, 3):
            # Shading only: the primitive is drawn flat (with a warning) rather than refused.
            self.warnings.append(
                f"{where}: NORMAL has {len(normals)} elements of {normals.shape[1] if normals.ndim == 2 else '?'}, "
                f"expected {count} of 3; shaded flat"
            )
            return None
        return normals + self.morph(spec, weights, count, where, "NORMAL")

    def morph(self, spec: dict, weights: object, count: int, where: str, attribute: str) -> np.ndarray:
        """Sum of the morph targets' ``attribute`` (POSITION or NORMAL) displacements at the default
        weights (0 without targets), glTF 2.0 §3.7.2.2."""
        targets = spec.get("targets")
        if not isinstance(targets, list) or not targets or not isinstance(weights, list):
            return np.zeros((count, 3))
        out = np.zeros((count, 3))
        for target, weight in zip(targets, weights):
            if isinstance(target, dict) and attribute in target and isinstance(weight, int | float) and weight:
                offsets = accessors.read(self.document, self.buffers, target[attribute])
                if offsets.shape != (count, 3):
                    raise SceneLoadError(
                        f"{where}: a morph target's {attribute} has {len(offsets)} elements, expected {count}"
                    )
                out += float(weight) * offsets
        return out

    def add(self, obj: SceneObject | None, triangles: int | None = None) -> None:
        """Append ``obj`` (None: a place :meth:`flush` fills with an object of ``triangles``),
        counted against the limits."""
        self.triangles += len(obj.faces) if obj is not None else triangles
        self.limits.check("objects", len(self.objects) + 1, "nodes")
        self.limits.check("triangles once node instancing is applied", self.triangles, "triangles")
        self.objects.append(obj)

    def moved(self, names: list[str], part: dict, worlds: np.ndarray, key: str, local: SceneObject) -> list | None:
        """The instances ``names`` of ``part`` at ``worlds``: its mesh's ``local`` object moved, all
        at once (:func:`~farfield.core.scene.instances_of`: what the instances share is not built
        and checked again), or None where :meth:`build` must make each: a normal map (its tangents
        may be derived from an instance's own vertices) or normals a move makes zero (repaired with
        a warning)."""
        if part.get("normal_uv") is not None and part["normals"] is not None:
            return None
        try:
            return instances_of(local, names, worlds, key, part["normals"])
        except SceneLoadError:
            return None  # build says what is wrong, or repairs it

    def build(self, name: str, part: dict, world: np.ndarray, instance: tuple | None = None) -> SceneObject:
        found: Material = part["material"]
        positions, faces = part["positions"], part["faces"]
        vertices = positions @ world[:3, :3].T + world[:3, 3]
        if np.linalg.det(world[:3, :3]) < 0.0:
            faces = faces[:, ::-1]  # a mirroring transform turns counter-clockwise faces clockwise
        normals = None
        if part["normals"] is not None:
            normals, warning = repair_normals(name, vertices, faces, transform_normals(part["normals"], world[:3, :3]))
            if warning is not None:
                self.warnings.append(warning)
        if "colour" not in part:  # the same for every instance of the part: computed once, shared
            part["colour"] = self.colour(name, found, part)
        base_color, texture, uv = part["colour"]
        base_color = base_color.copy()
        normal_map = self.normal_map(name, found, part, vertices, faces, normals, world)
        shading = self.shading(name, found, part, uv)
        prototype, matrix, local = (None, None, None) if instance is None else instance
        return SceneObject(
            prototype=prototype,
            instance_matrix=matrix,
            local=local,
            name=name,
            vertices=vertices,
            faces=faces,
            uv=uv,
            vertex_colors=part["colours"],
            base_color=base_color,
            texture=texture,
            alpha_cutoff=found.alpha_cutoff,
            double_sided=found.double_sided,
            normals=normals,
            **normal_map,
            **shading,
        )

    def colour(self, name: str, found: Material, part: dict) -> tuple:
        """(base colour, texture or None, uv or None) of a part: its texture wrapped by its sampler
        (:meth:`Images.wrapped`), uv in farfield's v-up convention, frozen so that its objects share it."""
        base_color = found.base_color.copy()
        texture = uv = None
        if part["uv"] is not None:
            wrapped = self.images.wrapped(found.texture, part["uv"], name, self.warnings)
            if wrapped is not None:
                decoded, uv = wrapped
                uv = np.column_stack([uv[:, 0], 1.0 - uv[:, 1]])  # glTF's v down -> farfield's v up
                if found.alpha_cutoff is not None and decoded.max_alpha * base_color[3] < 255.0 * found.alpha_cutoff:
                    self.warnings.append(
                        f"object {name!r}: no texel of its texture passes its alpha cut ({found.alpha_cutoff:g}); it is invisible"
                    )
                if decoded.single is not None:
                    # One colour: the same as a material colour, cheaper.
                    base_color = base_color * _srgb_unit(decoded.single)
                    uv = None
                else:
                    texture = decoded.rgba
        if uv is not None:  # frozen as SceneObject keeps it, so that material_uv can be the very array
            uv = np.array(uv, dtype=np.float64, order="C")
            uv.flags.writeable = False
        return base_color, texture, uv

    def shading(self, name: str, found: Material, part: dict, uv: np.ndarray | None) -> dict:
        """The object's metallic-roughness material fields (:class:`SceneObject`'s): the factors,
        and the textures of ``part["material_keys"]`` over one ``material_uv`` (the very array
        ``uv`` is where they map the same).  Each texture's sampler wraps as the base colour's do;
        one whose wrap modes move the uv elsewhere than the first's is left out with a warning."""
        out = {
            "metallic_factor": found.metallic,
            "roughness_factor": found.roughness,
            "occlusion_strength": found.occlusion_strength,
            "emissive_factor": found.emissive_factor,
        }
        material_uv = None
        refs = {
            "metallic_roughness_texture": found.metallic_roughness,
            "occlusion_texture": found.occlusion,
            "emissive_texture": found.emissive,
        }
        for key in part.get("material_keys", ()):
            if key == "emissive_texture" and not found.emissive_factor.any():
                continue  # multiplied by a zero factor: no emission
            wrapped = self.images.wrapped(refs[key], part["material_uv"], name, self.warnings)
            if wrapped is None:
                continue
            decoded, wrapped_uv = wrapped
            wrapped_uv = np.column_stack([wrapped_uv[:, 0], 1.0 - wrapped_uv[:, 1]])  # glTF's v down -> v up
            if material_uv is None:
                material_uv = uv if uv is not None and np.array_equal(uv, wrapped_uv) else wrapped_uv
            elif not np.array_equal(material_uv, wrapped_uv):
                self.warnings.append(
                    f"material {found.name!r}: its {key} wraps (sampler) otherwise than its other material "
                    "textures; farfield keeps one material uv, so it is ignored (its factor kept)"
                )
                continue
            out[key] = decoded.rgba
        if material_uv is not None:
            out["material_uv"] = material_uv
        return out

    def normal_map(self, name, found: Material, part: dict, vertices, faces, normals, world) -> dict:
        """The object's normal map (``normal_texture``, ``normal_uv``, ``tangents``, ``normal_scale``)
        from its material's ``normalTexture`` (glTF 2.0 §3.9.3), or {}: the texture's sampler wraps
        as the base colour's do (:meth:`Images.wrapped`), ``TANGENT`` is moved by the node
        (:func:`~farfield.core.exchange.normals.transform_tangents`) or, where missing, derived from
        the uv (:func:`~farfield.core.exchange.normals.uv_tangents`).  A primitive without
        ``NORMAL`` has no normal map (flat shading has no tangent frame to perturb)."""
        if part.get("normal_uv") is None or normals is None:
            return {}
        wrapped = self.images.wrapped(found.normal, part["normal_uv"], name, self.warnings)
        if wrapped is None:
            return {}
        decoded, uv = wrapped
        uv = np.column_stack([uv[:, 0], 1.0 - uv[:, 1]])  # glTF's v down -> farfield's v up
        if part["tangents"] is not None:
            tangents = transform_tangents(part["tangents"], world[:3, :3])
        else:
            tangents = uv_tangents(vertices, faces, normals, uv)
        return {
            "normal_texture": decoded.rgba,
            "normal_uv": uv,
            "tangents": tangents,
            "normal_scale": found.normal_scale,
        }


def _srgb_unit(rgba_u8: np.ndarray) -> np.ndarray:
    """(4,) float64 linear RGBA of (4,) uint8 sRGB-encoded RGBA."""
    out = np.asarray(rgba_u8, dtype=np.float64) / 255.0
    out[:3] = srgb_to_linear(out[:3])
    return out


def _roots(document: dict) -> list[int]:
    """The root nodes to draw: the default scene's (``scene``, else the first); with no ``scenes``
    at all, every node that is no node's child (``check_gltf`` then checked every node as a root,
    so the walk meets no cycle).  An empty ``scenes`` array draws nothing."""
    if "scenes" in document:
        scenes = array(document, "scenes")
        if not scenes:
            return []
        chosen = document.get("scene", 0)
        scene = item(document, "scenes", chosen)
        roots = scene.get("nodes", [])
        if not isinstance(roots, list):
            raise SceneLoadError(f"glTF scene {chosen}: nodes is not an array")
        return roots
    nodes = array(document, "nodes")
    children = set()
    for node in nodes:
        listed = node.get("children", []) if isinstance(node, dict) else []
        children.update(c for c in (listed if isinstance(listed, list) else []) if isinstance(c, int))
    return [i for i in range(len(nodes)) if i not in children]


def load(
    data: bytes, extension: str, name: str, resolver: Resolver, limits: SceneLimits = DEFAULT_LIMITS, **_options
) -> tuple[tuple[SceneObject, ...], tuple[str, ...]]:
    """Objects and warnings of a .glb / .gltf file (see the module docstring).

    Parameters
    ----------
    data : bytes
        The file.
    extension : str
        ``"glb"`` or ``"gltf"``, lower case without the dot.
    name : str
        The file's name, for messages.
    resolver : trimesh.resolvers.Resolver
        Finds external buffers and images of a ``.gltf``.
    limits : SceneLimits
        The most structure the file may have, checked from its JSON before buffers are read.

    Raises
    ------
    SceneLoadError
        Not glTF 2.0, malformed, an extension it requires that farfield does not read, a buffer
        that cannot be found.
    SceneTooCostlyError
        Its node hierarchy, primitives, instances or triangles are beyond ``limits``.
    """
    text, binary = split_glb(data) if extension == "glb" else (data, None)
    document = header_json(text)  # the GLB split once
    asset = document.get("asset")
    version = asset.get("version") if isinstance(asset, dict) else None
    if isinstance(version, str) and not version.startswith("2."):
        raise SceneLoadError(f"glTF version {version}: farfield reads glTF 2.0")
    missing = _unsupported_required(document)
    if missing:
        raise SceneLoadError(
            f"the file requires the glTF extension{'s' if len(missing) > 1 else ''} {', '.join(missing)}, "
            "which farfield does not read; export it without them (e.g. gltf-transform copy, or an exporter's "
            "option to turn compression off)"
        )
    check_gltf(document, limits)
    reader = _Reader(document, Buffers(document, binary, resolver), limits)
    roots = _roots(document)
    reader.count_uses(roots)
    reader.walk(roots)
    reader.flush()
    return tuple(reader.objects), tuple(dict.fromkeys(reader.warnings))
