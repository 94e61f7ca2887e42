"""Sidedness: which triangles of a one-sided object are seen, as (f,) bool masks over (f, 3) int64
faces of (v, 3) float64 vertices, from a set of viewpoints (a camera's eye, or a view cell's corners
and, for an unbounded shaft, its edge directions); and the ``sides`` option of the formats that
state no sidedness.

A one-sided object (:attr:`farfield.core.scene.SceneObject.double_sided` False) shows a triangle
only to a viewer on its front side, the side from which its corners run counter-clockwise, where
``n = (b - a) x (c - a)`` points; an engine culls it from behind (glTF ``doubleSided: false``;
three.js's ``FrontSide``, the material default of its OBJ, PLY and STL loaders).  Two rules follow,
both the one test of :func:`faces_seen`:

* **one camera** (evaluation, reference images, runtimes): a triangle is drawn when the eye is on
  its front side.  :class:`farfield.core.render.raster.MeshRenderer` leaves this to the GL's face
  culling, which for a perspective projection decides the same (a triangle's winding in the image
  turns exactly where the eye crosses its plane), with the front winding taken from the camera's
  handedness so that a mirroring frame decides it too (:func:`front_winding`).
* **a view cell** (the recordings of every technique): a triangle is kept when some viewpoint of
  the cell is on its front side or on its plane, and dropped only when the whole cell lies strictly
  behind its plane (:func:`seen_from_cell`).  The cell is convex, so its corners decide (and, for
  an unbounded shaft, its edges' directions: the shaft is the hull of its near cap's corners and
  the rays along them).  A triangle whose plane cuts the cell is kept: part of the cell sees it.

Double-sided objects are passed through untouched, at no cost.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import replace

import numpy as np

from farfield.core.constants import TOL
from farfield.core.errors import SceneLoadError
from farfield.core.scene import SceneObject
from farfield.core.viewcells import BoxCell, ViewCell

# The ``sides`` option of the formats that state no sidedness (OBJ, PLY, STL): "one" draws each
# triangle from its front side only, as engines and three.js's loaders draw these files; "both"
# from both sides (as farfield read every file before it read sidedness).
SIDES = ("one", "both")
DEFAULT_SIDES = "one"
# The option's help, the same in the CLI and the API.
SIDES_HELP = (
    "sidedness of the objects of OBJ, PLY and STL files, which state none: 'one' (the default) draws "
    "each triangle from its front only (counter-clockwise), as engines and three.js do; 'both' from "
    "both sides.  glTF follows its materials' doubleSided"
)


def double_sided(sides: str) -> bool:
    """Whether the ``sides`` option (``"one"`` or ``"both"``) makes objects double-sided.

    >>> double_sided("one"), double_sided("both")
    (False, True)
    >>> double_sided("two")
    Traceback (most recent call last):
    ...
    farfield.core.errors.SceneLoadError: sides must be 'one' or 'both', got 'two'
    """
    if sides not in SIDES:
        raise SceneLoadError(f"sides must be {' or '.join(map(repr, SIDES))}, got {sides!r}")
    return sides == "both"


def faces_seen(
    vertices: np.ndarray, faces: np.ndarray, points: np.ndarray, rays: np.ndarray | None = None
) -> np.ndarray:
    """(f,) bool: the triangles whose front side (or plane) some of ``points`` lies on, or whose
    front some of ``rays`` leads towards.

    A point counts as on the plane within ``TOL.rel_touch`` of the coordinates' magnitude (well
    above the rounding of the float64 plane test), so a triangle seen edge-on is kept: only a triangle with every point strictly behind it (and every ray running parallel to it
    or away from its front) is not seen.

    Parameters
    ----------
    vertices : (v, 3) float64, world units
    faces : (f, 3) int64, counter-clockwise seen from the front
    points : (p, 3) float64, world units: a camera's eye, or a view cell's corners
    rays : (r, 3) float64 or None
        Directions along which the viewpoints reach without end (an unbounded shaft's edges).

    Examples
    --------
    >>> tri = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])  # front towards +z
    >>> faces = np.array([[0, 1, 2], [0, 2, 1]])  # the second faces -z
    >>> faces_seen(tri, faces, np.array([[0.2, 0.2, 5.0]])).tolist()
    [True, False]
    >>> faces_seen(tri, faces, np.array([[0.2, 0.2, -5.0], [3.0, 3.0, 1.0]])).tolist()  # a cell across the plane
    [True, True]
    >>> faces_seen(tri, faces, np.array([[9.0, 0.0, 0.0]])).tolist()  # on the plane: edge-on, kept
    [True, True]
    >>> faces_seen(tri, faces, np.array([[0.0, 0.0, -1.0]]), rays=np.array([[0.0, 0.0, 1.0]])).tolist()
    [True, True]
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    normal = np.cross(b - a, c - a)  # (f, 3), length twice the area
    length = np.sqrt(np.einsum("ij,ij->i", normal, normal))
    offset = np.einsum("ij,ij->i", normal, a)
    # n.p - n.a rounds to within a few ulps of |n| |p| and |n| |a|, far below this slack, which
    # bounds |n| (|p - a| + the coordinates' magnitude) from above.
    scale = 4.0 * max(float(np.abs(vertices).max(initial=0.0)), float(np.abs(points).max(initial=0.0)))
    slack = TOL.rel_touch * scale * length
    seen = np.zeros(faces.shape[0], dtype=bool)
    for p in points:  # a few corners: one pass over the faces each
        seen |= normal @ p - offset >= -slack
    if rays is not None:
        for r in np.asarray(rays, dtype=np.float64).reshape(-1, 3):
            seen |= normal @ r >= -TOL.rel_touch * length * float(np.linalg.norm(r))
    return seen


