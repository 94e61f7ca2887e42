"""Small glTF 2.0 files built by tests, each exercising a rule of the specification.

:class:`GltfBuilder` writes what the Khronos validator accepts (aligned buffer views, POSITION
bounds, ``extensionsUsed``/``extensionsRequired``); tests check the files with the validator
and draw them with three.js's GLTFLoader (``tests/threejs.py``) beside farfield's loader.
"""

from __future__ import annotations

import io
import json
import struct
from pathlib import Path

import numpy as np
import PIL.Image

FLOAT, BYTE, UBYTE, SHORT, USHORT, UINT = 5126, 5120, 5121, 5122, 5123, 5125
REPEAT, CLAMP, MIRROR = 10497, 33071, 33648
_NUMPY = {FLOAT: np.float32, BYTE: np.int8, UBYTE: np.uint8, SHORT: np.int16, USHORT: np.uint16, UINT: np.uint32}
_KINDS = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4"}
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963


class GltfBuilder:
    """A glTF document and its one binary buffer, built piece by piece."""

    def __init__(self) -> None:
        self.doc: dict = {
            "asset": {"version": "2.0", "generator": "farfield tests"},
            "scene": 0,
            "scenes": [{"nodes": []}],
        }
        self.blob = bytearray()
        self.used: set[str] = set()
        self.required: set[str] = set()

    def _add(self, key: str, value: dict) -> int:
        self.doc.setdefault(key, []).append(value)
        return len(self.doc[key]) - 1

    def view(self, data: bytes, target: int | None = None, stride: int | None = None) -> int:
        self.blob += b"\0" * (-len(self.blob) % 4)
        spec = {"buffer": 0, "byteOffset": len(self.blob), "byteLength": len(data)}
        if target is not None:
            spec["target"] = target
        if stride is not None:
            spec["byteStride"] = stride
        self.blob += data
        return self._add("bufferViews", spec)

    def accessor(self, values, component: int = FLOAT, normalized: bool = False, target: int | None = ARRAY_BUFFER,
                 bounds: bool = False, view: bool = True) -> int:  # fmt: skip
        """An accessor of ``values`` ((n,) or (n, k)) stored as ``component``; ``view=False``: no
        buffer view (zeros, for a sparse accessor to fill)."""
        values = np.asarray(values)
        rows = values.reshape(len(values), -1)
        stored = rows.astype(_NUMPY[component])
        width = rows.shape[1]
        row_bytes = stored.itemsize * width
        stride = None
        data = stored.tobytes()
        if target == ARRAY_BUFFER and row_bytes % 4:
            stride = row_bytes + (-row_bytes % 4)  # vertex attributes are 4-byte aligned
            padded = np.zeros((len(rows), stride), dtype=np.uint8)
            padded[:, :row_bytes] = np.frombuffer(data, dtype=np.uint8).reshape(len(rows), row_bytes)
            data = padded.tobytes()
        spec = {"componentType": component, "count": len(rows), "type": _KINDS[width]}
        if view:
            spec["bufferView"] = self.view(data, target, stride)
        if normalized:
            spec["normalized"] = True
        if bounds:
            spec["min"] = stored.min(axis=0).tolist()
            spec["max"] = stored.max(axis=0).tolist()
        return self._add("accessors", spec)

    def normal_accessor(self, normals) -> int:
        """A NORMAL accessor: float32, or normalized BYTE/SHORT for int8/int16 ``normals``
        (KHR_mesh_quantization, which the file then requires)."""
        normals = np.asarray(normals)
        component = {np.dtype(np.int8): BYTE, np.dtype(np.int16): SHORT}.get(normals.dtype, FLOAT)
        if component != FLOAT:
            self.used.add("KHR_mesh_quantization")
            self.required.add("KHR_mesh_quantization")
        return self.accessor(normals, component, normalized=component != FLOAT)

    def sparse(self, accessor: int, indices, values, component: int = FLOAT) -> None:
        """Give ``accessor`` a sparse substitution of ``values`` at ``indices``."""
        indices = np.asarray(indices, dtype=np.uint16)
        values = np.asarray(values).astype(_NUMPY[component])
        spec = self.doc["accessors"][accessor]
        spec["sparse"] = {
            "count": len(indices),
            "indices": {"bufferView": self.view(indices.tobytes()), "componentType": USHORT},
            "values": {"bufferView": self.view(values.tobytes())},
        }

    def image(self, rgba: np.ndarray) -> int:
        out = io.BytesIO()
        PIL.Image.fromarray(np.asarray(rgba, dtype=np.uint8)).save(out, format="PNG")
        return self._add("images", {"bufferView": self.view(out.getvalue()), "mimeType": "image/png"})

    def texture(self, image: int, wrap=(REPEAT, REPEAT), filters=(9729, 9729)) -> int:
        sampler = self._add(
            "samplers", {"wrapS": wrap[0], "wrapT": wrap[1], "magFilter": filters[0], "minFilter": filters[1]}
        )
        return self._add("textures", {"source": image, "sampler": sampler})

    def material(self, color=(1.0, 1.0, 1.0, 1.0), texture: int | None = None, tex_coord: int = 0,
                 transform: dict | None = None, double_sided: bool = True, **extra) -> int:  # fmt: skip
        pbr: dict = {"baseColorFactor": list(color), "metallicFactor": 0.0}
        if texture is not None:
            info: dict = {"index": texture}
            if tex_coord:
                info["texCoord"] = tex_coord
            if transform is not None:
                info["extensions"] = {"KHR_texture_transform": transform}
                self.used.add("KHR_texture_transform")
            pbr["baseColorTexture"] = info
        return self._add("materials", {"pbrMetallicRoughness": pbr, "doubleSided": double_sided, **extra})

    def mesh(self, primitives: list[dict], name: str | None = None) -> int:
        spec: dict = {"primitives": primitives}
        if name:
            spec["name"] = name
        return self._add("meshes", spec)

    def node(self, root: bool = True, **spec) -> int:
        index = self._add("nodes", spec)
        if root:
            self.doc["scenes"][0]["nodes"].append(index)
        return index

    def quad(self, name: str, corner, size: float, material: int, uv=None, uv1=None, colours=None,
             position_component: int = FLOAT, normals=None, tangents=None, **node) -> int:  # fmt: skip
        """A node with a square facing +z, lower-left ``corner``, side ``size``; ``normals`` (4, 3):
        its NORMAL, float, or normalized BYTE/SHORT when given as int8/int16 (KHR_mesh_quantization);
        ``tangents`` (4, 4): its TANGENT."""
        corner = np.asarray(corner, dtype=np.float64)
        square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64)
        attributes = {}
        if position_component == FLOAT:
            attributes["POSITION"] = self.accessor(corner + size * square, bounds=True)
        else:  # KHR_mesh_quantization: normalized integers in the unit square, the node scales
            top = np.iinfo(_NUMPY[position_component]).max
            attributes["POSITION"] = self.accessor(square * top, position_component, normalized=True, bounds=True)
            node = {"translation": corner.tolist(), "scale": [size, size, size], **node}
            self.used.add("KHR_mesh_quantization")
            self.required.add("KHR_mesh_quantization")
        for k, coords in enumerate((uv, uv1)):
            if coords is not None:
                attributes[f"TEXCOORD_{k}"] = self.accessor(coords)
        if colours is not None:
            colours = np.asarray(colours)
            component = UBYTE if colours.dtype == np.uint8 else USHORT if colours.dtype == np.uint16 else FLOAT
            attributes["COLOR_0"] = self.accessor(colours, component, normalized=component != FLOAT)
        if normals is not None:
            attributes["NORMAL"] = self.normal_accessor(normals)
        if tangents is not None:
            attributes["TANGENT"] = self.accessor(np.asarray(tangents, dtype=np.float64))
        indices = self.accessor(np.array([0, 1, 2, 0, 2, 3]), USHORT, target=ELEMENT_ARRAY_BUFFER)
        mesh = self.mesh([{"attributes": attributes, "indices": indices, "material": material}])
        return self.node(name=name, mesh=mesh, **node)

    def _document(self) -> dict:
        doc = dict(self.doc)
        doc["buffers"] = [{"byteLength": len(self.blob)}]
        if self.used:
            doc["extensionsUsed"] = sorted(self.used)
        if self.required:
            doc["extensionsRequired"] = sorted(self.required)
        return doc

    def glb(self) -> bytes:
        text = json.dumps(self._document()).encode()
        text += b" " * (-len(text) % 4)
        blob = bytes(self.blob) + b"\0" * (-len(self.blob) % 4)
        body = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(blob), 0x004E4942) + blob
        return b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body

    def write(self, path: Path) -> Path:
        path.write_bytes(self.glb())
        return path


