"""OBJ polygons of five or more corners whose fan does not cover them -> triangles that do, before trimesh parses the text.

An OBJ face may be any planar polygon (the specification's "polygonal face element"), convex or
not: a floor plan's L-shaped face, a window frame's outline.  trimesh (and three.js's OBJLoader)
split a polygon as a fan from its first corner, which covers the polygon only where that corner
sees every other one: an L-shaped hexagon fanned from a corner of its long arm covers 4 square
units for its 3, a triangle of it outside the polygon and another one counted twice (Blender and
Assimp triangulate it right).  Here a polygon of five or more corners whose fan has a triangle
turned against the polygon (its normal against the polygon's Newell normal) is cut into triangles
by ear clipping in its plane (``mapbox_earcut``), each written as a face of its own with the
corners' own ``v/vt/vn`` words.  A polygon whose fan covers it is left as it is, so files without
such polygons read exactly as before.  Quads are not looked at: scanning every quad of a large
quad mesh would cost more than a concave quad is worth (a fan is what engines draw of one).

The polygons are found by one scan of the text (0.23 s for a 56 MB OBJ of 1 M quads, about 5 %
of its load); only files holding one pay for reading their vertices.  Ear clipping costs more per
corner as a polygon grows (a comb-shaped polygon: 2.1 µs a corner at 1,000 corners, 4.5 at
10,000, 48 at 100,000, 358 at 400,000: 143 s for one 7.8 MB face), so a polygon of more than
:data:`MAX_CLIPPED_CORNERS` corners is fanned, as before, with a warning.
"""

from __future__ import annotations

import re

import mapbox_earcut
import numpy as np

# The start of a face statement of five or more corners, after its newline (single spaces between
# the first five words: the cheapest scan measured, 0.23 s against 0.36-0.66 s for looser ones on
# 56 MB; a polygon written with wider gaps is fanned, as before).
_POLYGON = re.compile(r"\nf [^ \n]+ [^ \n]+ [^ \n]+ [^ \n]+ +[^ \n\r]")
_V = re.compile(r"^v +([^\r\n]*)", re.MULTILINE)

# The most corners of a polygon that is ear-clipped (module docstring): beyond, its fan is kept.
MAX_CLIPPED_CORNERS = 10_000


def _positions(text: str) -> np.ndarray | None:
    """(v, 3) float64 positions of the ``v`` lines, or None where one is not three numbers
    (trimesh's parse then names the problem)."""
    try:
        return np.array([line.split()[:3] for line in _V.findall(text)], dtype=np.float64).reshape(-1, 3)
    except ValueError:
        return None


def _fan_covers(points: np.ndarray, normal: np.ndarray) -> bool:
    """Whether the fan from the first point covers the polygon: every fan triangle turns its way."""
    turns = np.cross(points[1:-1] - points[0], points[2:] - points[0]) @ normal
    return bool(turns.min() >= -1e-12 * max(float(np.abs(turns).max()), 1e-300))


def _triangles(points: np.ndarray, normal: np.ndarray) -> np.ndarray | None:
    """(t, 3) corner indices of the polygon cut by ear clipping in its plane, each triangle turned
    as the polygon (counter-clockwise about ``normal``), or None where it cannot be cut."""
    axis = int(np.argmax(np.abs(normal)))
    keep = [k for k in range(3) if k != axis]
    flat = points[:, keep]
    found = mapbox_earcut.triangulate_float64(np.ascontiguousarray(flat), np.array([len(points)], dtype=np.uint32))
    if len(found) != 3 * (len(points) - 2):
        return None  # self-intersecting or degenerate: the fan, as before
    triangles = np.asarray(found, dtype=np.int64).reshape(-1, 3)
    a, b, c = (points[triangles[:, k]] for k in range(3))
    against = np.cross(b - a, c - a) @ normal < 0.0
    triangles[against] = triangles[against][:, ::-1]
    return triangles


def split_concave(text: str, warnings: list[str] | None = None) -> str:
    """``text`` with each face of five or more corners that its fan does not cover written as the
    triangles that do (module docstring); ``text`` itself where there is none.  A warning is
    appended to ``warnings`` for each such face of more than :data:`MAX_CLIPPED_CORNERS` corners,
    which is left to the fan.

    Relative indices must already be absolute (:mod:`farfield.core.exchange.obj_indices`), but for
    those trimesh reads right (counted from the end of the list), which are resolved so here.

    >>> split_concave("v 0 0 0\\nv 2 0 0\\nv 2 1 0\\nv 1 1 0\\nv 1 2 0\\nv 0 2 0\\nf 2 3 4 5 6 1\\n").splitlines()[6:]
    ['f 1 2 3', 'f 1 3 4', 'f 1 4 5', 'f 1 5 6']
    >>> split_concave("v 0 0 0\\nv 2 0 0\\nv 2 1 0\\nv 1 1 0\\nv 1 2 0\\nv 0 2 0\\nf 4 5 6 1 2 3\\n").endswith("f 4 5 6 1 2 3\\n")
    True
    """
    starts = [match.start() + 1 for match in _POLYGON.finditer(text)]
    if text.startswith("f "):
        starts = [0, *starts]  # the scan finds it only after a newline; the loop checks its corners
    if not starts:
        return text
    positions = _positions(text)
    if positions is None:
        return text
    count = len(positions)
    pieces: list[str] = []
    done = 0
    for start in starts:
        end = text.find("\n", start)
        end = len(text) if end < 0 else end
        words = text[start:end].split()[1:]
        if len(words) < 5:
            continue
        try:
            indices = np.array([int(word.split("/", 1)[0]) for word in words], dtype=np.int64)
        except (ValueError, OverflowError):  # not a number, or one beyond 64 bits
            continue  # trimesh's parse refuses it
        indices = np.where(indices > 0, indices - 1, count + indices)
        if indices.min() < 0 or indices.max() >= count:
            continue  # named by the parse's error (obj_indices.beyond_the_end)
        points = positions[indices]
        normal = np.cross(points, np.roll(points, -1, axis=0)).sum(axis=0)  # Newell: twice the area vector
        if not np.any(normal) or _fan_covers(points, normal):
            continue
        if len(points) > MAX_CLIPPED_CORNERS:
            if warnings is not None:
                warnings.append(
                    f"the concave polygon 'f {' '.join(words[:3])} ...' has {len(points):,} corners (more than "
                    f"{MAX_CLIPPED_CORNERS:,}): it is drawn as the fan from its first corner, which covers parts "
                    "of it twice or outside it"
                )
            continue
        triangles = _triangles(points, normal)
        if triangles is None:
            continue
        pieces += [text[done:start], "\n".join("f " + " ".join(words[k] for k in t) for t in triangles)]
        done = end
    return "".join(pieces) + text[done:] if pieces else text
