"""(v, 3) float64 shading normals as the loaders read them: moved by a node transform, and repaired.

Every loader that reads a format's shading normals (glTF ``NORMAL``, OBJ ``vn``, PLY ``nx ny nz``)
passes them through here, so that each format's normals reach
:attr:`farfield.core.scene.SceneObject.normals` by the same two rules:

* :func:`normal_matrix`: a normal moves with the inverse transpose of the linear part of the
  transform that moves the positions (glTF 2.0 §3.5.3, "Transformations": a node's matrix applies to
  the mesh; normals need the inverse transpose where the scale is not uniform).  A mirroring
  transform (negative determinant) keeps the normal on the geometric front, which is the front of
  the loaders' reversed counter-clockwise winding.
* :func:`repair_normals`: real files hold zero or non-finite normals (degenerate triangles at
  export, NaN from a normalised zero); each is replaced by the area-weighted mean of the face normals
  of the triangles that use the vertex, and the object gets one warning saying how many.
"""

from __future__ import annotations

import numpy as np

_UP = np.array([0.0, 0.0, 1.0])  # the normal of last resort: a vertex without any non-degenerate triangle


def normal_matrix(linear: np.ndarray) -> np.ndarray:
    """(3, 3) float64 matrix that moves normals as ``linear`` moves positions: the inverse transpose,
    up to a positive factor (normals are renormalised afterwards).

    It is computed as the cofactor matrix (columns ``b x c``, ``c x a``, ``a x b`` of ``linear``'s
    columns ``a, b, c``), which equals ``det(linear) * inv(linear).T``, times the sign of the
    determinant: no inverse is taken, so a singular transform (a zero scale) still gives the normal
    of the plane it flattens the mesh into rather than a ``LinAlgError``.

    Parameters
    ----------
    linear : (3, 3) float64
        The linear part of a column-vector transform (positions move as ``linear @ p``).

    Returns
    -------
    (3, 3) float64
        ``n' = out @ n``; for row arrays ``normals @ out.T``.

    Examples
    --------
    >>> normal_matrix(np.diag([2.0, 1.0, 1.0])).tolist()  # a stretch along x tilts normals towards y, z
    [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 2.0]]
    >>> (normal_matrix(np.diag([-1.0, 1.0, 1.0])) @ [0.0, 0.0, 1.0]).tolist()  # a mirror in x keeps +z
    [0.0, 0.0, 1.0]
    """
    return normal_matrices(np.asarray(linear, dtype=np.float64)[None])[0]


def normal_matrices(linear: np.ndarray) -> np.ndarray:
    """(n, 3, 3) :func:`normal_matrix` of each of ``linear`` (n, 3, 3) at once (an instanced mesh's
    transforms): the cofactors written out, ``b x c = (b1 c2 - b2 c1, b2 c0 - b0 c2, b0 c1 - b1 c0)``.

    >>> (normal_matrices(np.stack([np.eye(3), np.diag([-1.0, 2.0, 1.0])]))[1] + 0.0).tolist()  # a mirror in x
    [[-2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 2.0]]
    """
    m = np.asarray(linear, dtype=np.float64)
    a, b, c = m[..., :, 0], m[..., :, 1], m[..., :, 2]  # the columns, (n, 3) each

    def cross(p: np.ndarray, q: np.ndarray) -> np.ndarray:
        return np.stack(
            [
                p[:, 1] * q[:, 2] - p[:, 2] * q[:, 1],
                p[:, 2] * q[:, 0] - p[:, 0] * q[:, 2],
                p[:, 0] * q[:, 1] - p[:, 1] * q[:, 0],
            ],
            axis=1,
        )

    cofactor = np.stack([cross(b, c), cross(c, a), cross(a, b)], axis=2)  # columns b x c, c x a, a x b
    flip = np.linalg.det(m) < 0.0
    cofactor[flip] *= -1.0
    return cofactor


def transform_normals(normals: np.ndarray, linear: np.ndarray) -> np.ndarray:
    """(v, 3) float64 ``normals`` moved by the column-vector transform ``linear`` (3, 3), not renormalised
    (a zero stays zero, for :func:`repair_normals` to find)."""
    return np.asarray(normals, dtype=np.float64) @ normal_matrix(linear).T


