"""Tangent frames of a textured triangle mesh (a :class:`~farfield.core.impostor.impostor.MeshPayload`)
for a tangent-space normal texture: (t, 3, 3) float64 rows T, B, N per triangle, world space, and
the per-vertex frames a viewer interpolates.

**What a viewer does.**  glTF 2.0 (§3.7.2.1, §3.9.3) gives a vertex its NORMAL and TANGENT (xyz, w
the handedness) and a viewer rebuilds the bitangent as cross(N, T) * w.  three.js (r0.187,
``tangent`` vertex chunk and ``normal_fragment_begin``/``normal_fragment_maps``) normalizes the three
per vertex, interpolates them over the triangle (perspective-correct: affine over the world
triangle, and so over its UV triangle) and normalizes each per fragment: the texel's direction m
decodes to normalize([T B N] m), a frame that need not be orthogonal inside a triangle.

**What farfield writes.**  A textured depth mesh's triangles of one chart share their vertices
and its texels (seed 003 §7, :mod:`farfield.core.techniques.tdm.texture`): a texel near an edge is
read, bilinearly, by the triangles on both sides.  With a constant frame per triangle, the two
sides decode a texel in different frames (measured on the sphere of tests/test_tdm_lit.py, 128 px:
three.js's normals 18 degrees off farfield's at the 95th percentile, the median 0.02).  farfield
therefore gives each vertex the area-weighted mean frame of its triangles (:func:`vertex_frames`;
a vertex of triangles of both handednesses is split) and converts each texel with the frame
interpolated, exactly as above, at its centre in the triangle whose UV footprint holds it
(:func:`texel_frames`): exact at texel centres, continuous across a chart's shared edges.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import distance_transform_edt

from farfield.core.impostor.impostor import MeshPayload

# Edge-function slack, texels, under which a texel centre on a triangle's edge counts as inside.
OWNER_SLACK = 1e-9


@dataclass(frozen=True, slots=True)
class VertexFrames:
    """The frames of the GLB's vertices: one per (payload vertex, handedness) pair."""

    corner: np.ndarray  # (t, 3) int64 frame vertex of each triangle corner
    normal: np.ndarray  # (f, 3) float64 unit N
    tangent: np.ndarray  # (f, 3) float64 unit T, orthogonal to N
    handed: np.ndarray  # (f,) float64 +1 or -1: B = cross(N, T) * handed

    @property
    def bitangent(self) -> np.ndarray:
        """(f, 3) float64 unit B = cross(N, T) * handed."""
        return np.cross(self.normal, self.tangent) * self.handed[:, None]


def unit_rows(a: np.ndarray) -> np.ndarray:
    """Rows of ``a`` (n, 3) scaled to unit length; zero rows stay zero."""
    length = np.linalg.norm(a, axis=-1, keepdims=True)
    return np.divide(a, length, out=np.zeros_like(a), where=length > 0.0)


def triangle_frames(payload: MeshPayload, viewpoint: np.ndarray) -> np.ndarray:
    """(t, 3, 3) float64 orthonormal rows T, B, N of each triangle's tangent frame, world space: N
    the triangle's normal on ``viewpoint``'s side, T along the page's +x (increasing u) in the
    triangle's plane, B = ±cross(N, T), the sign that points it up the page (decreasing glTF v).

    A chart's map from the triangle to the page is affine but not conformal (a projection onto a
    voxel-space plane, then the perspective of the layers), so the derivative along -v is not
    always at right angles to T; a viewer rebuilds B as cross(N, T) * w, and this is that frame.

    >>> corners = np.array([[[0, 0, 5], [2, 0, 5], [0, 1, 5]]], float)
    >>> uv = np.array([[[0, 1], [1, 1], [0, 0]]], float)
    >>> m = MeshPayload.from_triangle_corners(corners, uv, np.zeros(1, int), np.zeros(1, int))
    >>> (triangle_frames(m, np.zeros(3))[0] + 0.0).tolist()
    [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]]
    """
    c, t = payload.triangle_corners(), payload.triangle_uv()
    e1, e2 = c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]
    d1, d2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    det = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    det = np.where(det == 0.0, 1.0, det)
    # e = du * dP/du + dv * dP/dv for both edges, solved for the two derivatives (as quad_frames).
    dpdu = (d2[:, 1, None] * e1 - d1[:, 1, None] * e2) / det[:, None]
    dpdv = (d1[:, 0, None] * e2 - d2[:, 0, None] * e1) / det[:, None]
    normal = unit_rows(np.cross(e1, e2))
    normal[np.einsum("ij,ij->i", normal, viewpoint - c[:, 0]) < 0.0] *= -1.0
    tangent = unit_rows(dpdu - np.einsum("ij,ij->i", dpdu, normal)[:, None] * normal)
    # A triangle without a UV footprint: any tangent in its plane; without an area, the x axis.
    lost = ~(np.linalg.norm(tangent, axis=1) > 0.0)
    if lost.any():
        axis = np.eye(3)[np.argmin(np.abs(normal[lost]), axis=1)]
        tangent[lost] = unit_rows(np.cross(normal[lost], axis))
        flat = ~(np.linalg.norm(normal, axis=1) > 0.0)
        tangent[lost & flat], normal[lost & flat] = (1.0, 0.0, 0.0), (0.0, 0.0, 1.0)
    bitangent = np.cross(normal, tangent)
    bitangent[np.einsum("ij,ij->i", bitangent, -dpdv) < 0.0] *= -1.0
    return np.stack([tangent, bitangent, normal], axis=1)


