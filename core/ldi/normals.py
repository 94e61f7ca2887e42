"""World shading normals of LDI samples: (m, 3) float64 unit vectors, one per sample (point-based
and LDI impostors keep them where an engine will light them, ``channels="albedo+normal"``).

A sample of a layered depth image knows the object and the triangle it lies on (:mod:`farfield.core.ldi.image`),
so its normal is computed, not recorded: the triangle's shading normals
(:func:`corner_normals`: the vertex normals where the object has them, else its face normal;
reversed on a double-sided triangle whose back faces the whole view cell)
interpolated at the sample's position with its barycentric coordinates in the triangle, exactly as
the G-buffer (``mesh.frag``'s NORMALS output) interpolates them over the triangle's pixels.  A sample
the LDI moved onto its pixel's centre ray (up to half a pixel sideways, seed 004 §4.1's merge) may
lie just outside its triangle: its barycentric coordinates are held to the triangle (:func:`barycentric`).
"""

from __future__ import annotations

import numpy as np

from farfield.core.scene import SceneObject


def barycentric(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """(m, 3) float64 barycentric weights of ``points`` (m, 3) projected onto their triangles
    ``corners`` (m, 3, 3), held to the triangle: negative weights set to 0 and the rest rescaled
    to sum to 1 (a point just outside an edge gets about its nearest point's); a degenerate
    triangle gives its first corner the whole weight.

    >>> tri = np.array([[[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]] * 2)
    >>> barycentric(np.array([[0.25, 0.25, 3.0], [-1.0, 0.5, 0.0]]), tri).round(3).tolist()
    [[0.5, 0.25, 0.25], [0.75, 0.0, 0.25]]
    """
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    e0, e1, d = b - a, c - a, np.asarray(points, dtype=np.float64) - a
    d00, d01, d11 = (np.einsum("ij,ij->i", x, y) for x, y in ((e0, e0), (e0, e1), (e1, e1)))
    d20, d21 = np.einsum("ij,ij->i", d, e0), np.einsum("ij,ij->i", d, e1)
    det = d00 * d11 - d01 * d01
    ok = det > 0.0
    det = np.where(ok, det, 1.0)
    v = np.where(ok, (d11 * d20 - d01 * d21) / det, 0.0)
    w = np.where(ok, (d00 * d21 - d01 * d20) / det, 0.0)
    weights = np.maximum(np.stack([1.0 - v - w, v, w], axis=1), 0.0)
    return weights / weights.sum(axis=1, keepdims=True)  # at least one weight stays positive


def corner_normals(obj: SceneObject, triangle: np.ndarray, viewpoints: np.ndarray) -> np.ndarray:
    """(n, 3, 3) float64 shading normals (triangle, corner, coordinate) of ``obj``'s triangles
    ``triangle`` (n,): the vertex normals where the object has them, else the face normal (glTF's
    flat shading where ``NORMAL`` is missing); a double-sided triangle whose back faces every one
    of ``viewpoints`` (k, 3) has them reversed (as glTF draws the back of a double-sided
    material), any other keeps its front's.

    Unlike a layer's texel, seen from its reference viewpoint
    (:func:`farfield.core.layering.recording.pair_normals`), a point or an LDI sample is drawn for
    every viewer in the cell, so it shows its front wherever some viewer in the cell sees that:
    a closed surface's rim, back-facing from the cell's centre but seen from a corner, keeps its
    outward normal.

    >>> tri = SceneObject("t", np.array([[0.0, 0, 5], [1, 0, 5], [0, 1, 5]]), np.array([[0, 1, 2]]))
    >>> (corner_normals(tri, np.array([0]), np.zeros((1, 3)))[0, 0] + 0.0).tolist()  # its front (+z) faces away
    [0.0, 0.0, -1.0]
    >>> corner_normals(tri, np.array([0]), np.array([[0.0, 0, 0], [0, 0, 6]]))[0, 0].tolist()
    [0.0, 0.0, 1.0]
    """
    faces = obj.faces[triangle]  # (n, 3)
    corners = obj.vertices[faces]  # (n, 3, 3)
    face = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    if obj.normals is not None:
        normals = obj.normals[faces]
    else:
        length = np.linalg.norm(face, axis=1, keepdims=True)
        unit = np.divide(face, length, out=np.zeros_like(face), where=length > 0.0)
        normals = np.repeat(unit[:, None, :], 3, axis=1)
    if obj.double_sided:
        centroid = corners.mean(axis=1)
        towards = np.asarray(viewpoints, dtype=np.float64).reshape(-1, 3)
        behind = np.all(np.einsum("ni,nki->nk", face, centroid[:, None, :] - towards[None]) > 0.0, axis=1)
        normals = np.where(behind[:, None, None], -normals, normals)
    return normals


def sample_normals(
    objects: list[SceneObject] | tuple[SceneObject, ...],
    obj: np.ndarray,
    triangle: np.ndarray,
    positions: np.ndarray,
    viewpoints: np.ndarray,
) -> np.ndarray:
    """(m, 3) float64 unit world shading normals of samples on triangle ``triangle`` (m,) int of
    ``objects[obj]`` (m,) at world ``positions`` (m, 3), on the side ``viewpoints`` (k, 3) (the view
    cell's corners) see (:func:`corner_normals`), interpolated as the module docstring says.  Where
    the interpolated vertex normals cancel, the nearest corner's.

    >>> tri = SceneObject("t", np.array([[0.0, 0, 5], [1, 0, 5], [0, 1, 5]]), np.array([[0, 1, 2]]),
    ...                   normals=np.array([[0.0, 0, 1], [1, 0, 0], [0, 0, 1]]))
    >>> sample_normals([tri], np.array([0]), np.array([0]), np.array([[0.5, 0.0, 5.0]]), np.zeros((1, 3))).round(3).tolist()
    [[-0.707, 0.0, -0.707]]
    """
    obj, triangle = np.asarray(obj, dtype=np.int64), np.asarray(triangle, dtype=np.int64)
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    out = np.zeros((positions.shape[0], 3))
    for k in np.unique(obj):
        mine = np.flatnonzero(obj == k)
        o = objects[int(k)]
        corners = corner_normals(o, triangle[mine], viewpoints)  # (m', 3 corners, 3)
        weights = barycentric(positions[mine], o.vertices[o.faces[triangle[mine]]])
        normal = np.einsum("mkc,mk->mc", corners, weights)
        length = np.linalg.norm(normal, axis=1)
        nearest = corners[np.arange(mine.size), np.argmax(weights, axis=1)]
        out[mine] = np.where((length > 1e-6)[:, None], normal / np.maximum(length, 1e-300)[:, None], nearest)
    return out
