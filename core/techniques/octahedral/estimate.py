"""The octahedral impostor's placement estimate: from a part's bounding box alone (no bake), its
memory, exactly, and a bound on its accuracy distance, for the frame-time planner
(:mod:`farfield.core.placement.candidates`; docs/techniques/octahedral.md, "As a placement candidate").

**Memory.** The bake lays its ``grid²`` frames out on pages by
:func:`~farfield.core.techniques.octahedral.frames.pages_layout` before it records anything, so the
bytes of its atlas pages (RGBA8, and as many again for a normal page) are known: the estimate is the
bake's ``texture_bytes``.

**Accuracy distance, bounded.** The bake's distance
(:func:`~farfield.core.techniques.octahedral.accuracy.accuracy_distance`) needs its bounding sphere
``r`` (the farthest vertex from the bounding box's centre), its depth extent ``e`` (the largest
recorded height above a frame's card plane, ``e <= r``) and, with two-sided depth, the part's
longest internal gap (a chord of the sphere, ``<= 2 r``).  From the box alone: ``r`` is at most its
half diagonal ``R`` (same centre), ``e <= R`` and the gap ``<= 2 R``.  The distance solves
``(D - r) a (1 - r²/D²) = delta`` with ``delta`` growing with ``r`` and ``e``; the left side falls
as ``r`` grows, so ``D`` grows with ``r`` and ``delta``: the distance computed with ``R`` for
``r``, ``e`` and half the gap is never less than the bake's.  Tested against bakes
(tests/test_octahedral_placement.py).

An octahedral impostor serves every view beyond that distance from its centre (above the centre's
horizon for a hemisphere), whatever the direction: the planner gives each element one candidate,
the outside-sphere cell of that radius, serving every problem view whose whole region lies in it.
At run time it is one card of two triangles (:class:`OutsideEstimate` ``quads`` 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from farfield.core.errors import ViewCellError
from farfield.core.impostor.impostor import wants_depth, wants_normals
from farfield.core.techniques.base import TEXEL_BYTES
from farfield.core.techniques.octahedral.accuracy import AccuracyDistance, accuracy_distance
from farfield.core.techniques.octahedral.frames import pages_layout
from farfield.core.techniques.octahedral.mapping import grid_angle, opposite_frames
from farfield.core.viewcells import BoxCell, SphereOutsideCell, ViewCell


@lru_cache(maxsize=64)
def _grid(n: int, hemisphere: bool) -> tuple[float, bool]:
    """(the grid's weighted-median angle, whether every frame has an opposite): the same for every part."""
    return grid_angle(n, hemisphere), bool((opposite_frames(n, hemisphere) >= 0).all())


def atlas_bytes(options) -> int:
    """Bytes of the atlas pages an octahedral bake of ``options`` writes (its stats' ``texture_bytes``),
    and as many again for a normal page.

    >>> from farfield.core.techniques.octahedral.technique import OctahedralOptions
    >>> atlas_bytes(OctahedralOptions())  # 13 x 13 frames of 64 texels, 4 padding: one page of 936
    3504384
    """
    _, _, sides = pages_layout(options.grid, options.frame_resolution, options.padding, options.max_page)
    colour = sum(int(s) * int(s) for s in sides) * TEXEL_BYTES
    return colour * (2 if wants_normals(options.channels) else 1)


def distance_bound(options, bounds) -> AccuracyDistance:
    """A bound on the accuracy distance of an octahedral bake of the part in ``bounds`` ((2, 3):
    lo, hi) with ``options``, from the centre of ``bounds`` (module docstring): never less than the
    bake's ``stats["accuracy_distance"]``.

    >>> from farfield.core.techniques.octahedral.technique import OctahedralOptions
    >>> d = distance_bound(OctahedralOptions(resolution=256, grid=13, frame_resolution=32), [[-1, -1, 0], [1, 1, 4]])
    >>> round(d.radius, 4), round(d.distance, 2)
    (2.4495, 323.84)
    """
    b = np.asarray(bounds, dtype=np.float64).reshape(2, 3)
    radius = 0.5 * float(np.linalg.norm(b[1] - b[0]))
    if not (math.isfinite(radius) and radius > 0.0):
        raise ViewCellError(f"an octahedral impostor needs a part of some size, got bounds {b.tolist()}")
    _, two_sided = _grid(options.grid, options.hemisphere)
    depth = wants_depth(options.channels)
    gap = 2.0 * radius if depth and two_sided else None
    return accuracy_distance(radius, radius, options.grid, options.hemisphere, options.frame_resolution,
                             options.resolution, options.fov_deg, depth, gap)  # fmt: skip


@dataclass(frozen=True, slots=True)
class OutsideEstimate:
    """What the planner needs of an impostor serving every view beyond a distance from its part:
    its view cell (:class:`~farfield.core.viewcells.SphereOutsideCell`), memory (bytes), quads drawn,
    and the layers and texels per layer it is reported with (frames and texels per frame)."""

    cell: SphereOutsideCell
    memory_bytes: float
    quads: float
    layers: float
    texels: float

    def serves(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """(k,) bool: which boxes ``lo``..``hi`` ((k, 3) each; the problem views' regions) lie wholly
        in the cell: their nearest point at least its radius from the centre (and above the
        centre's horizon for a hemisphere).

        >>> e = OutsideEstimate(SphereOutsideCell([0.0, 0.0, 0.0], 10.0), 1.0, 1.0, 1.0, 1.0)
        >>> e.serves(np.array([[10.0, 0, 0], [9.0, 0, 0]]), np.array([[11.0, 1, 1], [11.0, 1, 1]])).tolist()
        [True, False]
        """
        lo, hi = np.asarray(lo, dtype=np.float64).reshape(-1, 3), np.asarray(hi, dtype=np.float64).reshape(-1, 3)
        c = self.cell.centre
        gap = np.maximum(0.0, np.maximum(lo - c, c - hi))
        ok = np.sqrt(np.sum(gap * gap, axis=1)) >= self.cell.radius
        if self.cell.hemisphere:
            ok &= lo[:, 2] >= c[2]
        return ok


def outside_estimate(options, bounds) -> OutsideEstimate:
    """The octahedral candidate of the part in ``bounds`` (module docstring): the outside-sphere
    cell of the distance bound around the bounds' centre, the atlas's bytes, one card."""
    b = np.asarray(bounds, dtype=np.float64).reshape(2, 3)
    bound = distance_bound(options, b)
    cell = SphereOutsideCell(0.5 * (b[0] + b[1]), bound.distance, options.hemisphere)
    return OutsideEstimate(cell, float(atlas_bytes(options)), 1.0, float(options.grid**2),
                           float(options.frame_resolution**2))  # fmt: skip


def estimate_octahedral(cell: ViewCell, options, bounds) -> tuple[float, float]:
    """``Technique.estimate``: (frames, texels per frame) of an octahedral impostor of the part in
    ``bounds`` for ``cell``; raises ViewCellError where some viewpoint of ``cell`` comes nearer the
    part's centre than the distance bound (:func:`distance_bound`), or lies below its horizon for a
    hemisphere.

    >>> from farfield.core.techniques.octahedral.technique import OctahedralOptions
    >>> part, o = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]), OctahedralOptions(resolution=64)
    >>> estimate_octahedral(BoxCell([60.0, -1, -1], [70.0, 1, 1]), o, part)
    (169.0, 4096.0)
    >>> estimate_octahedral(BoxCell([5.0, -1, -1], [6.0, 1, 1]), o, part)
    Traceback (most recent call last):
    ...
    farfield.core.errors.ViewCellError: the box view cell comes within 5 of the part's centre; its octahedral impostor is within one pixel beyond 52.6847 (a bound from its bounds)
    """
    b = np.asarray(bounds, dtype=np.float64).reshape(2, 3)
    centre = 0.5 * (b[0] + b[1])
    distance = distance_bound(options, b).distance
    nearest = float(cell.distance_to_box(np.stack([centre, centre])))
    if not nearest >= distance:
        raise ViewCellError(
            f"the {cell.kind} view cell comes within {nearest:.6g} of the part's centre; its octahedral impostor is "
            f"within one pixel beyond {distance:.6g} (a bound from its bounds)"
        )
    if options.hemisphere:
        above = (isinstance(cell, SphereOutsideCell) and cell.hemisphere and cell.centre[2] >= centre[2]) or (
            isinstance(cell, BoxCell) and float(cell.lo[2]) >= centre[2]
        )
        if not above:
            raise ViewCellError(
                f"a hemisphere octahedral impostor is seen from above its centre only, not from a {cell.kind} cell"
            )
    return float(options.grid**2), float(options.frame_resolution**2)
