"""STL (binary or ASCII) -> SceneObject(s): one per ``solid``, no colour (the material default, white).

A binary STL is an 80-byte header, a little-endian uint32 triangle count ``n`` and ``50 n`` bytes
of triangles; anything else must be ASCII text starting with ``solid``.  The check is done here
because trimesh falls back from a failed binary parse to a text parse that needs an optional
package (charset_normalizer) to decode arbitrary bytes.

Sidedness: the format states none, so every object is one-sided by default (``sides="one"``: seen
from the front of each triangle only, counter-clockwise, as engines and three.js's STLLoader draw the
file) or double-sided with ``sides="both"`` (:mod:`farfield.core.sidedness`).
"""

from __future__ import annotations

import struct
from pathlib import PurePath

from trimesh.resolvers import Resolver

from farfield.core.errors import SceneLoadError
from farfield.core.exchange.limits import DEFAULT_LIMITS, SceneLimits
from farfield.core.exchange.trimesh_scene import objects_from_trimesh, parse
from farfield.core.scene import SceneObject
from farfield.core.sidedness import DEFAULT_SIDES, double_sided

# The format states no sidedness: load takes the ``sides`` option (farfield.core.exchange.load_scene).
SIDES_OPTION = True
EXTENSIONS = ("stl",)

_HEADER = 84  # bytes: 80 free-form + uint32 triangle count
_TRIANGLE = 50  # bytes: normal, 3 corners (12 float32), uint16 attribute count


def is_binary(data: bytes) -> bool:
    """Whether ``data`` has exactly the size a binary STL with its stated triangle count must have.

    >>> is_binary(bytes(80) + (1).to_bytes(4, "little") + bytes(50))
    True
    >>> is_binary(b"solid x\\nendsolid x\\n")
    False
    """
    if len(data) < _HEADER:
        return False
    (count,) = struct.unpack_from("<I", data, 80)
    return len(data) == _HEADER + _TRIANGLE * count


def check_ascii(text: str) -> None:
    """Raise unless every ``facet`` of an ASCII STL is closed and has three 3-number vertices.

    trimesh returns no triangles, without an error, for a truncated or malformed ASCII STL.

    >>> check_ascii("solid a\\nfacet normal 0 0 1\\nouter loop\\nvertex 0 0\\n")
    Traceback (most recent call last):
    ...
    farfield.core.errors.SceneLoadError: malformed ASCII STL: 1 facets, 0 endfacets, 1 vertex lines (0 with 3 numbers)
    """
    lines = text.lower().splitlines()
    opened = sum(1 for line in lines if line.split()[:1] == ["facet"])
    closed = sum(1 for line in lines if line.split()[:1] == ["endfacet"])
    vertices = [line.split() for line in lines if line.split()[:1] == ["vertex"]]
    good = sum(1 for v in vertices if len(v) == 4)
    if not (opened == closed and len(vertices) == good == 3 * opened):
        raise SceneLoadError(
            f"malformed ASCII STL: {opened} facets, {closed} endfacets, "
            f"{len(vertices)} vertex lines ({good} with 3 numbers)"
        )


def load(
    data: bytes,
    extension: str,
    name: str,
    resolver: Resolver,
    limits: SceneLimits = DEFAULT_LIMITS,
    sides: str = DEFAULT_SIDES,
) -> tuple[tuple[SceneObject, ...], tuple[str, ...]]:
    """Objects and warnings of an STL file.

    Parameters
    ----------
    data : bytes
        The STL file.
    extension : str
        ``"stl"``.
    name : str
        The file's name; its stem names a single object.
    resolver : trimesh.resolvers.Resolver
        Unused (STL refers to no other files).

    sides : str
        ``"one"`` (the default: one-sided objects, as engines draw the format) or ``"both"``.

    Raises
    ------
    SceneLoadError
        Neither a binary STL of consistent size nor ASCII text starting with ``solid``.
    """
    if not is_binary(data):
        head = data.lstrip()[:5].lower()
        if head != b"solid" or b"\x00" in data:
            count = struct.unpack_from("<I", data, 80)[0] if len(data) >= _HEADER else None
            expected = (
                "" if count is None else f" (header says {count} triangles = {_HEADER + _TRIANGLE * count} bytes)"
            )
            raise SceneLoadError(
                f"not an STL file: {len(data)} bytes do not make a binary STL{expected} "
                "and the text does not start with 'solid'"
            )
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError:
            text = data.decode("latin-1")
        check_ascii(text)
        # Re-encoded as UTF-8 so that trimesh decodes it without guessing the encoding.
        data = text.encode("utf-8")
    scene = parse(data, extension, resolver)
    nodes = list(scene.graph.nodes_geometry)
    rename = {nodes[0]: PurePath(name).stem or name} if len(nodes) == 1 else None
    return objects_from_trimesh(
        scene, rename=rename, double_sided=double_sided(sides), max_texture_pixels=limits.texel_budget()
    )
