"""Compressed GLBs for engines and web viewers: atlas pages as KTX2 (Basis Universal,
``KHR_texture_basisu``) and geometry through ``EXT_meshopt_compression``.

:func:`compress_glb` rewrites a GLB that :func:`farfield.core.impostor.glb.impostor_glb` wrote (PNG images, plain
bufferViews; the plain GLB stays the default everywhere):

``textures``
    ``"png"``: as they are.  ``"ktx2"``: each PNG page re-encoded as KTX2 by Basis Universal
    (``codec`` ``"etc1s"``, small, or ``"uastc"``, near-lossless, Zstandard-supercompressed; normal
    textures always UASTC with a linear transfer function), the
    texture's ``extensions.KHR_texture_basisu.source``; the PNG is dropped and the extension is
    required.  ``"ktx2+png"``: the same with the PNG kept as the texture's ``source``, a fallback for
    viewers without the extension (the extension is then only used; the file is larger than the
    plain one: what it saves is GPU memory, 8 bits per texel once transcoded to BC7/ASTC/ETC2
    against 32 for RGBA8).
``geometry``
    ``"plain"`` or ``"meshopt"``: every index and vertex bufferView compressed by meshoptimizer's
    codecs, losslessly (``TRIANGLES`` for triangle indices, ``INDICES`` for others, ``ATTRIBUTES``
    for vertex data; no quantisation filters).  As ``EXT_meshopt_compression`` §"Fallback buffers"
    allows, the uncompressed layout lives in a second buffer marked ``fallback: true`` that holds
    no data, so the extension is required.

Encoders: ``alktx2`` (Basis Universal's encoder, pinned in pyproject.toml) and ``meshopt``
(meshoptimizer 1.3's codecs).  Every output is decoded back in the tests (``alktx2``'s decoder,
``meshopt``'s decoder, and three.js's KTX2Loader and MeshoptDecoder in chromium).  The same input
gives the same bytes (single-threaded encoding).
"""

from __future__ import annotations

import io
import json
import struct

import numpy as np
from PIL import Image, UnidentifiedImageError

from farfield.core.errors import BundleFormatError
from farfield.core.impostor.depth import DEPTH_EXTENSION
from farfield.core.impostor.glb import OCTAHEDRAL_EXTENSION, page_png, write_glb

__all__ = [
    "CODECS",
    "GEOMETRY",
    "TEXTURES",
    "compress_glb",
    "read_glb",
    "write_glb",
]  # write_glb: farfield.core.impostor.glb's

TEXTURES = ("png", "ktx2", "ktx2+png")
GEOMETRY = ("plain", "meshopt")
CODECS = ("etc1s", "uastc")
BASISU = "KHR_texture_basisu"
MESHOPT = "EXT_meshopt_compression"

_MAGIC, _JSON, _BIN = 0x46546C67, 0x4E4F534A, 0x004E4942
_COMPONENT_BYTES = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
_TYPE_COUNT = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_TRIANGLES = 4
_ETC1S_QUALITY = 100  # alktx2's ETC1S quality, 1..100 (its highest)
_UASTC_DEPTH_QUALITY = 100  # UASTC quality of normal textures holding depth in their alpha
_UASTC_ZSTD = 18  # Zstandard level of UASTC's supercompression (basisu's -ktx2 default)


def read_glb(data: bytes) -> tuple[dict, bytes]:
    """(JSON document, BIN chunk) of GLB bytes.

    >>> read_glb(write_glb({"asset": {"version": "2.0"}}, b"abc"))
    ({'asset': {'version': '2.0'}}, b'abc\\x00')
    """
    if len(data) < 20 or struct.unpack_from("<I", data, 0)[0] != _MAGIC:
        raise BundleFormatError("not a GLB file (no glTF magic)")
    length, kind = struct.unpack_from("<II", data, 12)
    if kind != _JSON or 20 + length > len(data):
        raise BundleFormatError("GLB: the first chunk is not a whole JSON chunk")
    try:
        document = json.loads(data[20 : 20 + length])
    except ValueError as error:
        raise BundleFormatError(f"GLB: its JSON chunk does not parse: {error}") from None
    if not isinstance(document, dict):
        raise BundleFormatError("GLB: its JSON chunk is not an object")
    blob = b""
    at = 20 + length
    if at + 8 <= len(data):
        size, kind = struct.unpack_from("<II", data, at)
        if kind == _BIN:
            blob = data[at + 8 : at + 8 + size]
    return document, blob


