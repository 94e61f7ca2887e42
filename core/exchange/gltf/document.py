"""A glTF 2.0 asset's JSON document and the bytes its buffers, buffer views and images hold.

The container rules of the glTF 2.0 specification (Khronos, glTF 2.0, §4 "Binary glTF", §3.6
"Buffers and buffer views", §3.8 "Textures"): a ``.glb`` is a 12-byte header, a JSON chunk and an
optional BIN chunk, which is the buffer without a ``uri``; a ``.gltf`` is the JSON alone.  A
``uri`` is a ``data:`` URI (base64) or a relative reference, percent-encoded (RFC 3986), looked up
through a trimesh resolver (beside the file on disk; among the uploaded files).
"""

from __future__ import annotations

import base64
import binascii
import json
import struct
from urllib.parse import unquote

from trimesh.resolvers import Resolver

from farfield.core.errors import SceneLoadError
from farfield.core.exchange.trimesh_scene import fetch

_GLB_MAGIC = b"glTF"
_JSON_CHUNK = 0x4E4F534A  # "JSON", little-endian uint32
_BIN_CHUNK = 0x004E4942  # "BIN\0"


def uri_path(uri: str) -> str:
    """The relative file path a non-``data:`` URI names: percent-decoded, as the spec requires
    (``my%20texture.png`` is the file ``my texture.png``)."""
    return unquote(uri)


def uri_bytes(uri: str, resolver: Resolver) -> bytes | None:
    """The bytes ``uri`` refers to, or None where it cannot be found.

    Raises
    ------
    SceneLoadError
        A ``data:`` URI that is not base64 or does not decode.
    """
    if uri.startswith("data:"):
        head, _, payload = uri.partition(",")
        if not head.endswith(";base64"):
            raise SceneLoadError(f"data URI {head[:60]!r} is not base64 (glTF requires base64 data URIs)")
        try:
            return base64.b64decode(payload, validate=False)
        except (binascii.Error, ValueError) as error:
            raise SceneLoadError(f"data URI does not decode as base64: {error}") from error
    found = fetch(resolver, uri_path(uri))
    return found if found is not None or uri_path(uri) == uri else fetch(resolver, uri)


def split_glb(data: bytes) -> tuple[bytes, bytes | None]:
    """(JSON chunk, BIN chunk or None) of a ``.glb``.

    Raises
    ------
    SceneLoadError
        Not a GLB, a version other than 2, or chunks that run past the file.
    """
    if data[:4] != _GLB_MAGIC:
        raise SceneLoadError(f"not a GLB: a GLB starts with the bytes 'glTF', this file with {data[:4]!r}")
    if len(data) < 20:
        raise SceneLoadError(f"truncated GLB: {len(data)} bytes, the header alone takes 20")
    version, _total = struct.unpack_from("<II", data, 4)
    if version != 2:
        raise SceneLoadError(f"GLB version {version}: farfield reads glTF 2.0 (version 2) only")
    length, kind = struct.unpack_from("<II", data, 12)
    if kind != _JSON_CHUNK:
        raise SceneLoadError(f"GLB's first chunk is of type 0x{kind:08x}, not JSON")
    if 20 + length > len(data):
        raise SceneLoadError(f"truncated GLB: its JSON chunk needs {length} bytes, {len(data) - 20} are left")
    text = data[20 : 20 + length]
    offset = 20 + length
    binary = None
    if offset + 8 <= len(data):
        length, kind = struct.unpack_from("<II", data, offset)
        if kind == _BIN_CHUNK:
            binary = data[offset + 8 : offset + 8 + length]
            if len(binary) < length:
                raise SceneLoadError(f"truncated GLB: its BIN chunk needs {length} bytes, {len(binary)} are there")
    return text, binary


