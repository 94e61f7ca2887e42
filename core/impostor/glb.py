"""glTF 2.0 binary (GLB) bytes of one impostor: its float64 world quads or mesh -> float32 indexed triangles.

The file is deterministic: the same impostor gives byte-identical bytes (fixed JSON key order, no
timestamps, PNG pages encoded with fixed settings by :func:`page_png`).  Layout (glTF 2.0 spec,
"GLB File Format Specification" and "Properties Reference"):

* 12-byte header: magic ``glTF``, version 2, total length (little-endian uint32).
* JSON chunk (type ``JSON``), padded with spaces (0x20) to a multiple of 4 bytes.
* BIN chunk (type ``BIN\\0``), padded with zeros; every bufferView inside starts on a 4-byte
  boundary.  For each page with quads, in page order: indices, POSITION, TEXCOORD_0; then every
  page's PNG image.
* One scene, one node, one mesh.  The node's ``extras.farfield`` says where the impostor is valid
  (:func:`engine_metadata`: technique, view cell, reference viewpoint, resolution, field of view).
  Its ``translation`` is the impostor's reference viewpoint as float64 JSON numbers, and POSITION holds float32 corners *relative to it*: float32 keeps ~7
  significant digits, which at continental coordinates (1e6 m) is ~0.1 m absolute, but relative
  to a viewpoint a few hundred metres away it is well below a millimetre.
* One primitive per atlas page that has geometry.  A quad payload (:class:`farfield.core.impostor.impostor.QuadPayload`)
  gives two triangles per quad (corners 0, 3, 2 and 0, 2, 1: TL, BL, BR and TL, BR, TR); its
  vertices are welded: each distinct float32 (position, UV) pair that a triangle uses is stored
  once, in the order of its first copy among the quads' corners (a layered impostor's quads,
  each with its own tile, keep their four corners in order).  A mesh payload
  (:class:`farfield.core.impostor.impostor.MeshPayload`) gives its own indexed triangles: the page's triangles in
  payload order, and the vertices they use in the order of their first use.  Indices are uint16
  when the page has fewer than 65,535 vertices (0xFFFF is the primitive-restart value, which glTF
  forbids), else uint32.
* Every triangle is counter-clockwise as seen from the reference viewpoint (glTF's front face):
  a triangle whose stored float32 corners wind the other way there has its last two corners
  swapped (a baked layered impostor's image x runs right to left as seen from the viewpoint, so
  its quads' TL, BL, BR is clockwise there; a textured depth mesh's triangles have no winding of
  their own).  A triangle seen edge-on keeps its order.
* One material per page, whether or not the page has quads: ``baseColorTexture`` of that page,
  ``KHR_materials_unlit``, ``alphaMode`` ``MASK`` with cutoff 0.5 and ``doubleSided`` (the
  impostor is only seen from inside its view cell, so a viewer must not cull it if it disagrees
  about winding).  Samplers are linear / linear (no mipmaps), clamp-to-edge: a viewer's mipmaps
  average a tile's alpha with the transparent texels around it, and the alpha cut then eats the
  impostor's silhouette (three.js, envmap from a cell corner: up to 17 pixels beyond one); seen
  from inside its cell, an impostor's texels are about one pixel wide, so mipmaps buy nothing.

Texture coordinates are stored as given: :class:`farfield.core.impostor.impostor.Impostor` already uses glTF's
convention (0, 0 is the top-left of the page).
"""

from __future__ import annotations

import json
import struct
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from farfield.core.colour_space import srgb_to_linear
from farfield.core.errors import BundleFormatError
from farfield.core.impostor.depth import DEPTH_ATTRIBUTE, DEPTH_EXTENSION
from farfield.core.impostor.impostor import (
    Impostor,
    MeshPayload,
    PointPayload,
    QuadPayload,
    check_impostor,
    decode_normals,
    encode_normals,
)
from farfield.core.impostor.mesh_frames import (
    VertexFrames,
    filled_owners,
    texel_frames,
    triangle_frames,
    triangle_owners,
    vertex_frames,
)
from farfield.core.impostor.png_pages import PagePngs, page_png

__all__ = ["GlbBuilder", "GlbParts", "engine_metadata", "impostor_glb", "page_png", "write_glb"]

_MAGIC = 0x46546C67  # "glTF"
_VERSION = 2
_CHUNK_JSON = 0x4E4F534A  # "JSON"
_CHUNK_BIN = 0x004E4942  # "BIN\0"

# glTF enums (spec, "accessor.componentType", "bufferView.target", "sampler").
_UNSIGNED_SHORT = 5123
_UNSIGNED_INT = 5125
_FLOAT = 5126
_ARRAY_BUFFER = 34962
_ELEMENT_ARRAY_BUFFER = 34963
_LINEAR = 9729
_CLAMP_TO_EDGE = 33071
_TRIANGLES = 4
_POINTS = 0

_UNLIT = "KHR_materials_unlit"
_INSTANCING = "EXT_mesh_gpu_instancing"
# A point impostor's directional colours (seed 001 §5.3), for a runtime that knows them (see
# :func:`_point_primitive`); viewers that do not show the points' COLOR_0.
POINT_APPEARANCE = "FARFIELD_point_appearance"
# An octahedral impostor's frame grid on its fallback card's primitive
# (farfield.core.techniques.octahedral.payload.octahedral_extension), for a runtime that blends frames.
OCTAHEDRAL_EXTENSION = "FARFIELD_octahedral_impostor"