def block_padded(rgba: np.ndarray) -> np.ndarray:
    """``rgba`` (H, W, 4) grown right and down to multiples of 4 by repeating its last column and
    row (KHR_texture_basisu: a KTX2 image's width and height MUST be multiples of 4; repeating the
    edge keeps what a clamp-to-edge sampler shows inside the original area).

    >>> block_padded(np.zeros((5, 8, 4), np.uint8)).shape
    (8, 8, 4)
    """
    h, w = rgba.shape[:2]
    return np.pad(rgba, ((0, -h % 4), (0, -w % 4), (0, 0)), mode="edge")


def ktx2_page(rgba: np.ndarray, codec: str = "etc1s", srgb: bool = True, uastc_quality: int | None = None) -> bytes:
    """KTX2 bytes (Basis Universal, sRGB unless ``srgb`` is False, no mipmaps) of one (H, W, 4)
    uint8 RGBA page, top row first; H and W multiples of 4 (:func:`block_padded`).
    ``uastc_quality`` (UASTC only) overrides the encoder's default quality (50)."""
    import alktx2

    h, w = rgba.shape[:2]
    if h % 4 or w % 4:
        raise ValueError(f"a KTX2 page must be a multiple of 4 texels each way, got {w} x {h}")
    options = {"quality": _ETC1S_QUALITY} if codec == "etc1s" else {"zstd_supercompression_level": _UASTC_ZSTD}
    if codec == "uastc" and uastc_quality is not None:
        options["quality"] = uastc_quality
    return alktx2.encode_raw_rgba_to_ktx2(
        np.ascontiguousarray(rgba, dtype=np.uint8).tobytes(),
        w,
        h,
        True,
        codec=codec,
        srgb=srgb,
        mipmaps=False,
        threads=1,
        **options,
    )


def decode_ktx2(data: bytes) -> np.ndarray:
    """(H, W, 4) uint8 RGBA of KTX2 bytes (Basis Universal's transcoder to RGBA8), top row first."""
    import alktx2

    info = alktx2.inspect_ktx2(data)
    png, _ = alktx2.decode_ktx2_to_bytes(data, format="png")
    # alktx2 0.1.7 decodes whole 4 x 4 blocks: a page of 54 rows comes back with 56; the KTX2's
    # header has the page's own size (what three.js's KTX2Loader uses)
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGBA"))[: info["height"], : info["width"]]


class _Blob:
    """A BIN chunk being written: 4-byte aligned parts."""

    def __init__(self) -> None:
        self.parts: list[bytes] = []
        self.length = 0

    def add(self, data: bytes) -> tuple[int, int]:
        offset = self.length
        padded = data + b"\x00" * (-len(data) % 4)
        self.parts.append(padded)
        self.length += len(padded)
        return offset, len(data)

    def bytes(self) -> bytes:
        return b"".join(self.parts)


def _view_bytes(document: dict, blob: bytes, index: int) -> bytes:
    view = document["bufferViews"][index]
    if view.get("buffer", 0) != 0:
        raise BundleFormatError(f"GLB: bufferView {index} is not in the GLB's own buffer")
    start = view.get("byteOffset", 0)
    return blob[start : start + view["byteLength"]]


def _geometry_views(document: dict) -> dict[int, tuple[str, int]]:
    """bufferView -> (meshopt mode, element bytes) for every view an accessor reads; views whose
    elements meshopt cannot take (attributes not a multiple of 4 bytes) are left out."""
    modes: dict[int, tuple[str, int]] = {}
    triangle_indices = {
        p["indices"]
        for m in document.get("meshes", [])
        for p in m["primitives"]
        if "indices" in p and p.get("mode", _TRIANGLES) == _TRIANGLES
    }
    for n, accessor in enumerate(document.get("accessors", [])):
        if "bufferView" not in accessor or accessor.get("sparse"):
            continue
        size = _COMPONENT_BYTES[accessor["componentType"]] * _TYPE_COUNT[accessor["type"]]
        view = accessor["bufferView"]
        if document["bufferViews"][view].get("target") == 34963:  # ELEMENT_ARRAY_BUFFER
            if size in (2, 4):  # meshopt's index codecs take 16- and 32-bit indices
                modes[view] = ("TRIANGLES" if n in triangle_indices else "INDICES", size)
        elif size % 4 == 0 and size <= 256 and "byteStride" not in document["bufferViews"][view]:
            modes[view] = ("ATTRIBUTES", size)
    return modes