def cell_viewpoints(cell: ViewCell) -> tuple[np.ndarray, np.ndarray | None]:
    """((p, 3) float64 points, (r, 3) float64 rays or None) whose hull is ``cell``: a box's eight
    corners; a bounded shaft's eight; an unbounded shaft's near cap's four and the directions of
    its four edges.

    >>> points, rays = cell_viewpoints(BoxCell([0.0, 0, 0], [1.0, 2, 3]))
    >>> points.shape, rays
    ((8, 3), None)
    """
    corners = cell.corners()
    if isinstance(cell, BoxCell) or cell.bounded:
        return corners, None
    return corners, corners - cell.apex  # the shaft's edges run from its apex through the cap's corners


def seen_faces(obj: SceneObject, points: np.ndarray, rays: np.ndarray | None = None) -> np.ndarray | None:
    """Indices (ascending) of ``obj``'s triangles seen from ``points`` (and ``rays``), or None when
    all of them are (a double-sided object, untested)."""
    if obj.double_sided:
        return None
    seen = faces_seen(obj.vertices, obj.faces, points, rays)
    return None if seen.all() else np.flatnonzero(seen)


def seen_from_cell(objects: Iterable[SceneObject], cell: ViewCell) -> tuple[SceneObject, ...]:
    """``objects`` as a view cell sees them: a one-sided object keeps the triangles some point of
    ``cell`` sees (an object none of whose triangles is seen is left out); a double-sided one, or
    one seen whole, is the same object.

    >>> from farfield.core.viewcells import BoxCell
    >>> wall = SceneObject("wall", np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]), double_sided=False)
    >>> [o.name for o in seen_from_cell([wall], BoxCell([0.0, 0, 1], [1.0, 1, 2]))]  # in front
    ['wall']
    >>> seen_from_cell([wall], BoxCell([0.0, 0, -2], [1.0, 1, -1]))  # wholly behind
    ()
    >>> len(seen_from_cell([wall], BoxCell([0.0, 0, -1], [1.0, 1, 1])))  # the plane cuts the cell
    1
    """
    objects = tuple(objects)
    if all(obj.double_sided for obj in objects):
        return objects
    points, rays = cell_viewpoints(cell)
    out = []
    for obj in objects:
        kept = seen_faces(obj, points, rays)
        if kept is None:
            out.append(obj)
        elif kept.size:
            out.append(replace(obj, faces=obj.faces[kept]))
    return tuple(out)


def front_winding(right: np.ndarray, up: np.ndarray, forward: np.ndarray) -> str:
    """The GL front face (``"ccw"`` or ``"cw"``) of a camera whose eye frame is ``right``, ``up``,
    ``forward`` (each (3,) float64) and whose projection puts ``right`` to the image's right and
    ``up`` up: counter-clockwise for the frame of an eye looking along ``forward`` (``right x up
    = -forward``, :meth:`farfield.core.render.raster.Camera.look_at`'s), clockwise for its mirror image.

    >>> front_winding(np.array([1.0, 0, 0]), np.array([0.0, 1, 0]), np.array([0.0, 0, -1]))
    'ccw'
    >>> front_winding(np.array([-1.0, 0, 0]), np.array([0.0, 1, 0]), np.array([0.0, 0, -1]))
    'cw'
    """
    return "ccw" if float(np.dot(np.cross(right, up), forward)) < 0.0 else "cw"