# Corner order TL, TR, BR, BL (0..3): the triangles TL-BL-BR and TL-BR-TR (their winding as seen
# from the reference viewpoint is then set by _face_viewpoint).
_QUAD_TRIANGLES = np.array([0, 3, 2, 0, 2, 1], dtype=np.int64)
# 0xFFFF is reserved as primitive restart, so uint16 indices address at most 65,535 vertices.
_MAX_UINT16_VERTICES = 0xFFFF


def _pad(data: bytes, fill: bytes) -> bytes:
    return data + fill * (-len(data) % 4)


class _Bin:
    """The growing BIN chunk: appends 4-byte-aligned bufferViews and returns their indices."""

    def __init__(self) -> None:
        self.parts: list[bytes] = []
        self.length = 0
        self.views: list[dict] = []

    def add(self, data: bytes, target: int | None = None) -> int:
        view = {"buffer": 0, "byteOffset": self.length, "byteLength": len(data)}
        if target is not None:
            view["target"] = target
        padded = _pad(data, b"\x00")
        self.parts.append(padded)
        self.length += len(padded)
        self.views.append(view)
        return len(self.views) - 1

    def bytes(self) -> bytes:
        return b"".join(self.parts)


def _weld(
    positions: np.ndarray, uv: np.ndarray, indices: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The vertices (float32 ``positions`` (n, 3), ``uv`` (n, 2)) that ``indices`` use, each
    distinct (position, uv) pair once, in the order of its first copy among the given vertices,
    and the indices remapped to them (vertices all distinct and all used: unchanged), and which of
    the given vertices each kept one is (for attributes that follow them).

    >>> p = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 1, 0]], "<f4")
    >>> t = np.array([[0, 0], [1, 0], [0, 1], [0, 1]], "<f4")
    >>> q, _, i, _ = _weld(p, t, np.array([0, 3, 1, 0, 2, 1]))
    >>> len(q), i.tolist()
    (3, [0, 2, 1, 0, 2, 1])
    """
    rows = np.ascontiguousarray(np.concatenate([positions, uv], axis=1), dtype="<f4")
    keys = rows.view(np.dtype((np.void, rows.dtype.itemsize * rows.shape[1])))[:, 0]
    _, first, key_of = np.unique(keys, return_index=True, return_inverse=True)
    key_of = key_of.reshape(-1)
    used = np.unique(key_of[indices])  # the keys drawn
    order = used[np.argsort(first[used], kind="stable")]
    slot = np.empty(first.size, np.int64)
    slot[order] = np.arange(order.size)
    kept = first[order]
    return positions[kept], uv[kept], slot[key_of[indices]], kept


def _quad_pages(
    payload: QuadPayload,
    viewpoint: np.ndarray,
    page_count: int,
    frames: np.ndarray | None = None,
    ranges: np.ndarray | None = None,
):
    """Per page with quads: (page, float32 positions relative to ``viewpoint``, float32 UVs, indices),
    and with ``frames`` (q, 3, 3) (:func:`quad_frames`) float32 NORMAL (n, 3) and TANGENT (n, 4) too,
    and with ``ranges`` (q, 2) (the depth channel's) each vertex's quad's, float32 (n, 2), after them."""
    # Narrowed to float32 here, after the float64 subtraction, so only the local offset is rounded.
    relative = (payload.corners - viewpoint).astype("<f4")
    uv = payload.uv.astype("<f4")
    for page in range(page_count):
        quads = np.flatnonzero(payload.page == page)
        if quads.size == 0:
            continue  # glTF accessors need count >= 1; the page keeps its material and image
        indices = (np.arange(quads.size, dtype=np.int64)[:, None] * 4 + _QUAD_TRIANGLES).ravel()
        positions, texcoords, indices, kept = _weld(relative[quads].reshape(-1, 3), uv[quads].reshape(-1, 2), indices)
        if frames is None:
            yield page, positions, texcoords, indices
            continue
        frame = frames[quads[kept // 4]]  # (n, 3, 3) rows tangent, bitangent, normal of each vertex's quad
        if ranges is not None:
            yield page, positions, texcoords, indices, *_normal_tangent(frame), ranges[quads[kept // 4]].astype("<f4")
            continue
        yield page, positions, texcoords, indices, *_normal_tangent(frame)


def _normal_tangent(frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """float32 NORMAL (n, 3) and TANGENT (n, 4) of vertices whose frames are ``frame`` (n, 3, 3)
    (rows T, B, N): the tangent's w is the handedness a viewer rebuilds B with (glTF 2.0 §3.7.2.1:
    B = cross(N, T) * w)."""
    handed = np.sign(np.einsum("ij,ij->i", np.cross(frame[:, 2], frame[:, 0]), frame[:, 1]))
    tangent = np.concatenate([frame[:, 0], np.where(handed < 0, -1.0, 1.0)[:, None]], axis=1)
    return frame[:, 2].astype("<f4"), tangent.astype("<f4")


def quad_frames(payload: QuadPayload, viewpoint: np.ndarray) -> np.ndarray:
    """(q, 3, 3) float64 unit rows T, B, N of each quad's tangent frame, world space: T along the
    page's +x (increasing u), B along the page's up (decreasing glTF v, the image's top; glTF
    2.0 §3.9.3: a normal texture's +Y is up), N the quad's normal on ``viewpoint``'s side.

    >>> quad = np.array([[[-1, 5, 1], [1, 5, 1], [1, 5, -1], [-1, 5, -1]]], dtype=np.float64)
    >>> uv = np.array([[[0, 0], [1, 0], [1, 1], [0, 1]]], dtype=np.float64)
    >>> (quad_frames(QuadPayload(quad, uv, np.zeros(1, np.int64), np.zeros(1, np.int64)), np.zeros(3))[0] + 0.0).tolist()
    [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]
    """
    c, t = payload.corners, payload.uv
    e1, e2 = c[:, 1] - c[:, 0], c[:, 3] - c[:, 0]  # TL -> TR, TL -> BL
    d1, d2 = t[:, 1] - t[:, 0], t[:, 3] - t[:, 0]
    det = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    det = np.where(det == 0.0, 1.0, det)
    # e = du * dP/du + dv * dP/dv for both edges, solved for the two derivatives.
    dpdu = (d2[:, 1, None] * e1 - d1[:, 1, None] * e2) / det[:, None]
    dpdv = (d1[:, 0, None] * e2 - d2[:, 0, None] * e1) / det[:, None]
    normal = np.cross(e1, e2)
    towards = np.einsum("ij,ij->i", normal, viewpoint - c[:, 0]) < 0.0
    normal[towards] *= -1.0

    def unit(a):
        length = np.linalg.norm(a, axis=1, keepdims=True)
        return np.divide(a, length, out=np.zeros_like(a), where=length > 0.0)

    return np.stack([unit(dpdu), unit(-dpdv), unit(normal)], axis=1)


# Rows of a page turned into tangent space at a time: the per-texel frames of a band, not of the
# page, are held (a 4096 x 4096 page at once took 2 GB for quads and 6 GB for a mesh).
BAND_ROWS = 128


def tangent_space_pages(payload: QuadPayload | MeshPayload, frames, pages) -> list[np.ndarray]:
    """The normal pages (world normals, :data:`farfield.core.impostor.impostor.PAGE_CHANNELS`) as
    tangent-space normal textures (glTF ``normalTexture``).  Quads: each texel in the frame
    (``frames``, :func:`quad_frames`) of the quad whose tile holds it, the texels between tiles in
    that of the nearest tile (their padding).  A mesh: each texel in the frame a viewer
    interpolates at its centre from the vertex frames (``frames``,
    :func:`farfield.core.impostor.mesh_frames.vertex_frames`) of the triangle that holds it
    (:func:`farfield.core.impostor.mesh_frames.texel_frames`).  :data:`BAND_ROWS` rows at a time."""
    out = []
    mesh = isinstance(payload, MeshPayload)
    for index, page in enumerate(pages):
        h, w = page.shape[:2]
        owner = filled_owners(triangle_owners(payload, index, h, w) if mesh else _quad_owners(payload, index, h, w))
        if owner is None:
            out.append(encode_normals(np.broadcast_to([0.0, 0.0, 1.0], (h, w, 3))))
            continue
        converted = np.empty((h, w, 4), np.uint8)
        for start in range(0, h, BAND_ROWS):
            rows = slice(start, min(start + BAND_ROWS, h))
            to_local = texel_frames(payload, frames, owner, rows) if mesh else frames[owner[rows]]
            world = decode_normals(page[rows])
            local = np.einsum("hwij,hwj->hwi", to_local, world)
            local[~(np.linalg.norm(world, axis=-1) > 0.0)] = (0.0, 0.0, 1.0)
            converted[rows] = encode_normals(local)
        out.append(converted)
    return out


def _quad_owners(payload: QuadPayload, index: int, h: int, w: int) -> np.ndarray:
    """(h, w) int32 the quad whose tile holds each texel of page ``index``, -1 for none."""
    owner = np.full((h, w), -1, np.int32)
    for q in np.flatnonzero(payload.page == index):
        u, v = payload.uv[q, :, 0] * w, payload.uv[q, :, 1] * h
        x0, x1 = int(np.floor(u.min() + 0.5)), int(np.floor(u.max() + 0.5))
        y0, y1 = int(np.floor(v.min() + 0.5)), int(np.floor(v.max() + 0.5))
        owner[max(y0, 0) : y1, max(x0, 0) : x1] = q
    return owner


def _mesh_pages(payload: MeshPayload, viewpoint: np.ndarray, page_count: int, frames: VertexFrames | None = None):
    """Per page with triangles: (page, float32 positions relative to ``viewpoint``, float32 UVs, indices),
    and with ``frames`` (:func:`farfield.core.impostor.mesh_frames.vertex_frames`) float32 NORMAL
    (n, 3) and TANGENT (n, 4) too (:func:`_lit_mesh_pages`)."""
    if frames is not None:
        yield from _lit_mesh_pages(payload, viewpoint, page_count, frames)
        return
    for page in range(page_count):
        triangles = payload.triangles[payload.page == page].ravel()
        if triangles.size == 0:
            continue
        used, first, local = np.unique(triangles, return_index=True, return_inverse=True)
        order = np.argsort(first, kind="stable")  # vertices in the order of their first use
        slot = np.empty(used.size, np.int64)
        slot[order] = np.arange(used.size)
        kept = used[order]
        positions = (payload.vertices[kept] - viewpoint).astype("<f4")
        yield page, positions, payload.uv[kept].astype("<f4"), slot[local.reshape(-1)]


def _lit_mesh_pages(payload: MeshPayload, viewpoint: np.ndarray, page_count: int, frames: VertexFrames):
    """:func:`_mesh_pages` with ``frames``: each page's vertices are its frame vertices (a payload
    vertex once per handedness of its triangles), with their NORMAL and TANGENT, in the order of
    their first use."""
    relative = (payload.vertices - viewpoint).astype("<f4")
    uv = payload.uv.astype("<f4")
    position = np.unique(frames.corner.reshape(-1), return_index=True)[1]  # a corner of each frame vertex
    vertex = payload.triangles.reshape(-1)[position]  # the payload vertex of each frame vertex
    frame = np.stack([frames.tangent, frames.bitangent, frames.normal], axis=1)
    for page in range(page_count):
        corners = frames.corner[payload.page == page].ravel()
        if corners.size == 0:
            continue
        used, first, local = np.unique(corners, return_index=True, return_inverse=True)
        order = np.argsort(first, kind="stable")  # vertices in the order of their first use
        slot = np.empty(used.size, np.int64)
        slot[order] = np.arange(used.size)
        kept = used[order]
        yield page, relative[vertex[kept]], uv[vertex[kept]], slot[local.reshape(-1)], *_normal_tangent(frame[kept])


def _face_viewpoint(positions: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """``indices`` (3n,) of triangles over ``positions`` (float32, relative to the viewpoint at the
    origin), each counter-clockwise as seen from the origin: the last two corners of a triangle
    that winds the other way are swapped.

    >>> p = np.array([[0, 5, 0], [1, 5, 0], [0, 5, 1]], "<f4")  # seen from the origin along +y
    >>> _face_viewpoint(p, np.array([0, 1, 2])).tolist(), _face_viewpoint(p, np.array([0, 2, 1])).tolist()
    ([0, 1, 2], [0, 1, 2])
    """
    triangles = indices.reshape(-1, 3).copy()
    corner = positions.astype(np.float64)[triangles]
    normal = np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0])
    away = np.einsum("ij,ij->i", normal, corner.sum(axis=1)) > 0  # the front faces away from the origin
    triangles[away] = triangles[away][:, [0, 2, 1]]
    return triangles.reshape(-1)


def _point_primitive(payload: PointPayload, viewpoint: np.ndarray, binary: _Bin, accessors: list[dict]) -> dict:
    """The one ``POINTS`` primitive of a point impostor (material 0, unlit): POSITION (float32,
    relative to the node's translation), ``COLOR_0`` (float32 linear RGB, glTF's rule: the
    single-colour preview of seed 001 §5.3, what any viewer shows as one-pixel points) and
    ``_FARFIELD_TILE`` (float32 VEC3: the point's page, -1 for one colour, and its tile's first
    texel x, y), and where the points keep them ``NORMAL`` (float32 unit world normals, one per
    point).  The extension :data:`POINT_APPEARANCE` on the primitive names the textures of the
    pages (``textures``, one per atlas page, in page order; sRGB like a base-colour texture), the tile's texels ``tile`` (along u,
    along v), the sampling ``plane`` (unit normal, offset; world coordinates: normal · x = offset),
    its ``axes`` u, v and the ``rectangle`` [[lo u, lo v], [hi u, hi v]] of plane coordinates
    (x · u, x · v) the tiles span.  A runtime shows a textured point with the bilinear look-up, in
    its tile, of where the ray from the eye to the point crosses the plane (texel centres at
    (c + ½) / tu, (r + ½) / tv of the rectangle; row 0 at low v)."""
    positions = np.ascontiguousarray(payload.positions - viewpoint, dtype="<f4")
    colour = np.ascontiguousarray(srgb_to_linear(payload.colour[:, :3] / 255.0), dtype="<f4")
    tile = np.ascontiguousarray(np.concatenate([payload.page[:, None], payload.texel], axis=1), dtype="<f4")
    base = len(accessors)
    accessors.append({
        "bufferView": binary.add(positions.tobytes(), _ARRAY_BUFFER), "componentType": _FLOAT, "count": int(positions.shape[0]), "type": "VEC3",
        "min": [float(x) for x in positions.min(axis=0)], "max": [float(x) for x in positions.max(axis=0)],
    })  # fmt: skip
    accessors.append(
        {
            "bufferView": binary.add(colour.tobytes(), _ARRAY_BUFFER),
            "componentType": _FLOAT,
            "count": int(colour.shape[0]),
            "type": "VEC3",
        }
    )
    accessors.append(
        {
            "bufferView": binary.add(tile.tobytes(), _ARRAY_BUFFER),
            "componentType": _FLOAT,
            "count": int(tile.shape[0]),
            "type": "VEC3",
        }
    )
    attributes = {"POSITION": base, "COLOR_0": base + 1, "_FARFIELD_TILE": base + 2}
    if payload.normal is not None:  # kept normals (channels albedo+normal): unit float32, as glTF's NORMAL
        normal = np.ascontiguousarray(payload.normal, dtype="<f4")
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)  # unit after the narrowing too (the validator checks)
        attributes["NORMAL"] = len(accessors)
        accessors.append({"bufferView": binary.add(normal.tobytes(), _ARRAY_BUFFER), "componentType": _FLOAT,
                          "count": int(normal.shape[0]), "type": "VEC3"})  # fmt: skip
    return {
        "attributes": attributes,
        "material": 0,
        "mode": _POINTS,
        "extensions": {POINT_APPEARANCE: {
            "textures": list(range(int(payload.page.max(initial=-1)) + 1)),
            "tile": [int(t) for t in payload.tile],
            "plane": [float(x) for x in payload.plane],
            "axes": [[float(x) for x in a] for a in payload.axes],
            "rectangle": [[float(x) for x in r] for r in payload.rectangle],
        }},
    }  # fmt: skip


@dataclass(frozen=True)
class GlbParts:
    """A payload's part of its impostor's GLB (:meth:`farfield.core.impostor.impostor.Payload.glb_parts`):
    the mesh's ``primitives``, the ``materials``, the ``images`` (glTF image objects, their PNGs in
    the BIN chunk already) and the ``extensions`` it uses beside ``KHR_materials_unlit``."""

    primitives: list[dict]
    materials: list[dict]
    images: list[dict]
    extensions: tuple[str, ...] = ()


def _page_material(index: int, normal: int | None = None) -> dict:
    """The material of atlas page ``index``: its texture, unlit, alpha-cut at 0.5, double-sided;
    with the texture ``normal`` (a tangent-space normal texture), lit: glTF's metallic-roughness,
    a rough dielectric (metallic 0, roughness 1: the colour is the diffuse albedo)."""
    if normal is not None:
        material = _page_material(index)
        del material["extensions"]
        return material | {"normalTexture": {"index": normal, "texCoord": 0}}
    return {
        "name": f"atlas-{index:03d}",
        "pbrMetallicRoughness": {
            "baseColorFactor": [1.0, 1.0, 1.0, 1.0],
            "baseColorTexture": {"index": index, "texCoord": 0},
            "metallicFactor": 0.0,
            "roughnessFactor": 1.0,
        },
        "alphaMode": "MASK",
        "alphaCutoff": 0.5,
        "doubleSided": True,
        "extensions": {_UNLIT: {}},
    }


def _add_material_pages(
    binary, images: list, materials: list, material_pages, emissive_pages=None, pngs=page_png
) -> None:
    """Append each page's material page (glTF's ORM packing, linear) and emissive page (sRGB, where
    kept) to ``images`` and light ``materials`` (one per page, in page order) with them: the ORM
    image as both ``metallicRoughnessTexture`` and ``occlusionTexture``, factors 1 (the page holds
    the values), and ``emissiveTexture`` with ``emissiveFactor`` [1, 1, 1]."""
    kinds = [("material", material_pages)] + ([("emissive", emissive_pages)] if emissive_pages is not None else [])
    for kind, kind_pages in kinds:
        first = len(images)
        images += [
            {"bufferView": binary.add(pngs(page)), "mimeType": "image/png", "name": f"{kind}-{index:03d}"}
            for index, page in enumerate(kind_pages)
        ]
        for index, material in enumerate(materials):
            if kind == "material":
                pbr = material["pbrMetallicRoughness"]
                pbr["metallicFactor"], pbr["roughnessFactor"] = 1.0, 1.0
                pbr["metallicRoughnessTexture"] = {"index": first + index, "texCoord": 0}
                material["occlusionTexture"] = {"index": first + index, "texCoord": 0}
            else:
                material["emissiveTexture"] = {"index": first + index, "texCoord": 0}
                material["emissiveFactor"] = [1.0, 1.0, 1.0]


_POINTS_MATERIAL = {
    "name": "points",
    "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 0.0, "roughnessFactor": 1.0},
    "extensions": {_UNLIT: {}},
}
# Points with normals: the same material lit, glTF's metallic-roughness (a rough dielectric: the
# points' colour is the diffuse albedo), for a viewer that lights points by their NORMAL.
_LIT_POINTS_MATERIAL = {k: v for k, v in _POINTS_MATERIAL.items() if k != "extensions"}


class GlbBuilder:
    """The GLB being written: the BIN chunk, the accessors, and the helpers a payload builds its
    :class:`GlbParts` with (:meth:`textured` for textured triangles per page, :meth:`points` for a
    point impostor).  Positions are float32 relative to ``viewpoint`` (the node's translation).
    ``pngs`` encodes the page images (:class:`farfield.core.impostor.png_pages.PagePngs`): a bundle
    passes the one that wrote its page files, so each page is encoded once."""

    def __init__(self, viewpoint: np.ndarray, pngs: PagePngs | None = None) -> None:
        self.viewpoint = np.asarray(viewpoint, dtype=np.float64)
        self.binary = _Bin()
        self.accessors: list[dict] = []
        self.pngs = pngs if pngs is not None else PagePngs()

    def quad_pages(self, payload: QuadPayload, page_count: int):
        """Per page with quads: (page, float32 positions, float32 UVs, indices), vertices welded."""
        return _quad_pages(payload, self.viewpoint, page_count)

    def lit_quads(
        self, payload: QuadPayload, pages, normal_pages, material_pages=None, emissive_pages=None
    ) -> GlbParts:
        """:meth:`textured` quads with NORMAL, TANGENT and each page's world normals (``normal_pages``)
        as a tangent-space normal texture in the frames of its quads (:func:`quad_frames`), and
        the material and emissive pages where given (:meth:`textured`)."""
        frames = quad_frames(payload, self.viewpoint)
        if payload.depth_range is not None:
            return self._depth_quads(payload, pages, normal_pages, frames, material_pages, emissive_pages)
        geometry = _quad_pages(payload, self.viewpoint, len(pages), frames)
        normal = tangent_space_pages(payload, frames, normal_pages)
        return self.textured(geometry, pages, normal, material_pages, emissive_pages)

    def _depth_quads(
        self, payload: QuadPayload, pages, normal_pages, frames, material_pages=None, emissive_pages=None
    ) -> GlbParts:
        """:meth:`lit_quads` of quads with the depth channel (:mod:`farfield.core.impostor.depth`):
        the normal textures keep the depth in their alpha, every vertex carries its quad's ray
        scales as ``_DEPTH_RANGE`` (float32 VEC2), and each material says so with the extension
        ``FARFIELD_impostor_depth`` (used, not required: a viewer without it draws the lit cards)."""
        geometry = _quad_pages(payload, self.viewpoint, len(pages), frames, payload.depth_range)
        tangent = tangent_space_pages(payload, frames, normal_pages)
        for converted, world in zip(tangent, normal_pages):
            converted[..., 3] = world[..., 3]
        parts = self.textured(geometry, pages, tangent, material_pages, emissive_pages)
        for material in parts.materials:
            material.setdefault("extensions", {})[DEPTH_EXTENSION] = {"alpha": "depth", "attribute": DEPTH_ATTRIBUTE}
        return GlbParts(parts.primitives, parts.materials, parts.images, (*parts.extensions, DEPTH_EXTENSION))

    def mesh_pages(self, payload: MeshPayload, page_count: int):
        """Per page with triangles: (page, float32 positions, float32 UVs, indices)."""
        return _mesh_pages(payload, self.viewpoint, page_count)

    def lit_mesh(self, payload: MeshPayload, pages, normal_pages, material_pages=None, emissive_pages=None) -> GlbParts:
        """:meth:`textured` triangles with NORMAL, TANGENT and each page's world normals
        (``normal_pages``) as a tangent-space normal texture in the frames a viewer interpolates
        from the vertices' (:mod:`farfield.core.impostor.mesh_frames`), and the material and
        emissive pages where given (:meth:`textured`)."""
        frames = vertex_frames(payload, triangle_frames(payload, self.viewpoint))
        geometry = _mesh_pages(payload, self.viewpoint, len(pages), frames)
        normal = tangent_space_pages(payload, frames, normal_pages)
        return self.textured(geometry, pages, normal, material_pages, emissive_pages)

    def images(self, pages) -> list[dict]:
        """Each page's PNG in the BIN chunk, as glTF images in page order."""
        return [
            {"bufferView": self.binary.add(data), "mimeType": "image/png", "name": f"atlas-{index:03d}"}
            for index, data in enumerate(self.pngs.encode(pages))
        ]

    def textured(
        self, page_geometry: Iterable, pages, normal_pages=None, material_pages=None, emissive_pages=None
    ) -> GlbParts:
        """One ``TRIANGLES`` primitive per item of ``page_geometry`` ((page, positions, UVs, indices),
        each triangle turned to face the viewpoint), then every page of ``pages`` as an image and a material.

        With ``normal_pages`` (tangent-space normal textures, one per page) each item also carries
        float32 NORMAL (n, 3) and TANGENT (n, 4), written as attributes, and the materials are
        glTF's metallic-roughness (dielectric, roughness 1) with the page's ``normalTexture``,
        lit by the viewer, instead of unlit: their images follow the colour pages'."""
        # Every image of the GLB encoded first, together (several threads), then added in order.
        self.pngs.encode([*pages, *(normal_pages or ()), *(material_pages or ()), *(emissive_pages or ())])
        primitives = []
        for page, positions, texcoords, indices, *lit in page_geometry:
            indices = _face_viewpoint(positions, indices)
            vertex_count = positions.shape[0]
            index_dtype, component = (
                ("<u2", _UNSIGNED_SHORT) if vertex_count < _MAX_UINT16_VERTICES else ("<u4", _UNSIGNED_INT)
            )
            base = len(self.accessors)
            self.accessors.append(
                {
                    "bufferView": self.binary.add(indices.astype(index_dtype).tobytes(), _ELEMENT_ARRAY_BUFFER),
                    "componentType": component,
                    "count": int(indices.size),
                    "type": "SCALAR",
                }
            )
            self.accessors.append(
                {
                    "bufferView": self.binary.add(positions.tobytes(), _ARRAY_BUFFER),
                    "componentType": _FLOAT,
                    "count": int(vertex_count),
                    "type": "VEC3",
                    # float32 values widened exactly to float64, so min/max equal the stored data.
                    "min": [float(x) for x in positions.min(axis=0)],
                    "max": [float(x) for x in positions.max(axis=0)],
                }
            )
            self.accessors.append(
                {
                    "bufferView": self.binary.add(texcoords.tobytes(), _ARRAY_BUFFER),
                    "componentType": _FLOAT,
                    "count": int(vertex_count),
                    "type": "VEC2",
                }
            )
            attributes = {"POSITION": base + 1, "TEXCOORD_0": base + 2}
            for name, values, kind in zip(("NORMAL", "TANGENT", DEPTH_ATTRIBUTE), lit, ("VEC3", "VEC4", "VEC2")):
                attributes[name] = len(self.accessors)
                self.accessors.append(
                    {
                        "bufferView": self.binary.add(np.ascontiguousarray(values).tobytes(), _ARRAY_BUFFER),
                        "componentType": _FLOAT,
                        "count": int(vertex_count),
                        "type": kind,
                    }
                )
            primitives.append({"attributes": attributes, "indices": base, "material": page, "mode": _TRIANGLES})
        images = self.images(pages)
        if normal_pages is None:
            return GlbParts(primitives, [_page_material(index) for index in range(len(pages))], images)
        images += [
            {"bufferView": self.binary.add(self.pngs(page)), "mimeType": "image/png", "name": f"normal-{index:03d}"}
            for index, page in enumerate(normal_pages)
        ]
        materials = [_page_material(index, normal=len(pages) + index) for index in range(len(pages))]
        if material_pages is not None:
            _add_material_pages(self.binary, images, materials, material_pages, emissive_pages, self.pngs)
        return GlbParts(primitives, materials, images)

    def points(self, payload: PointPayload, pages) -> GlbParts:
        """A point impostor: every page as an image (the directional colours' tiles), then one
        ``POINTS`` primitive (none without points, :func:`_point_primitive`) and one opaque material:
        unlit, or lit (metallic-roughness, metallic 0, roughness 1) where the points keep normals."""
        images = self.images(pages)
        primitives = [_point_primitive(payload, self.viewpoint, self.binary, self.accessors)] if payload.count else []
        material = _POINTS_MATERIAL if payload.normal is None else _LIT_POINTS_MATERIAL
        return GlbParts(primitives, [json.loads(json.dumps(material))], images, (POINT_APPEARANCE,))


def engine_metadata(impostor: Impostor) -> dict:
    """What an engine needs to know where the impostor is valid, as the node's ``extras.farfield``:
    ``technique``, ``viewcell`` (the bundle's dict: kind and corners or shaft), ``reference_viewpoint``
    (world, the node's translation), ``resolution`` and ``fov_deg`` (the output image it was made
    for: one texel or point about one pixel there), ``code_version``.

    >>> from farfield.core.impostor.impostor import PointPayload
    >>> engine_metadata(Impostor("points", {"kind": "box", "lo": [0, 0, 0], "hi": [1, 1, 1]}, np.zeros(3), 64, 45.0, (), PointPayload.empty()))["viewcell"]["kind"]
    'box'
    """
    return json.loads(json.dumps({
        "technique": impostor.technique,
        "viewcell": impostor.viewcell,
        "reference_viewpoint": [float(x) for x in np.asarray(impostor.reference_viewpoint, dtype=np.float64)],
        "resolution": int(impostor.resolution),
        "fov_deg": float(impostor.fov_deg),
        "code_version": impostor.code_version,
    }, default=lambda v: v.tolist() if isinstance(v, np.ndarray) else float(v), allow_nan=False))  # fmt: skip


def instance_attributes(matrices, viewpoint: np.ndarray, binary: _Bin, accessors: list[dict]) -> dict:
    """The ``EXT_mesh_gpu_instancing`` object of a node at ``viewpoint`` (its translation) drawn once
    per instance: each of ``matrices`` ((m, 16) row-major, or (m, 4, 4): the prototype's local ->
    world) as float ``TRANSLATION``, unit-quaternion ``ROTATION`` (x, y, z, w) and ``SCALE``
    accessors.  The extension applies each instance's transform before the node's
    (Khronos, EXT_mesh_gpu_instancing), so instance ``i`` is ``T(-viewpoint) M_i T(viewpoint)``: the
    card, stored relative to the viewpoint, lands where ``M_i`` puts the prototype's.

    Raises
    ------
    BundleFormatError
        A matrix that is not translation x rotation x axis scale (a shear).
    """
    from scipy.spatial.transform import Rotation

    m = np.asarray(matrices, dtype=np.float64).reshape(-1, 4, 4)
    linear = m[:, :3, :3]
    scale = np.linalg.norm(linear, axis=1)  # (m, 3): each column's length
    scale[np.linalg.det(linear) < 0.0, 0] *= -1.0  # a mirror as a negative x scale
    if not (np.abs(scale) > 0.0).all():
        raise BundleFormatError("an instance matrix collapses an axis")
    rotation = linear / scale[:, None, :]
    if not np.allclose(np.einsum("kab,kac->kbc", rotation, rotation), np.eye(3), atol=1e-6):
        raise BundleFormatError("an instance matrix shears: EXT_mesh_gpu_instancing keeps translation, rotation, scale")
    translation = linear @ viewpoint + m[:, :3, 3] - viewpoint
    quaternion = Rotation.from_matrix(rotation).as_quat()  # (x, y, z, w), glTF's order
    quaternion *= np.where(quaternion[:, 3:] < 0.0, -1.0, 1.0)  # one of the two signs, for equal bytes
    out = {}
    for name, values in (("TRANSLATION", translation), ("ROTATION", quaternion), ("SCALE", scale)):
        data = np.ascontiguousarray(values, dtype="<f4")
        accessors.append({"bufferView": binary.add(data.tobytes()), "componentType": _FLOAT, "count": len(data),
                          "type": f"VEC{data.shape[1]}"})  # fmt: skip
        out[name] = len(accessors) - 1
    return {"attributes": out}


def impostor_glb(impostor: Impostor, pngs: PagePngs | None = None) -> bytes:
    """GLB bytes of ``impostor``: one node at the reference viewpoint, one primitive per page.

    Parameters
    ----------
    impostor : Impostor
        A quad or mesh payload in float64 world metres, UVs in glTF convention; pages (H, W, 4)
        uint8 RGBA top row first.
    pngs : PagePngs, optional
        The encoder of the page images; pages it encoded before are not encoded again
        (:func:`farfield.core.impostor.bundle.write_bundle` passes the one of its page files).

    Returns
    -------
    bytes
        A glTF 2.0 binary file, byte-identical for equal impostors.

    Raises
    ------
    BundleFormatError
        The impostor's arrays do not fit (see :func:`farfield.core.impostor.impostor.check_impostor`).

    Examples
    --------
    >>> quad = np.array([[[-1, 5, 1], [1, 5, 1], [1, 5, -1], [-1, 5, -1]]], dtype=np.float64)
    >>> uv = np.array([[[0, 0], [1, 0], [1, 1], [0, 1]]], dtype=np.float64)
    >>> payload = QuadPayload(quad, uv, np.zeros(1, np.int64), np.zeros(1, np.int64))
    >>> one = Impostor("billboard", {}, np.zeros(3), 64, 60.0, (np.full((4, 4, 4), 255, np.uint8),), payload)
    >>> data = impostor_glb(one)
    >>> data[:4], struct.unpack_from("<I", data, 4)[0], len(data) % 4
    (b'glTF', 2, 0)
    >>> impostor_glb(one) == data
    True
    """
    check_impostor(impostor)
    viewpoint = np.asarray(impostor.reference_viewpoint, dtype=np.float64)
    glb = GlbBuilder(viewpoint, pngs)
    parts = impostor.payload.glb_parts(impostor, glb)  # the payload's kind decides what it writes
    primitives, materials, images, accessors, binary = (
        parts.primitives,
        parts.materials,
        parts.images,
        glb.accessors,
        glb.binary,
    )
    unlit = any(_UNLIT in m.get("extensions", {}) for m in materials) or not materials
    extensions = [_UNLIT] * unlit + [*parts.extensions]
    node: dict = {
        "name": "impostor",
        "translation": [float(x) for x in viewpoint],
        "extras": {"farfield": engine_metadata(impostor)},
    }
    instances = impostor.parameters.get("instances")
    if instances and primitives:  # one card for every instance of a prototype (instances.bake_prototypes)
        node["extensions"] = {_INSTANCING: instance_attributes(instances["matrices"], viewpoint, binary, accessors)}
        extensions.append(_INSTANCING)
    document: dict = {
        "asset": {"version": "2.0", "generator": f"farfield {impostor.code_version}".rstrip()},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [node],
    }
    if extensions:
        document = {"asset": document["asset"], "extensionsUsed": sorted(extensions)} | document
    if primitives:
        node["mesh"] = 0
        document["meshes"] = [{"name": f"impostor-{impostor.technique}", "primitives": primitives}]
    if accessors:
        document["accessors"] = accessors
    if materials:
        document["materials"] = materials
    if images:
        document["images"] = images
        document["samplers"] = [
            {
                "magFilter": _LINEAR,
                "minFilter": _LINEAR,
                "wrapS": _CLAMP_TO_EDGE,
                "wrapT": _CLAMP_TO_EDGE,
            }
        ]
        document["textures"] = [{"sampler": 0, "source": index} for index in range(len(images))]
    blob = binary.bytes()
    if blob:
        document["buffers"] = [{"byteLength": len(blob)}]
        document["bufferViews"] = binary.views

    return write_glb(document, blob)


def write_glb(document: dict, blob: bytes) -> bytes:
    """GLB bytes of a JSON document and a BIN chunk (none when empty): fixed JSON key order and
    spacing, the JSON padded with spaces and the BIN with zeros to 4 bytes (glTF 2.0, "GLB File
    Format Specification")."""
    text = json.dumps(document, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)
    json_chunk = _pad(text.encode("ascii"), b" ")
    chunks = struct.pack("<II", len(json_chunk), _CHUNK_JSON) + json_chunk
    if blob:
        blob = _pad(blob, b"\x00")
        chunks += struct.pack("<II", len(blob), _CHUNK_BIN) + blob
    return struct.pack("<III", _MAGIC, _VERSION, 12 + len(chunks)) + chunks
