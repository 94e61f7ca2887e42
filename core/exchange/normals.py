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
    a, b, c = np.asarray(linear, dtype=np.float64).T
    cofactor = np.column_stack([np.cross(b, c), np.cross(c, a), np.cross(a, b)])
    return -cofactor if np.linalg.det(linear) < 0.0 else cofactor


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
