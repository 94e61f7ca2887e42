"""An octahedral impostor of one instance from its prototype's: the prototype baked once in its
mesh's own space, then moved by each instance's matrix (docs/techniques/octahedral.md, "Instancing").

An octahedral impostor is a set of orthographic frames of the part along directions ``d_k`` with
image axes ``right_k, up_k`` over its bounding sphere ``(c, r)``, for viewpoints beyond a sphere
around ``c``.  Under a similarity ``x -> s R x + t`` (``R`` a rotation, ``s > 0``) an orthographic
frame of the prototype along ``d`` is, texel for texel, the frame of the instance along ``R d``
with axes ``R right, R up`` over the sphere ``(s R c + t, s r)``: orthographic projection commutes
with rotation, translation and uniform scale, and depth scales by ``s`` (the normal page's heights
are fractions of the radius, so they stay).  So the instance's impostor is the prototype's with its
frame axes rotated, its sphere moved and scaled, and its lengths (depth extent, accuracy distance)
scaled; its pixels are the prototype's.  The view cell moves likewise: an instance's cell outside
a sphere is the prototype's cell outside the sphere moved back by the inverse matrix.

A matrix that shears, scales unevenly or mirrors gives frames that are not the prototype's; so does
a hemisphere cell (or option) whose instance turns the prototype's up axis away from world +z.
Those instances are baked as objects of their own (:func:`local_cell` answers None).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from farfield.core.impostor.impostor import Impostor
from farfield.core.viewcells import SphereOutsideCell, ViewCell, viewcell_from_dict

# Relative tolerance of a similarity: a matrix read from float32 glTF accessors is a rotation to ~1e-7.
SIMILARITY_TOL = 1e-5
# Lengths of the stats and of the accuracy record that scale with the instance.
SCALED_STATS = ("radius", "depth_extent", "accuracy_distance")
SCALED_ACCURACY = ("distance", "radius", "texel", "extent", "displacement", "gap")


def similarity(matrix) -> tuple[float, np.ndarray] | None:
    """(s, R) of a (4, 4) affine ``matrix`` whose linear part is ``s R`` (``R`` a proper rotation,
    ``s > 0``), else None.

    >>> s, r = similarity(np.diag([2.0, 2.0, 2.0, 1.0]))
    >>> s, r.tolist()[0], similarity(np.diag([1.0, 2.0, 1.0, 1.0]))
    (2.0, [1.0, 0.0, 0.0], None)
    """
    linear = np.asarray(matrix, dtype=np.float64)[:3, :3]
    det = float(np.linalg.det(linear))
    if not det > 0.0:
        return None
    s = float(np.linalg.norm(linear, axis=0).mean())  # the columns' common length
    rotation = linear / s
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=SIMILARITY_TOL):
        return None
    return s, rotation


def local_cell(cell: ViewCell, matrix, hemisphere: bool = False) -> SphereOutsideCell | None:
    """The prototype's view cell whose impostor, moved by ``matrix``, serves ``cell`` of an
    instance: ``cell`` (outside a sphere) moved back by the inverse matrix; None where no such
    cell is the prototype's (not an outside-sphere cell, not a similarity, or a hemisphere
    cell or bake (``hemisphere``) whose instance tilts the up axis).

    >>> m = np.eye(4); m[:3, 3] = (10.0, 0.0, 0.0); m[:3, :3] *= 2.0
    >>> c = local_cell(SphereOutsideCell([10.0, 0.0, 0.0], 6.0), m)
    >>> c.centre.tolist(), c.radius
    ([0.0, 0.0, 0.0], 3.0)
    """
    found = similarity(matrix)
    if found is None or not isinstance(cell, SphereOutsideCell):
        return None
    s, rotation = found
    if (hemisphere or cell.hemisphere) and not np.allclose(rotation[:, 2], (0.0, 0.0, 1.0), atol=SIMILARITY_TOL):
        return None
    matrix = np.asarray(matrix, dtype=np.float64)
    centre = rotation.T @ (cell.centre - matrix[:3, 3]) / s
    # Rounded to 10 digits of the radius: instances of equal cells give the very same local cell
    # (the key their shared bake is found by), not cells apart by rounding.
    radius = float(f"{cell.radius / s:.10g}")
    quantum = 1e-10 * radius
    return SphereOutsideCell(np.round(centre / quantum) * quantum + 0.0, radius, hemisphere=cell.hemisphere)


def _moved_cell(viewcell: dict, matrix: np.ndarray, s: float, rotation: np.ndarray) -> dict:
    cell = viewcell_from_dict(viewcell)
    if not isinstance(cell, SphereOutsideCell):
        raise ValueError(f"an octahedral impostor for a {cell.kind} view cell is not moved by instancing")
    centre = s * rotation @ cell.centre + matrix[:3, 3]
    return SphereOutsideCell(centre, s * cell.radius, hemisphere=cell.hemisphere).to_dict()


def moved_impostor(
    impostor: Impostor, matrix, objects: list[str] | None = None, scene_hash: str | None = None
) -> Impostor:
    """The octahedral ``impostor`` of a prototype (baked in its local space) moved by an instance's
    ``matrix`` (4, 4): frame axes rotated, sphere, view cell and reference viewpoint moved, lengths
    scaled; pages shared, not copied.  ``objects`` and ``scene_hash`` name the instance's part in
    the parameters (the prototype's are kept under ``prototype_objects``).

    Raises
    ------
    ValueError
        ``matrix`` is not a similarity (:func:`similarity`).
    """
    found = similarity(matrix)
    if found is None:
        raise ValueError("an octahedral impostor moves only by rotation, translation and uniform scale")
    s, rotation = found
    m = np.asarray(matrix, dtype=np.float64)
    p = impostor.payload
    axes = p.axes @ rotation.T  # each row (right, up, direction) rotated
    sphere = np.concatenate([s * rotation @ p.centre + m[:3, 3], [s * p.radius]])
    stats = dict(impostor.stats)
    for key in SCALED_STATS:
        if stats.get(key) is not None:
            stats[key] = s * stats[key]
    if isinstance(stats.get("accuracy"), dict):
        stats["accuracy"] = {
            k: s * v if k in SCALED_ACCURACY and v is not None else v for k, v in stats["accuracy"].items()
        }
    parameters = {k: v for k, v in impostor.parameters.items() if k != "instances"}  # one instance now
    if objects is not None:
        parameters["prototype_objects"] = parameters.get("objects")
        parameters["objects"] = list(objects)
    if scene_hash is not None:
        parameters["scene_hash"] = scene_hash
    parameters["instance_matrix"] = m.reshape(-1).tolist()
    return replace(
        impostor,
        viewcell=_moved_cell(impostor.viewcell, m, s, rotation),
        reference_viewpoint=s * rotation @ np.asarray(impostor.reference_viewpoint, dtype=np.float64) + m[:3, 3],
        payload=replace(p, axes=axes, sphere=sphere),
        stats=stats,
        parameters=parameters,
    )


def grid_rotation(payload) -> np.ndarray | None:
    """(3, 3) the rotation ``R`` that carries the octahedral grid's own frame directions onto the
    payload's (``axes[:, 2] = R d_k``: a moved instance's, :func:`moved_impostor`), or None where
    they are the grid's own: a runtime maps a world view direction ``v`` to the grid by ``R^T v``.

    >>> from farfield.core.techniques.octahedral.payload import OctahedralPayload
    >>> from farfield.core.techniques.octahedral.frames import frame_axes
    >>> from farfield.core.techniques.octahedral.mapping import frame_directions
    >>> p = OctahedralPayload(frame_axes(frame_directions(3)), np.zeros((9, 2), np.int64), np.zeros(9, np.int64),
    ...                       np.array([0, 0, 0, 1.0]), np.array([3, 8, 0, 0, 0]))
    >>> grid_rotation(p) is None, grid_rotation(replace(p, axes=p.axes @ np.diag([-1.0, -1.0, 1.0]).T)).round(6).tolist()[0]
    (True, [-1.0, 0.0, 0.0])
    """
    from farfield.core.techniques.octahedral.mapping import frame_directions

    if not payload.count:
        return None
    own = frame_directions(payload.n, payload.hemisphere)
    found = payload.axes[:, 2]
    if np.allclose(found, own, atol=1e-9):
        return None
    u, _, vt = np.linalg.svd(own.T @ found)
    fix = np.diag([1.0, 1.0, np.sign(np.linalg.det(vt.T @ u.T))])
    return vt.T @ fix @ u.T


def _local_cell(cell: ViewCell, matrix, options) -> SphereOutsideCell | None:
    return local_cell(cell, matrix, bool(getattr(options, "hemisphere", False)))


def instancing():
    """The technique's :class:`~farfield.core.techniques.base.Instancing`: :func:`local_cell` and
    :func:`moved_impostor`."""
    from farfield.core.techniques.base import Instancing

    return Instancing(local_cell=_local_cell, moved=moved_impostor)