def vertex_frames(payload: MeshPayload, frames: np.ndarray) -> VertexFrames:
    """Each payload vertex's frame: its triangles' ``frames`` (:func:`triangle_frames`) averaged,
    weighted by their areas (N the unit mean normal, T the mean tangent made orthogonal to it); a
    vertex whose triangles have both handednesses is one frame vertex per handedness, numbered
    in the order of first use.  A mean that cancels (a fold) takes its first triangle's.

    Two triangles of one plane and one page, sharing two vertices, share their frames:

    >>> corners = np.array([[[0, 0, 5], [1, 0, 5], [0, 1, 5]], [[1, 0, 5], [1, 1, 5], [0, 1, 5]]], float)
    >>> uv = np.array([[[0, 1], [1, 1], [0, 0]], [[1, 1], [1, 0], [0, 0]]], float)
    >>> m = MeshPayload.from_triangle_corners(corners, uv, np.zeros(2, int), np.zeros(2, int))
    >>> f = vertex_frames(m, triangle_frames(m, np.zeros(3)))
    >>> f.corner.tolist(), (f.normal[0] + 0.0).tolist(), f.handed.tolist()
    ([[0, 1, 2], [1, 3, 2]], [0.0, 0.0, -1.0], [-1.0, -1.0, -1.0, -1.0])
    """
    t = payload.count
    handed = np.where(np.einsum("ij,ij->i", np.cross(frames[:, 2], frames[:, 0]), frames[:, 1]) < 0.0, -1.0, 1.0)
    key = payload.triangles.reshape(-1) * 2 + np.repeat(handed > 0, 3)
    _, first, group = np.unique(key, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    number = np.empty(first.size, np.int64)
    number[order] = np.arange(first.size)
    group = number[group.reshape(-1)]
    corners = payload.triangle_corners()
    area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    weight = np.repeat(np.maximum(area, 1e-300), 3)  # a triangle without area still has a say
    count = first.size
    normal = np.zeros((count, 3))
    tangent = np.zeros((count, 3))
    np.add.at(normal, group, weight[:, None] * np.repeat(frames[:, 2], 3, axis=0))
    np.add.at(tangent, group, weight[:, None] * np.repeat(frames[:, 0], 3, axis=0))
    first_frame = frames[first[order] // 3]  # the first triangle of each frame vertex
    total = np.zeros(count)
    np.add.at(total, group, weight)
    folded = ~(np.linalg.norm(normal, axis=1) > 0.5 * total)
    normal[folded], tangent[folded] = first_frame[folded, 2], first_frame[folded, 0]
    normal = unit_rows(normal)
    tangent = unit_rows(tangent - np.einsum("ij,ij->i", tangent, normal)[:, None] * normal)
    lost = ~(np.linalg.norm(tangent, axis=1) > 0.0)
    tangent[lost] = first_frame[lost, 0]
    return VertexFrames(group.reshape(t, 3), normal, tangent, handed[first[order] // 3])


OWNER_TEXELS = 1 << 20  # box texels tested per run of triangles (:func:`triangle_owners`)


def triangle_owners(payload: MeshPayload, index: int, h: int, w: int) -> np.ndarray:
    """(h, w) int32 the triangle of ``payload`` on page ``index`` (h x w texels) whose UV footprint
    holds each texel's centre, -1 for none (a centre on an edge shared by two goes to the later).

    >>> m = MeshPayload.from_triangle_corners(np.zeros((2, 3, 3)), np.array([[[0, 0], [1, 0], [0, 1]],
    ...     [[1, 0], [1, 1], [0, 1]]], float), np.zeros(2, int), np.zeros(2, int))  # fmt: skip
    >>> triangle_owners(m, 0, 2, 2).tolist()
    [[0, 1], [1, 1]]
    """
    owner = np.full((h, w), -1, np.int32)
    triangles = np.flatnonzero(payload.page == index)
    if triangles.size == 0:
        return owner
    p = payload.uv[payload.triangles[triangles]] * np.array([w, h], np.float64)  # (t, 3, 2) texels
    lo = np.clip(np.floor(p.min(axis=1) - 0.5).astype(np.int64), 0, [w - 1, h - 1])
    hi = np.clip(np.ceil(p.max(axis=1) - 0.5).astype(np.int64), 0, [w - 1, h - 1])
    size = hi - lo + 1  # (t, 2) columns, rows of each triangle's box
    count = size.prod(axis=1)
    # Triangles in runs of about OWNER_TEXELS box texels, so memory grows with a run, not the page.
    run = np.cumsum(count) // OWNER_TEXELS
    for chosen in np.split(np.arange(triangles.size), np.flatnonzero(np.diff(run)) + 1):
        n = count[chosen]
        which = np.repeat(chosen, n)
        k = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)  # texel within its box
        x, y = lo[which, 0] + k % size[which, 0], lo[which, 1] + k // size[which, 0]
        centre = np.stack([x + 0.5, y + 0.5], axis=1)
        q = p[which]
        area = _cross2(q[:, 1] - q[:, 0], q[:, 2] - q[:, 0])
        sign = np.where(area < 0, -1.0, 1.0)
        inside = np.abs(area) > 0
        for a, b in ((0, 1), (1, 2), (2, 0)):
            edge = sign * _cross2(q[:, b] - q[:, a], centre - q[:, a])
            inside &= edge >= -OWNER_SLACK * np.linalg.norm(q[:, b] - q[:, a], axis=1)
        owner[y[inside], x[inside]] = triangles[which[inside]]
    return owner


def filled_owners(owner: np.ndarray) -> np.ndarray | None:
    """``owner`` (h, w) (:func:`triangle_owners`, or a quad payload's) with every texel that has none
    given its nearest owner's (the texels between tiles or charts: their padding); None when the
    page has no owner at all."""
    if (owner < 0).all():
        return None
    if (owner < 0).any():
        iy, ix = distance_transform_edt(owner < 0, return_distances=False, return_indices=True)
        owner = owner[iy, ix]
    return owner


def texel_frames(payload: MeshPayload, frames: VertexFrames, owner: np.ndarray, rows: slice) -> np.ndarray:
    """(r, w, 3, 3) float64 per texel of the page's ``rows`` the matrix taking a world normal to the
    texel direction a viewer decodes back to it (the inverse of its interpolated [T B N], module
    docstring), in the triangle that holds the texel's centre, the other texels in the nearest such
    triangle's at their clamped barycentric coordinates (``owner``: :func:`filled_owners` of
    :func:`triangle_owners`, (h, w)).  A band of rows at a time, so memory grows with the band,
    not with the page."""
    h, w = owner.shape
    band = owner[rows]
    ys, xs = np.mgrid[rows, 0:w]
    centre = np.stack([(xs + 0.5) / w, (ys + 0.5) / h], axis=-1).reshape(-1, 2)
    p = payload.uv[payload.triangles[band.reshape(-1)]]  # (m, 3, 2)
    d1, d2, q = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], centre - p[:, 0]
    det = _cross2(d1, d2)
    det = np.where(det == 0.0, 1.0, det)
    b1, b2 = _cross2(q, d2) / det, _cross2(d1, q) / det
    b = np.clip(np.stack([1.0 - b1 - b2, b1, b2], axis=1), 0.0, None)
    b /= np.maximum(b.sum(axis=1, keepdims=True), 1e-300)
    corner = frames.corner[band.reshape(-1)]  # (m, 3) frame vertices
    columns = [
        unit_rows(np.einsum("mk,mkc->mc", b, attribute[corner]))
        for attribute in (frames.tangent, frames.bitangent, frames.normal)
    ]
    tbn = np.stack(columns, axis=-1)  # (m, 3, 3) columns T, B, N: decoded = tbn @ m
    singular = ~(np.abs(np.linalg.det(tbn)) > 1e-6)
    tbn[singular] = np.eye(3)
    inverse = np.linalg.inv(tbn)
    # Where interpolation left no frame (opposite vertex frames cancelling): the transpose of the owner's.
    inverse[singular] = np.stack([frames.tangent, frames.bitangent, frames.normal], axis=1)[corner[singular, 0]]
    return inverse.reshape(band.shape[0], w, 3, 3)


def _cross2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The z of the cross products of rows of 2D vectors ``a``, ``b`` (n, 2)."""
    return a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
