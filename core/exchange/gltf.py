"""glTF 2.0 (.glb binary, .gltf JSON) -> (k,) SceneObject, one per mesh node, world transforms applied.

Object names are the scene graph's node names (unique; trimesh invents one for an unnamed node).
A node that instances a shared mesh becomes its own object.  Colours follow glTF's metallic-
roughness base colour: ``baseColorTexture`` x ``COLOR_0`` x ``baseColorFactor``; ``alphaMode``
``MASK`` gives ``alpha_cutoff`` (default 0.5).  Texture coordinates are flipped by trimesh from
glTF's top-left origin to the bottom-left origin of :mod:`farfield.core.scene`.

trimesh drops an image it cannot fetch (a missing ``uri`` file of a ``.gltf``) with a debug log
only, so :func:`load` checks every external image itself and warns.
"""

from __future__ import annotations

import json
import struct

from trimesh.resolvers import Resolver

from farfield.core.errors import SceneLoadError
from farfield.core.exchange.limits import DEFAULT_LIMITS, SceneLimits, check_gltf
from farfield.core.exchange.trimesh_scene import fetch, objects_from_trimesh, parse
from farfield.core.scene import SceneObject

EXTENSIONS = ("glb", "gltf")

_GLB_MAGIC = b"glTF"
_GLB_JSON_CHUNK = 0x4E4F534A  # "JSON", little-endian uint32 (glTF 2.0 spec, GLB file format)


def header_json(data: bytes) -> dict:
    """The glTF JSON document of a .glb or .gltf file.

    Checked here because trimesh, given JSON that is not UTF-8, tries an optional package
    (charset_normalizer) to guess its encoding and fails with an ImportError.

    Parameters
    ----------
    data : bytes
        A whole .glb (12-byte header, then a JSON chunk) or .gltf (UTF-8 JSON) file.

    Raises
    ------
    SceneLoadError
        No readable JSON document (truncated, not UTF-8, not JSON, not an object).
    """
    if data[:4] == _GLB_MAGIC:
        if len(data) < 20:
            raise SceneLoadError(f"truncated GLB: {len(data)} bytes, the header alone takes 20")
        length, kind = struct.unpack_from("<II", data, 12)
        if kind != _GLB_JSON_CHUNK:
            raise SceneLoadError(f"GLB's first chunk is of type 0x{kind:08x}, not JSON")
        text = data[20 : 20 + length]
    else:
        text = data
    try:
        document = json.loads(text.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as error:
        raise SceneLoadError(f"glTF JSON is unreadable: {error}") from error
    if not isinstance(document, dict):
        raise SceneLoadError(f"glTF JSON is a {type(document).__name__}, not an object")
    return document


def missing_images(document: dict, resolver: Resolver) -> list[str]:
    """The external image ``uri`` s of a glTF document that ``resolver`` cannot fetch."""
    missing = []
    images = document.get("images", [])
    for image in images if isinstance(images, list) else []:
        uri = image.get("uri") if isinstance(image, dict) else None
        if isinstance(uri, str) and not uri.startswith("data:") and fetch(resolver, uri) is None:
            missing.append(uri)
    return missing


def load(
    data: bytes, extension: str, name: str, resolver: Resolver, limits: SceneLimits = DEFAULT_LIMITS
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

    Raises
    ------
    SceneLoadError
        Not parseable as glTF (its JSON is checked first, then trimesh parses).
    SceneTooCostlyError
        Its node hierarchy, primitives or instanced triangles are beyond ``limits``
        (:mod:`farfield.core.exchange.limits`), found from the JSON before the buffers are parsed.
    """
    if extension == "glb" and data[:4] != _GLB_MAGIC:
        raise SceneLoadError(f"not a GLB: a GLB starts with the bytes 'glTF', this file with {data[:4]!r}")
    document = header_json(data)
    check_gltf(document, limits)
    warnings = [
        f"texture {uri!r} not found; objects using it fall back to their material colour"
        for uri in missing_images(document, resolver)
    ]
    objects, more = objects_from_trimesh(parse(data, extension, resolver), linear_colours=True)
    return objects, tuple(warnings) + more