def gradient(size: int = 16) -> np.ndarray:
    """(size, size, 4) uint8: red rises to the right, green downwards (glTF's v), blue 64, opaque."""
    ramp = np.linspace(16, 240, size)
    rgba = np.zeros((size, size, 4), dtype=np.uint8)
    rgba[..., 0] = ramp[None, :]
    rgba[..., 1] = ramp[:, None]
    rgba[..., 2] = 64
    rgba[..., 3] = 255
    return rgba


SQUARE_UV = np.array([[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]])  # glTF uv of quad()'s corners (v down)


def sampler_scene(path: Path) -> Path:
    """Quads in a row, each one rule: CLAMP_TO_EDGE and MIRRORED_REPEAT over uv -0.5..1.5,
    KHR_texture_transform (offset, rotation, scale), ``texCoord`` 1, COLOR_0 as normalized
    bytes, positions as normalized shorts (KHR_mesh_quantization), and a sparse POSITION."""
    b = GltfBuilder()
    image = b.image(gradient())
    wide = SQUARE_UV * 2.0 - 0.5
    clamp = b.material(texture=b.texture(image, (CLAMP, CLAMP)))
    mirror = b.material(texture=b.texture(image, (MIRROR, MIRROR)))
    repeat = b.texture(image)
    moved = b.material(texture=repeat, transform={"offset": [0.25, 0.1], "rotation": 0.4, "scale": [1.5, 0.75]})
    second = b.material(texture=repeat, tex_coord=1)
    plain = b.material(color=(0.8, 0.9, 1.0, 1.0))
    b.quad("clamp", [0, 0, 0], 1.0, clamp, uv=wide)
    b.quad("mirror", [1.1, 0, 0], 1.0, mirror, uv=wide)
    b.quad("transform", [2.2, 0, 0], 1.0, moved, uv=SQUARE_UV)
    b.quad("texcoord1", [0, 1.1, 0], 1.0, second, uv=np.full((4, 2), 0.5), uv1=SQUARE_UV * 0.5)
    b.quad(
        "colours",
        [1.1, 1.1, 0],
        1.0,
        plain,
        colours=np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [255, 255, 0]], np.uint8),
    )
    b.quad("quantized", [2.2, 1.1, 0], 1.0, plain, position_component=SHORT)
    # Sparse: the stored square is collapsed to a point; the sparse part restores three corners.
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64) + [0.0, 2.2, 0.0]
    positions = b.accessor(np.repeat(square[:1], 4, axis=0), bounds=True)
    b.doc["accessors"][positions].update(min=square.min(axis=0).tolist(), max=square.max(axis=0).tolist())
    b.sparse(positions, [1, 2, 3], square[1:])
    indices = b.accessor(np.array([0, 1, 2, 0, 2, 3]), USHORT, target=ELEMENT_ARRAY_BUFFER)
    b.node(name="sparse", mesh=b.mesh([{"attributes": {"POSITION": positions}, "indices": indices, "material": plain}]))
    return b.write(path)