def _bad(normals: np.ndarray) -> np.ndarray:
    """(v,) bool: the zero or non-finite rows of ``normals``."""
    with np.errstate(invalid="ignore", over="ignore"):
        length = np.sqrt(np.einsum("ij,ij->i", normals, normals))
    return ~(np.isfinite(length) & (length > 0.0))


def repair_normals(
    name: str, vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray
) -> tuple[np.ndarray, str | None]:
    """``normals`` with each zero or non-finite one replaced, and the one warning that says how many.

    A replaced normal is the sum of the (unnormalised) face normals ``(b - a) x (c - a)`` of the
    triangles that use the vertex: twice their areas times their unit normals, so the mean weighted by
    area, in the direction the counter-clockwise winding makes the front.  Where that sum is zero too
    (no triangle uses the vertex, they are all degenerate, or they cancel) the face normal of the first
    non-degenerate triangle using it is taken, else +z.  Finite non-zero normals are kept as they are
    (not renormalised: :class:`~farfield.core.scene.SceneObject` does that).

    Parameters
    ----------
    name : str
        The object's name, for the warning.
    vertices : (v, 3) float64
        Positions in the frame of ``normals`` (world space, after the node transform).
    faces : (f, 3) int64
        Counter-clockwise front faces (a mirrored node's already reversed), indices into ``vertices``.
    normals : (v, 3) float64
        As read; may hold zero, NaN or infinite rows.

    Returns
    -------
    normals : (v, 3) float64
        A new array without zero or non-finite rows.
    warning : str or None
        ``"object 'x': 2 of 9 shading normals were zero or not finite; ..."``, None when none was.

    Examples
    --------
    >>> v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5]])
    >>> fixed, warning = repair_normals("t", v, np.array([[0, 1, 2]]), np.array([[0.0, 0, 0], [0, 0, 1], [np.nan, 0, 0], [0, 0, 0]]))
    >>> fixed.tolist()
    [[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]]
    >>> warning
    "object 't': 3 of 4 shading normals were zero or not finite; replaced by the area-weighted mean of their triangles' face normals"
    """
    normals = np.array(normals, dtype=np.float64)
    bad = _bad(normals)
    count = int(bad.sum())
    if count == 0:
        return normals, None
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    corners = vertices[faces]  # (f, 3, 3)
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])  # (f, 3), |.| = 2 area
    sums = np.zeros_like(normals)
    for k in range(3):
        np.add.at(sums, faces[:, k], cross)
    normals[bad] = sums[bad]
    still = bad & _bad(normals)
    if still.any():
        usable = np.flatnonzero(~_bad(cross))
        first = np.full(len(normals), len(faces), dtype=np.int64)  # len(faces): no usable triangle
        for k in range(3):
            np.minimum.at(first, faces[usable, k], usable)
        found = still & (first < len(faces))
        normals[found] = cross[first[found]]
        normals[still & ~found] = _UP
    warning = (
        f"object {name!r}: {count} of {len(normals)} shading normals were zero or not finite; "
        "replaced by the area-weighted mean of their triangles' face normals"
    )
    return normals, warning


