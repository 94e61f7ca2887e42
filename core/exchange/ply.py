"""Stanford PLY (ASCII or binary) -> (1,) SceneObject named after the file, with vertex or face colours if any.

A PLY file holds one mesh.  ``red, green, blue[, alpha]`` vertex properties become vertex colours;
face colours become the material colour when uniform, else per-corner vertex colours.  A file with
vertices but no faces is a point cloud and has no triangles.

Sidedness: the format states none, so every object is one-sided by default (``sides="one"``: seen
from the front of each triangle only, counter-clockwise, as engines and three.js's PLYLoader draw the
file) or double-sided with ``sides="both"`` (:mod:`farfield.core.sidedness`).
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import PurePath

from trimesh.resolvers import Resolver

from farfield.core.errors import SceneLoadError
from farfield.core.exchange.limits import DEFAULT_LIMITS, SceneLimits
from farfield.core.exchange.ply_colours import vertex_colours
from farfield.core.exchange.trimesh_scene import objects_from_trimesh, parse
from farfield.core.scene import SceneObject
from farfield.core.sidedness import DEFAULT_SIDES, double_sided

# The format states no sidedness: load takes the ``sides`` option (farfield.core.exchange.load_scene).
SIDES_OPTION = True
EXTENSIONS = ("ply",)


_ELEMENT = re.compile(rb"^element[ \t]+(\w+)[ \t]+(\d+)[ \t]*$", re.MULTILINE)


def _declared_counts(data: bytes) -> dict[str, int]:
    """``element`` counts of a PLY header, by name (the header ends at ``end_header``)."""
    end = data.find(b"end_header")
    header = data[: end if end >= 0 else 4096]
    return {name.decode("ascii", "replace"): int(count) for name, count in _ELEMENT.findall(header)}


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
    scene = parse(data, extension, resolver)
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
    objects, warnings = objects_from_trimesh(
        scene, rename=rename, double_sided=double_sided(sides), max_texture_pixels=limits.texture_pixels
    )
    colours = vertex_colours(data)  # by their declared type: trimesh truncates ushort colours to a byte
    if colours is not None:
        objects = tuple(
            replace(obj, vertex_colors=colours)
            if obj.vertex_colors is not None and len(obj.vertex_colors) == len(colours)
            else obj
            for obj in objects
        )
    return objects, warnings