def compress_glb(data: bytes, textures: str = "png", geometry: str = "plain", codec: str = "etc1s") -> bytes:
    """``data`` (a GLB of :func:`farfield.core.impostor.glb.impostor_glb`) with its textures and geometry compressed
    (see the module docstring); a GLB it cannot read is a :class:`BundleFormatError`.

    >>> from farfield.core.impostor.glb import impostor_glb
    >>> from farfield.core.impostor.impostor import Impostor, QuadPayload
    >>> quad = np.array([[[-1, 5, 1], [1, 5, 1], [1, 5, -1], [-1, 5, -1]]], dtype=np.float64)
    >>> uv = np.array([[[0, 0], [1, 0], [1, 1], [0, 1]]], dtype=np.float64)
    >>> page = np.full((8, 8, 4), 200, np.uint8)
    >>> plain = impostor_glb(Impostor("billboard", {}, np.zeros(3), 64, 60.0, (page,), QuadPayload(quad, uv, np.zeros(1, np.int64), np.zeros(1, np.int64))))
    >>> document, _ = read_glb(compress_glb(plain, "ktx2", "meshopt"))
    >>> document["extensionsRequired"], document["images"][0]["mimeType"], document["textures"][0]["extensions"]
    (['EXT_meshopt_compression', 'KHR_texture_basisu'], 'image/ktx2', {'KHR_texture_basisu': {'source': 0}})
    >>> compress_glb(plain) == plain
    True
    """
    if len(data) >= 12 and data[:4] == b"glTF" and int.from_bytes(data[8:12], "little") > len(data):
        raise BundleFormatError(
            f"GLB: truncated: its header says {int.from_bytes(data[8:12], 'little'):,} bytes, the file has {len(data):,}"
        )
    try:
        return _compress(data, textures, geometry, codec)
    except UnidentifiedImageError:  # an OSError: before the general case, whose message would name a BytesIO
        raise BundleFormatError(
            "GLB: not one this can compress (an embedded image is neither a PNG nor a JPEG PIL can read)"
        ) from None
    except (KeyError, IndexError, TypeError, ValueError, OSError) as error:
        raise BundleFormatError(f"GLB: not one this can compress ({type(error).__name__}: {error})") from None