def instanced_scene(path: Path, count: int = 3, texture: bool = True) -> Path:
    """A GLB drawing one textured box ``count`` times with ``EXT_mesh_gpu_instancing`` (node
    "box", instances translated 4 apart along x, turned about z and uniformly scaled), and one
    quad mesh used by two nodes ("left", "right"): both kinds of instancing a loader keeps."""
    import trimesh

    b = GltfBuilder()
    box = trimesh.creation.box(extents=(1.0, 0.6, 0.8))
    vertices = np.asarray(box.vertices)
    uv = (vertices[:, :2] - vertices[:, :2].min(axis=0)) / np.ptp(vertices[:, :2], axis=0)
    material = b.material(texture=b.texture(b.image(gradient()))) if texture else b.material((0.8, 0.3, 0.2, 1.0))
    attributes = {"POSITION": b.accessor(vertices, bounds=True), "NORMAL": b.accessor(np.asarray(box.vertex_normals))}
    if texture:
        attributes["TEXCOORD_0"] = b.accessor(uv)
    indices = b.accessor(np.asarray(box.faces).reshape(-1), USHORT, target=ELEMENT_ARRAY_BUFFER)
    mesh = b.mesh([{"attributes": attributes, "indices": indices, "material": material}], name="box")
    k = np.arange(count, dtype=np.float64)
    angles = 0.3 * k
    translation = np.column_stack([4.0 * k, np.zeros(count), np.zeros(count)])
    rotation = np.column_stack([np.zeros(count), np.zeros(count), np.sin(angles / 2), np.cos(angles / 2)])
    scale = np.repeat((1.0 + 0.1 * (k % 3))[:, None], 3, axis=1)
    spec = {"TRANSLATION": b.accessor(translation), "ROTATION": b.accessor(rotation), "SCALE": b.accessor(scale)}
    b.node(name="box", mesh=mesh, extensions={"EXT_mesh_gpu_instancing": {"attributes": spec}})
    b.used.add("EXT_mesh_gpu_instancing")
    quad = b.doc["nodes"][b.quad("left", [0, 0, 0], 1.0, b.material((0.2, 0.6, 0.2, 1.0)), translation=[0, 5, 0])]
    b.node(name="right", mesh=quad["mesh"], translation=[3.0, 5.0, 0.0])
    return b.write(path)
