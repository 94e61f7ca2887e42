"""Stanford PLY (ASCII or binary) -> (1,) SceneObject named after the file, with vertex or face colours if any.

A PLY file holds one mesh.  ``red, green, blue[, alpha]`` vertex properties become vertex colours;
face colours become the material colour when uniform, else per-corner vertex colours.  A file with
vertices but no faces is a point cloud and has no triangles.

Shading normals: ``nx ny nz`` vertex properties when all three are declared, of any numeric type
(the format states no range: a float is taken as it is, an integer type scaled to -1..1 by its
range as glTF scales normalized integers, §3.11; the direction is what counts, since they are
renormalised), and zero or non-finite ones repaired with a warning
(:mod:`farfield.core.exchange.normals`).  Without them the object is shaded flat.

Sidedness: the format states none, so every object is one-sided by default (``sides="one"``: seen
from the front of each triangle only, counter-clockwise, as engines and three.js's PLYLoader draw the
file) or double-sided with ``sides="both"`` (:mod:`farfield.core.sidedness`).
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import PurePath

import numpy as np
import trimesh
from trimesh.resolvers import Resolver

from farfield.core.errors import SceneLoadError
from farfield.core.exchange.limits import DEFAULT_LIMITS, SceneLimits
from farfield.core.exchange.ply_colours import _header, vertex_colours
from farfield.core.exchange.trimesh_scene import objects_from_trimesh, parse
from farfield.core.scene import SceneObject
from farfield.core.sidedness import DEFAULT_SIDES, double_sided

# The format states no sidedness: load takes the ``sides`` option (farfield.core.exchange.load_scene).
SIDES_OPTION = True
EXTENSIONS = ("ply",)


# ``\r`` too: a header of CRLF lines (the Stanford bunny's) is a header.
_ELEMENT = re.compile(rb"^element[ \t]+(\w+)[ \t]+(\d+)[ \t\r]*$", re.MULTILINE)
_ASCII = re.compile(rb"^format[ \t]+ascii[ \t\r]", re.MULTILINE)


def _declared_counts(data: bytes) -> dict[str, int]:
    """``element`` counts of a PLY header, by name (the header ends at ``end_header``)."""
    end = data.find(b"end_header")
    header = data[: end if end >= 0 else 4096]
    return {name.decode("ascii", "replace"): int(count) for name, count in _ELEMENT.findall(header)}


def _check_ascii_length(data: bytes, declared: dict[str, int]) -> None:
    """Raise SceneLoadError when an ASCII PLY holds fewer data lines than its header declares
    elements (one a line): a truncated file, which trimesh either reads short or fails on with a
    message about arrays."""
    end = data.find(b"end_header")
    if end < 0 or not declared or not _ASCII.search(data[:end]):
        return
    data_lines = [line for line in data[end:].splitlines()[1:] if line.strip()]
    lines = len(data_lines)
    for element, count in declared.items():  # the elements' lines follow each other in header order
        if lines < count:
            raise SceneLoadError(
                f"the header declares {count:,} {element} elements but the file holds {lines:,} "
                "(truncated or a corrupt header)"
            )
        lines -= count
    _check_last_line(data, data_lines)


def _check_last_line(data: bytes, data_lines: list[bytes]) -> None:
    """Raise SceneLoadError when the last element line of an ASCII PLY holds fewer values than its
    properties need: a file cut inside its last line has the declared count of lines, and trimesh
    reads the cut face with whatever indices are left (or fails on numpy's shapes)."""
    parsed = _header(data)
    elements = [element for element in parsed[1] if element[1] > 0] if parsed else []
    if not elements or not data_lines:
        return
    name, _count, properties = elements[-1]
    words = data_lines[sum(element[1] for element in elements) - 1].split()
    needed, at = 0, 0
    for _property, kind in properties:  # a list property is its length, then that many values
        if kind is None:
            if at >= len(words):
                needed = at + 1
                break
            if not words[at].isdigit():
                return  # not a count: trimesh's parser says what is wrong
            needed = at = at + 1 + int(words[at])
        else:
            needed = at = at + 1
    if len(words) < needed:
        raise SceneLoadError(
            f"the last {name} element has {len(words)} values where its properties need {needed} "
            "(truncated inside its last line)"
        )


def _normals(mesh: trimesh.Trimesh, warnings: list[str]) -> np.ndarray | None:
    """(v, 3) float64 normals of the file's ``nx ny nz`` (trimesh keeps the vertex element as read,
    by declared type, in ``metadata["_ply_raw"]``), integer types scaled by their range; None when
    the file has none."""
    raw = mesh.metadata.get("_ply_raw", {}).get("vertex", {}).get("data")
    try:
        columns = [np.asarray(raw[axis]) for axis in ("nx", "ny", "nz")]
    except (KeyError, ValueError, IndexError, TypeError):
        return None
    scaled = []
    for column in columns:
        if column.dtype.kind in "iu":
            info = np.iinfo(column.dtype)
            scaled.append(np.maximum(column.astype(np.float64) / float(info.max), -1.0))
        else:
            scaled.append(column.astype(np.float64))
    normals = np.column_stack(scaled)
    if normals.shape != mesh.vertices.shape:
        # trimesh unmerges the vertices of a file with per-face texture coordinates (its face
        # ``texcoord`` lists); which vertex came from which it does not say.
        warnings.append("the file's vertex normals do not match the vertices of its per-face uv; shaded flat")
        return None
    return normals


def load(
    data: bytes,
    extension: str,
    name: str,
    resolver: Resolver,
    limits: SceneLimits = DEFAULT_LIMITS,
    sides: str = DEFAULT_SIDES,
) -> tuple[tuple[SceneObject, ...], tuple[str, ...]]:
    """Objects and warnings of a PLY file.

    Parameters
    ----------
    data : bytes
        The PLY file.
    extension : str
        ``"ply"``.
    name : str
        The file's name; its stem names the object.
    resolver : trimesh.resolvers.Resolver
        Finds a texture named by a ``comment TextureFile`` header line.

    sides : str
        ``"one"`` (the default: one-sided objects, as engines draw the format) or ``"both"``.

    Raises
    ------
    SceneLoadError
        Not a PLY file, or a header that does not match the data.
    """
    declared = _declared_counts(data)
    _check_ascii_length(data, declared)
    try:
        scene = parse(data, extension, resolver)
    except SceneLoadError as error:
        if "unexpected length" not in str(error):
            raise
        counts = " and ".join(f"{count:,} {element}" for element, count in declared.items())
        raise SceneLoadError(
            f"the binary data ({len(data):,} bytes in all) is not the length the header's {counts} elements "
            "need (truncated or a corrupt header)"
        ) from error
    held = {"vertex": 0, "face": 0}
    for geometry in scene.geometry.values():
        held["vertex"] += len(getattr(geometry, "vertices", ()))
        held["face"] += len(getattr(geometry, "faces", ()) if hasattr(geometry, "faces") else ())
    for element, count in declared.items():
        if element in held and held[element] < count:
            raise SceneLoadError(
                f"the header declares {count:,} {element} elements but the file holds {held[element]:,} "
                "(truncated or a corrupt header)"
            )
    nodes = list(scene.graph.nodes_geometry)
    rename = {nodes[0]: PurePath(name).stem or name} if len(nodes) == 1 else None
    warnings: list[str] = []
    normals = {
        key: found
        for key, mesh in scene.geometry.items()
        if isinstance(mesh, trimesh.Trimesh) and (found := _normals(mesh, warnings)) is not None
    }
    objects, more = objects_from_trimesh(
        scene,
        rename=rename,
        double_sided=double_sided(sides),
        max_texture_pixels=limits.texel_budget(),
        normals=normals,
    )
    warnings.extend(more)
    colours = vertex_colours(data)  # by their declared type: trimesh truncates ushort colours to a byte
    if colours is not None:
        objects = tuple(
            replace(obj, vertex_colors=colours)
            if obj.vertex_colors is not None and len(obj.vertex_colors) == len(colours)
            else obj
            for obj in objects
        )
    return objects, tuple(warnings)