def header_json(data: bytes) -> dict:
    """The glTF JSON document of a .glb or .gltf file.

    Raises
    ------
    SceneLoadError
        No readable JSON document (truncated, not UTF-8, not JSON, not an object).
    """
    text = split_glb(data)[0] if data[:4] == _GLB_MAGIC else data
    try:
        document = json.loads(bytes(text).decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as error:
        raise SceneLoadError(f"glTF JSON is unreadable: {error}") from error
    if not isinstance(document, dict):
        raise SceneLoadError(f"glTF JSON is a {type(document).__name__}, not an object")
    return document


def array(document: dict, key: str) -> list:
    """The top-level array ``key`` of a document (empty when absent).

    Raises
    ------
    SceneLoadError
        ``key`` is not an array.
    """
    value = document.get(key, [])
    if not isinstance(value, list):
        raise SceneLoadError(f"glTF '{key}' is a {type(value).__name__}, not an array")
    return value


def item(document: dict, key: str, index: object) -> dict:
    """Element ``index`` of the top-level array ``key``, checked to be an object.

    Raises
    ------
    SceneLoadError
        ``index`` is not an integer in range, or the element is not an object.
    """
    items = array(document, key)
    if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < len(items):
        raise SceneLoadError(f"glTF {key} index {index!r} is out of range (the file has {len(items)} {key})")
    value = items[index]
    if not isinstance(value, dict):
        raise SceneLoadError(f"glTF {key}[{index}] is a {type(value).__name__}, not an object")
    return value


class Buffers:
    """The bytes of a document's buffers and buffer views, each fetched once, on first use.

    Parameters
    ----------
    document : dict
        The glTF JSON.
    binary : bytes or None
        A GLB's BIN chunk: the bytes of the buffer that has no ``uri``.
    resolver : trimesh.resolvers.Resolver
        Finds external ``uri`` s.
    """

    def __init__(self, document: dict, binary: bytes | None, resolver: Resolver) -> None:
        self.document = document
        self.binary = binary
        self.resolver = resolver
        self._buffers: dict[int, bytes] = {}

    def buffer(self, index: int) -> bytes:
        """Buffer ``index``'s bytes.

        Raises
        ------
        SceneLoadError
            The buffer cannot be found or is shorter than its ``byteLength``.
        """
        spec = item(self.document, "buffers", index)
        if index not in self._buffers:
            uri = spec.get("uri")
            if uri is None:
                if self.binary is None:
                    raise SceneLoadError(f"glTF buffer {index} has no uri and the file has no GLB binary chunk")
                data = self.binary
            elif isinstance(uri, str):
                data = uri_bytes(uri, self.resolver)
                if data is None:
                    shown = uri if len(uri) < 80 else uri[:77] + "..."
                    raise SceneLoadError(f"glTF buffer {index}: file {shown!r} not found (upload it with the scene)")
            else:
                raise SceneLoadError(f"glTF buffer {index}: uri is a {type(uri).__name__}, not a string")
            length = spec.get("byteLength", len(data))
            if not isinstance(length, int) or length < 0 or len(data) < length:
                raise SceneLoadError(f"glTF buffer {index}: byteLength {length!r} but {len(data)} bytes found")
            self._buffers[index] = data
        return self._buffers[index]

    def view(self, index: int) -> tuple[memoryview, int | None]:
        """(bytes, byteStride or None) of buffer view ``index``.

        Raises
        ------
        SceneLoadError
            The view runs past its buffer, or has a bad stride.
        """
        spec = item(self.document, "bufferViews", index)
        data = self.buffer(spec.get("buffer"))
        offset, length = spec.get("byteOffset", 0), spec.get("byteLength")
        if not all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in (offset, length)):
            raise SceneLoadError(
                f"glTF bufferView {index}: byteOffset {offset!r} / byteLength {length!r} are not sizes"
            )
        if offset + length > len(data):
            raise SceneLoadError(
                f"glTF bufferView {index}: bytes {offset}..{offset + length} run past its buffer of {len(data)} bytes"
            )
        stride = spec.get("byteStride")
        if stride is not None and (not isinstance(stride, int) or not 4 <= stride <= 252):
            raise SceneLoadError(f"glTF bufferView {index}: byteStride {stride!r} is not in 4..252")
        return memoryview(data)[offset : offset + length], stride

    def image(self, index: int) -> bytes | None:
        """The encoded bytes of image ``index`` (from its buffer view or its ``uri``), or None where
        its file cannot be found."""
        spec = item(self.document, "images", index)
        if "bufferView" in spec:
            return bytes(self.view(spec["bufferView"])[0])
        uri = spec.get("uri")
        if not isinstance(uri, str):
            raise SceneLoadError(f"glTF image {index} has neither a bufferView nor a uri")
        return uri_bytes(uri, self.resolver)