def _compress(data: bytes, textures: str, geometry: str, codec: str) -> bytes:
    import meshopt

    if textures not in TEXTURES:
        raise BundleFormatError(f"textures must be one of {list(TEXTURES)}, got {textures!r}")
    if geometry not in GEOMETRY:
        raise BundleFormatError(f"geometry must be one of {list(GEOMETRY)}, got {geometry!r}")
    if codec not in CODECS:
        raise BundleFormatError(f"codec must be one of {list(CODECS)}, got {codec!r}")
    document, blob = read_glb(data)
    if textures == "png" and geometry == "plain":
        return data
    if {BASISU, MESHOPT} & set(document.get("extensionsUsed", [])):
        raise BundleFormatError("the GLB is compressed already (it uses KHR_texture_basisu or EXT_meshopt_compression)")
    if len(document.get("buffers", [])) > 1 or any("uri" in b for b in document.get("buffers", [])):
        raise BundleFormatError("only a self-contained GLB (one buffer, the BIN chunk) can be compressed here")
    images = document.get("images", [])
    if textures != "png" and any(img.get("mimeType") != "image/png" or "bufferView" not in img for img in images):
        raise BundleFormatError("KTX2 pages are made from PNG images inside the GLB; this GLB has others")
    views = document.get("bufferViews", [])
    image_views = {img["bufferView"] for img in images if "bufferView" in img}
    used = set(document.get("extensionsUsed", []))
    required = set(document.get("extensionsRequired", []))
    keep_png = textures == "ktx2+png"

    # Normal textures (a lit impostor's, glTF normalTexture) hold directions, not colours: UASTC
    # whatever the codec asked (ETC1S's shared endpoints bend normals by degrees), linear transfer.
    # So do the material pages (glTF's ORM packing: occlusion, roughness, metallic), linear data
    # too; an emissive page is a colour, sRGB in the codec asked.
    # An octahedral impostor's frame pages of normals (world, depth in alpha) and materials, which
    # only its extension names, are such data too.
    frame_data = _octahedral_images(document, ("normal", "material"))
    normal_images = _normal_images(document) | _material_images(document) | frame_data
    # Normal textures whose alpha holds depth (farfield.core.impostor.depth): UASTC at quality 100,
    # which keeps the alpha within 3 levels at the 99th percentile (the default 50: 20).
    depth_images = _normal_images(document, DEPTH_EXTENSION) | _octahedral_images(document, ("normal",))
    # The pages first: a page grown to whole 4 x 4 blocks scales the texture coordinates that use it.
    pages: list[tuple[bytes, bytes | None]] = []  # per image: (PNG to keep or b"", KTX2 or None)
    grown: dict[int, tuple[float, float]] = {}  # image -> (u, v) scale
    for n, image in enumerate(images):
        png = _view_bytes(document, blob, image["bufferView"])
        if textures == "png":
            pages.append((png, None))
            continue
        rgba = np.asarray(Image.open(io.BytesIO(png)).convert("RGBA"))
        padded = block_padded(rgba)
        if padded.shape != rgba.shape:
            grown[n] = (rgba.shape[1] / padded.shape[1], rgba.shape[0] / padded.shape[0])
            png = page_png(padded) if keep_png else png  # the fallback shares the scaled coordinates
        normal = n in normal_images
        quality = _UASTC_DEPTH_QUALITY if n in depth_images else None
        pages.append(
            (
                png if keep_png else b"",
                ktx2_page(padded, "uastc" if normal else codec, srgb=not normal, uastc_quality=quality),
            )
        )
    scale = _uv_scales(document, grown)

    out, fallback = _Blob(), _Blob()
    new_views: list[dict | None] = [None] * len(views)
    compressed = _geometry_views(document) if geometry == "meshopt" else {}
    for n, view in enumerate(views):
        if n in image_views:
            continue  # written with the images below
        raw = _view_bytes(document, blob, n)
        if n in scale:
            raw = (np.frombuffer(raw, "<f4").reshape(-1, 2) * np.asarray(scale[n], dtype="<f4")).astype("<f4").tobytes()
        if n in compressed:
            mode, size = compressed[n]
            count = len(raw) // size
            if mode == "ATTRIBUTES":
                encoded = meshopt.encode_gltf_buffer(np.frombuffer(raw, np.uint8).reshape(count, size), mode)
            else:
                encoded = meshopt.encode_gltf_buffer(np.frombuffer(raw, np.uint16 if size == 2 else np.uint32), mode)
            offset, length = out.add(encoded)
            place, _ = fallback.add(raw)
            new_views[n] = {**view, "buffer": 1, "byteOffset": place, "byteLength": len(raw),
                            "extensions": {MESHOPT: {"buffer": 0, "byteOffset": offset, "byteLength": length, "byteStride": size, "mode": mode, "count": count}}}  # fmt: skip
        else:
            offset, length = out.add(raw)
            new_views[n] = {**view, "buffer": 0, "byteOffset": offset, "byteLength": length}

    new_images: list[dict] = []
    png_of: dict[int, int] = {}
    ktx2_of: dict[int, int] = {}
    for n, (image, (png, ktx2)) in enumerate(zip(images, pages)):
        if png:
            offset, length = out.add(png)
            new_views[image["bufferView"]] = {"buffer": 0, "byteOffset": offset, "byteLength": length}
            png_of[n] = len(new_images)
            new_images.append(image)
        if ktx2 is not None:
            offset, length = out.add(ktx2)
            new_views.append({"buffer": 0, "byteOffset": offset, "byteLength": length})
            ktx2_of[n] = len(new_images)
            new_images.append(
                {
                    "bufferView": len(new_views) - 1,
                    "mimeType": "image/ktx2",
                    "name": f"{image.get('name', f'image-{n}')}-{'uastc' if n in normal_images else codec}",
                }
            )
    for texture in document.get("textures", []) if textures != "png" else []:
        source = texture["source"]
        texture.setdefault("extensions", {})[BASISU] = {"source": ktx2_of[source]}
        if keep_png:
            texture["source"] = png_of[source]  # the PNG, for viewers without the extension
        else:
            del texture["source"]
        used.add(BASISU)
        if not keep_png:
            required.add(BASISU)

    # renumber the bufferViews that remain (a dropped PNG's view is gone)
    renumber, kept = {}, []
    for n, view in enumerate(new_views):
        if view is not None:
            renumber[n] = len(kept)
            kept.append(view)
    for accessor in document.get("accessors", []):
        if "bufferView" in accessor:
            accessor["bufferView"] = renumber[accessor["bufferView"]]
    for image in new_images:
        image["bufferView"] = renumber[image["bufferView"]]
    if kept:
        document["bufferViews"] = kept
    else:
        document.pop("bufferViews", None)
    if new_images:
        document["images"] = new_images
    buffers = [{"byteLength": out.length}] if out.length else []
    if compressed:
        buffers.append({"byteLength": fallback.length, "extensions": {MESHOPT: {"fallback": True}}})
        used.add(MESHOPT)
        required.add(MESHOPT)
    if buffers:
        document["buffers"] = buffers
    else:
        document.pop("buffers", None)
    if used:
        document["extensionsUsed"] = sorted(used)
    if required:
        document["extensionsRequired"] = sorted(required)
    return write_glb(document, out.bytes())