def uv_tangents(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None, uv: np.ndarray) -> np.ndarray:
    """(v, 4) float64 tangents for a normal map over ``uv`` (v, 2) (origin bottom-left, v up) where
    a file has none: per vertex, the area-weighted sum of its triangles' dP/du, made orthogonal to
    the vertex normal (``normals``, or the area-weighted face normal where None), and the
    handedness w = +-1 that points ``cross(normal, tangent) * w`` along its triangles' dP/dv (up
    the image, glTF 2.0 §3.9.3's +Y).  A vertex whose triangles give no direction (no uv extent)
    gets any unit vector orthogonal to its normal.

    The glTF specification asks for MikkTSpace tangents when ``TANGENT`` is missing; this is the
    per-vertex average MikkTSpace reduces to where charts are not split by angle, and it agrees
    with the per-pixel frame three.js derives from screen-space derivatives on smooth meshes
    (``tests/test_normal_maps.py``).

    >>> quad = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]); faces = np.array([[0, 1, 2], [0, 2, 3]])
    >>> uv_tangents(quad, faces, None, quad[:, :2])[0].tolist()
    [1.0, 0.0, 0.0, 1.0]
    >>> uv_tangents(quad, faces, None, np.column_stack([quad[:, 0], -quad[:, 1]]))[0].tolist()  # v flipped
    [1.0, 0.0, 0.0, -1.0]
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(uv, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    e1, e2 = v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]
    d1, d2 = t[f[:, 1]] - t[f[:, 0]], t[f[:, 2]] - t[f[:, 0]]
    det = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    sign = np.where(det < 0.0, -1.0, 1.0)
    # dP/du and dP/dv scaled by det (and its sign), so each triangle weighs by its area in space.
    dpdu = (d2[:, 1, None] * e1 - d1[:, 1, None] * e2) * sign[:, None]
    dpdv = (d1[:, 0, None] * e2 - d2[:, 0, None] * e1) * sign[:, None]
    dpdu[det == 0.0] = 0.0
    dpdv[det == 0.0] = 0.0
    count = v.shape[0]
    tangent, bitangent = np.zeros((count, 3)), np.zeros((count, 3))
    for corner in range(3):
        np.add.at(tangent, f[:, corner], dpdu)
        np.add.at(bitangent, f[:, corner], dpdv)
    if normals is None:
        face = np.cross(e1, e2)
        normal = np.zeros((count, 3))
        for corner in range(3):
            np.add.at(normal, f[:, corner], face)
    else:
        normal = np.asarray(normals, dtype=np.float64).copy()
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.divide(normal, length, out=np.tile([0.0, 0.0, 1.0], (count, 1)), where=length > 0.0)
    tangent -= np.einsum("ij,ij->i", tangent, normal)[:, None] * normal
    length = np.linalg.norm(tangent, axis=1, keepdims=True)
    # Where no triangle gives a direction: the world axis least along the normal, made orthogonal.
    axis = np.eye(3)[np.argmin(np.abs(normal), axis=1)]
    fallback = axis - np.einsum("ij,ij->i", axis, normal)[:, None] * normal
    fallback /= np.linalg.norm(fallback, axis=1, keepdims=True)
    scale = np.maximum(np.abs(tangent).max(axis=1, keepdims=True), 1e-300)
    usable = length > 1e-12 * scale
    tangent = np.where(usable, tangent / np.where(usable, length, 1.0), fallback)
    w = np.where(np.einsum("ij,ij->i", np.cross(normal, tangent), bitangent) < 0.0, -1.0, 1.0)
    return np.column_stack([tangent, w])


def transform_tangents(tangents: np.ndarray, linear: np.ndarray) -> np.ndarray:
    """(v, 4) float64 glTF ``TANGENT`` moved by the column-vector transform ``linear`` (3, 3):
    the direction as positions move (renormalised; a zero one becomes +x, never used by a
    degenerate triangle), ``w`` negated by a mirroring transform, whose normals (inverse transpose)
    keep their side while ``cross(normal, tangent)`` turns (glTF 2.0 §3.7.2.1).

    >>> transform_tangents(np.array([[1.0, 0, 0, 1]]), np.diag([-2.0, 1.0, 1.0])).tolist()
    [[-1.0, 0.0, 0.0, -1.0]]
    """
    tangents = np.asarray(tangents, dtype=np.float64)
    linear = np.asarray(linear, dtype=np.float64)
    direction = tangents[:, :3] @ linear.T
    length = np.linalg.norm(direction, axis=1, keepdims=True)
    direction = np.divide(direction, length, out=np.tile([1.0, 0.0, 0.0], (len(direction), 1)), where=length > 0.0)
    w = np.where(tangents[:, 3] < 0.0, -1.0, 1.0) * (-1.0 if np.linalg.det(linear) < 0.0 else 1.0)
    return np.column_stack([direction, w])