def _normal_images(document: dict, extension: str | None = None) -> set[int]:
    """The images that materials use as ``normalTexture`` (only materials with ``extension``, when given)."""
    textures = document.get("textures", [])
    found = set()
    for material in document.get("materials", []):
        if extension is not None and extension not in material.get("extensions", {}):
            continue
        info = material.get("normalTexture")
        if isinstance(info, dict) and isinstance(info.get("index"), int) and info["index"] < len(textures):
            source = textures[info["index"]].get("source")
            if isinstance(source, int):
                found.add(source)
    return found


def _octahedral_images(document: dict, sets: tuple[str, ...]) -> set[int]:
    """The images of the page ``sets`` (e.g. ``"normal"``) that an octahedral impostor's extension
    (:data:`farfield.core.impostor.glb.OCTAHEDRAL_EXTENSION`, on a primitive) names by texture."""
    textures = document.get("textures", [])
    found = set()
    for mesh in document.get("meshes", []):
        for primitive in mesh.get("primitives", []):
            pages = primitive.get("extensions", {}).get(OCTAHEDRAL_EXTENSION, {}).get("pages", {})
            for name in sets:
                for index in pages.get(name, []) if isinstance(pages, dict) else []:
                    if (
                        isinstance(index, int)
                        and 0 <= index < len(textures)
                        and isinstance(textures[index].get("source"), int)
                    ):
                        found.add(textures[index]["source"])
    return found


def _material_images(document: dict) -> set[int]:
    """The images that materials use as ``metallicRoughnessTexture`` or ``occlusionTexture`` (linear data)."""
    textures = document.get("textures", [])
    found = set()
    for material in document.get("materials", []):
        pbr = material.get("pbrMetallicRoughness", {})
        for info in (
            pbr.get("metallicRoughnessTexture") if isinstance(pbr, dict) else None,
            material.get("occlusionTexture"),
        ):
            if isinstance(info, dict) and isinstance(info.get("index"), int) and info["index"] < len(textures):
                source = textures[info["index"]].get("source")
                if isinstance(source, int):
                    found.add(source)
    return found


def _uv_scales(document: dict, grown: dict[int, tuple[float, float]]) -> dict[int, tuple[float, float]]:
    """bufferView -> (u, v) scale for the texture coordinates of every primitive whose base-colour
    texture's image was grown to whole blocks."""
    out: dict[int, tuple[float, float]] = {}
    if not grown:
        return out
    materials, textures, accessors = (
        document.get("materials", []),
        document.get("textures", []),
        document.get("accessors", []),
    )
    for mesh in document.get("meshes", []):
        for primitive in mesh["primitives"]:
            info = (
                materials[primitive["material"]].get("pbrMetallicRoughness", {}).get("baseColorTexture")
                if "material" in primitive
                else None
            )
            if info is None or textures[info["index"]]["source"] not in grown:
                continue
            accessor = accessors[primitive["attributes"][f"TEXCOORD_{info.get('texCoord', 0)}"]]
            if (
                accessor["componentType"] != 5126
                or accessor["type"] != "VEC2"
                or "byteStride" in document["bufferViews"][accessor["bufferView"]]
            ):
                raise BundleFormatError(
                    "a grown page's texture coordinates must be a float VEC2 bufferView of their own"
                )
            factor = grown[textures[info["index"]]["source"]]
            if out.setdefault(accessor["bufferView"], factor) != factor:
                raise BundleFormatError("texture coordinates shared by pages of different sizes")
    return out
