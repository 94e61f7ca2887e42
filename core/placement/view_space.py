"""The problem view space (seed 000 §5.5): where the views are too slow, as conservative problem views (CPVs).

The 3D view space (a box) is split in halves along its longest side down to a minimum region size
(§5.5.1); for each region the view directions are split into the six faces of a cube, each face a
quadtree of *view-direction intervals* (VDIs) down to a minimum angle (§5.5.2, Fig. 5.3).  A VDI's
rendering time is estimated over its *enclosing frustum* (Fig. 5.2): every element that some view
from the region, with a direction in the VDI, could see.  A VDI within ``t_max`` is solved and
dropped; one over it is split, down to the minimum angle; a region is split only while some of
its VDIs are still over.  Leaves over ``t_max`` at the minimum region size and angle are the CPVs.
A child region tests only its parent's problem VDIs and the elements their frusta met: its views
are a subset of the parent's, so anything solved or unseen there stays so.

**Enclosing frusta, conservatively.**  The frame is square with field of view ``fov`` and any roll
(rotations about the view vector are not part of the view space, §5.3, so every roll is allowed):
every ray of a view lies within ``atan(sqrt(2) tan(fov / 2))`` of its view direction, and every
view direction of a VDI within the VDI's *cone* (axis through its centre, half-angle to its
farthest corner).  A point ``p`` can be seen from the region ``R`` when some ``p - e``, ``e`` in
``R``, lies in the cone widened by the frame's half-diagonal; for an element box ``B`` the set of
``p - e`` is the box ``B - R``, tested first through its bounding sphere (``angle to centre -
angular radius <= half-angle``: cheap, loose), then, for the pairs the sphere lets through, exactly
(:mod:`farfield.core.placement.cone_box`: the cone's axis ray hits the box, or one of its twelve
edges comes within the half-angle).  The sphere of ``B - R`` is loose where ``R`` is flat or large
(over a 37.5 x 1 x 37.5 m street-level region the sphere of ``B - R`` is at least 26 m in radius,
however low ``B``, so intervals looking up see the ground); the exact test keeps 4-18 % fewer elements per CPV on the benchmark cities and, over the
same cone, is as tight as a union of sub-boxes of ``R`` can be (``B - R`` is the union of their
``B - R_i``).  Each step only grows the set, so an element a view can see is never missed (tested
by sampling views in ``tests/test_placement.py``, with elements at the frame corner of views at
the cone's edge); the frustum has no far plane, and no occlusion culling is applied (the setting
of Table 5.1 test 16).

**Visibility hook.**  ``visible(region_lo, region_hi, element_indices) -> element_indices`` may be
given to :func:`problem_view_space`: a *conservative from-region* visibility step (§5.5.1,
[Wonk00]) that removes elements hidden from the whole region before the VDI estimate.  The planner's
``visibility`` setting plugs in :class:`farfield.core.visibility.pvs.RegionVisibility`, sampled
from points with id cube maps: not conservative (its measured false-invisible rate is in
docs/placement/visibility.md), so a problem view it hides may still be slow; off by default.

**Pixels.**  An element's covered pixels are estimated as ``f²`` times a bound of its solid angle
from any point of the region: the smaller of its bounding sphere's disc seen from the region's
nearest point and its box's faces (:func:`box_solid_angle_bound`: at most one face per axis faces
a point, each at most ``area / distance²``; tighter for elongated boxes, looser for cubes), at
most a frame.  Like the disc before it, this counts the frame centre's pixels per steradian: near
the frame's corner a steradian covers up to ``1 / cos³`` of the half-diagonal more (1.56x at 45°),
which the bounds' slack and the cap absorb (the test weights pixels by ``cos³``).  Summed over a frustum without occlusion culling, these
discs count every nearby element as a whole frame; the estimate therefore caps a view's pixels at
``depth_complexity`` frames (:data:`DEFAULT_DEPTH_COMPLEXITY`, 1), scaling its elements' pixels
alike; ``inf`` gives the strict sum.  One frame because the cost model's per-pixel ``c`` is
fitted on *covered* pixels (:mod:`farfield.core.placement.calibration` counts a view's non-empty
pixels, at most a frame; the overdraw of its views is in the fit), so ``c`` times a frame bounds
the term for any view, and a disc sum bounds a view's covered pixels from above.  The earlier cap
of 4 frames counted overdraw a second time: along the walks of ``benchmarks/bench_estimate_split.py``
(128 px, llvmpipe) the discs summed to 1.5 .. 4 frames at the median where 0.1 .. 1 frame was covered,
and the model over exactly what a frame drew was 1.6 .. 2.3x the measured frame with the discs
capped at 4 frames, 1.0 .. 1.2x with the covered pixels (docs/placement/visibility.md).

**Unsolvable.**  An element whose hierarchy leaf meets a region can never be replaced there (no
impostor may be built for a view cell that meets its part).  Where those elements alone exceed
``t_max`` in a CPV, no placement can solve it (§5.5.1, §5.9): the CPV is kept and reported as
unsolvable, with the elements to blame.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from numba import njit

from farfield.core.cube_faces import FACES
from farfield.core.placement.cone_box import refine_cone_box
from farfield.core.placement.cost_model import CostModel
from farfield.core.placement.hierarchy import Elements, Hierarchy, PlacementError

FACE_NAMES = tuple(FACES)
# A view's estimated pixels are at most this many frames (see **Pixels** above).
DEFAULT_DEPTH_COMPLEXITY = 1.0
MAX_REGIONS = 1e6  # smallest regions a view space may be cut into (a guard against a mistyped CPV size)
# Deepest VDI quadtree level: 6 x 4^6 = 24,576 intervals of 1.40625° per region at most.  Without it a
# mistyped angle (1e-9°: level 37) makes the subdivision of one region outgrow any memory; a frame of
# 45° at 128 px is 0.35° a pixel, and the thesis works at 11.25° and coarser.
MAX_VDI_LEVEL = 6
MIN_VDI_DEG = 90.0 / 2**MAX_VDI_LEVEL
Visibility = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


def face_frame(face: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(normal, u, v): a cube face's outward normal and the two axes its tangent coordinates run along."""
    axis, sign = FACES[FACE_NAMES[face]]
    normal, u, v = np.zeros(3), np.zeros(3), np.zeros(3)
    normal[axis] = sign
    u[(axis + 1) % 3] = 1.0
    v[(axis + 2) % 3] = 1.0
    return normal, u, v


def frame_half_diagonal(fov: float) -> float:
    """Largest angle between a square frame's view direction and any of its rays: ``atan(sqrt(2) tan(fov/2))``.

    >>> round(math.degrees(frame_half_diagonal(math.radians(90))), 4)
    54.7356
    """
    return math.atan(math.sqrt(2.0) * math.tan(0.5 * fov))


def level_for_angle(min_angle_deg: float) -> int:
    """Quadtree level whose VDIs span about ``min_angle_deg`` at most (a face spans 90°; the
    gnomonic cells are up to ~25 % wider near a face's centre, the distortion §5.5.2 accepts).

    >>> level_for_angle(11.25), level_for_angle(90), level_for_angle(10), level_for_angle(MIN_VDI_DEG)
    (3, 0, 4, 6)
    """
    if not (math.isfinite(min_angle_deg) and MIN_VDI_DEG <= min_angle_deg <= 90.0):
        raise PlacementError(
            f"the minimum view-direction interval must lie in [{MIN_VDI_DEG:g}, 90] degrees, got {min_angle_deg!r}"
        )
    return max(0, math.ceil(math.log2(90.0 / min_angle_deg) - 1e-9))


@dataclass(frozen=True, slots=True)
class VDI:
    """A view-direction interval: cell ``(i, j)`` of level ``level`` of cube face ``face``'s quadtree.

    Its directions are ``normal + x u + y v`` for ``x`` in ``[-1 + 2 i / 2^level, ... + 2 / 2^level]``
    and likewise ``y`` with ``j`` (see :func:`face_frame`).
    """

    face: int
    level: int
    i: int
    j: int

    def ranges(self) -> tuple[float, float, float, float]:
        step = 2.0 / (1 << self.level)
        return -1.0 + self.i * step, -1.0 + (self.i + 1) * step, -1.0 + self.j * step, -1.0 + (self.j + 1) * step

    def directions(self, x, y) -> np.ndarray:
        """(k, 3) unit directions at tangent coordinates ``x``, ``y`` (k,)."""
        normal, u, v = face_frame(self.face)
        d = (
            normal[None, :]
            + np.asarray(x, dtype=np.float64)[:, None] * u
            + np.asarray(y, dtype=np.float64)[:, None] * v
        )
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def cone(self) -> tuple[np.ndarray, float]:
        """(axis (3,), half-angle): the smallest cone about the VDI's centre direction holding all of it."""
        axis, half = _cone(self)  # every region asks again for the same few hundred intervals
        return axis.copy(), half

    def _cone(self) -> tuple[np.ndarray, float]:
        x0, x1, y0, y1 = self.ranges()
        axis = self.directions([0.5 * (x0 + x1)], [0.5 * (y0 + y1)])[0]
        corners = self.directions([x0, x1, x0, x1], [y0, y0, y1, y1])
        return axis, float(np.max(np.arccos(np.clip(corners @ axis, -1.0, 1.0))))

    def contains(self, directions) -> np.ndarray:
        """(k,) bool: which unit ``directions`` (k, 3) fall in this VDI (faces ties go to every face)."""
        d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
        normal, u, v = face_frame(self.face)
        along = d @ normal
        with np.errstate(divide="ignore", invalid="ignore"):
            x, y = (d @ u) / along, (d @ v) / along
        x0, x1, y0, y1 = self.ranges()
        return (along > 0.0) & (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)

    def children(self) -> list[VDI]:
        return [VDI(self.face, self.level + 1, 2 * self.i + a, 2 * self.j + b) for b in (0, 1) for a in (0, 1)]


@lru_cache(maxsize=1 << 16)
def _cone(vdi: VDI) -> tuple[np.ndarray, float]:
    return vdi._cone()


def box_gap(lo_a: np.ndarray, hi_a: np.ndarray, lo_b, hi_b) -> np.ndarray:
    """(k,) distances between boxes ``lo_a``/``hi_a`` (k, 3) and one box ``lo_b``/``hi_b`` (3,); 0 where they meet."""
    gap = np.maximum(0.0, np.maximum(lo_a - hi_b, lo_b - hi_a))
    return np.sqrt(np.sum(gap * gap, axis=1))


@dataclass(frozen=True, slots=True, eq=False)
class RegionSight:
    """How a region sees each of some elements: the box ``element - region`` (``d_lo``/``d_hi``), its
    bounding sphere as a direction (``unit``) and angular radius (``cos``/``sin``), and whether it
    holds the origin."""

    unit: np.ndarray  # (k, 3)
    cos_r: np.ndarray  # (k,)
    sin_r: np.ndarray  # (k,)
    always: np.ndarray  # (k,) bool: the element meets the region, or its sphere holds the region's origin
    d_lo: np.ndarray  # (k, 3) the box element - region
    d_hi: np.ndarray  # (k, 3)

    @classmethod
    def of(cls, lo: np.ndarray, hi: np.ndarray, region_lo, region_hi) -> RegionSight:
        d_lo, d_hi = lo - region_hi, hi - region_lo
        centre = 0.5 * (d_lo + d_hi)
        radius = 0.5 * np.linalg.norm(d_hi - d_lo, axis=1)
        dist = np.linalg.norm(centre, axis=1)
        always = (radius >= dist) | np.all((d_lo <= 0.0) & (d_hi >= 0.0), axis=1)
        safe = np.where(dist > 0.0, dist, 1.0)
        sin_r = np.where(always, 1.0, np.minimum(radius / safe, 1.0))
        return cls(centre / safe[:, None], np.sqrt(1.0 - sin_r * sin_r), sin_r, always, d_lo, d_hi)

    def seen_by_sphere(self, axes: np.ndarray, half_angles: np.ndarray) -> np.ndarray:
        """(v, k) bool: which elements each cone (axis (v, 3), half-angle (v,)) may see, by the
        bounding sphere of ``element - region`` (looser than :meth:`seen`)."""
        cos_d = axes @ self.unit.T  # (v, k) cosine of the angle to the sphere's centre
        h = np.minimum(half_angles, math.pi)[:, None]
        # angle - r <= h  <=>  cos(angle) >= cos(h + r) when h + r < pi (else always true)
        limit = np.cos(h) * self.cos_r[None, :] - np.sin(h) * self.sin_r[None, :]
        wide = (h + np.arcsin(self.sin_r)[None, :]) >= math.pi
        return (cos_d >= limit) | wide | self.always[None, :]

    def seen(self, axes: np.ndarray, half_angles: np.ndarray) -> np.ndarray:
        """(v, k) bool: which elements each cone may see: the sphere's pairs, refined by the exact
        cone-against-box test of ``element - region`` (:mod:`farfield.core.placement.cone_box`)."""
        axes = np.asarray(axes, dtype=np.float64).reshape(-1, 3)
        half_angles = np.asarray(half_angles, dtype=np.float64).reshape(-1)
        return refine_cone_box(axes, half_angles, self.d_lo, self.d_hi, self.seen_by_sphere(axes, half_angles))


def box_solid_angle_bound(lo: np.ndarray, hi: np.ndarray, region_lo, region_hi) -> np.ndarray:
    """(k,) upper bound of the solid angle of boxes ``lo``/``hi`` (k, 3) seen from any point of the
    region: per axis, the larger of its two faces' ``area / distance²`` over the faces some point of
    the region lies in front of (a point sees at most one face per axis, and a face's solid angle is
    ``∫ cos / r² dA <= area / r_min²``); ``inf`` where the region meets a box.

    >>> b = box_solid_angle_bound(np.array([[10.0, 0, 0]]), np.array([[11.0, 1, 1]]), np.zeros(3), np.zeros(3))
    >>> round(float(b[0]), 6)  # only the face x = 10 faces the origin: 1 m² at 10 m
    0.01
    """
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    region_lo = np.asarray(region_lo, dtype=np.float64)
    region_hi = np.asarray(region_hi, dtype=np.float64)
    ext = hi - lo
    total = np.zeros(len(lo))
    for a in range(3):
        area = ext[:, (a + 1) % 3] * ext[:, (a + 2) % 3]
        best = np.zeros(len(lo))
        for side, plane in ((1, hi[:, a]), (-1, lo[:, a])):
            front = region_hi[a] > plane if side > 0 else region_lo[a] < plane
            face_lo, face_hi = lo.copy(), hi.copy()
            face_lo[:, a] = plane
            face_hi[:, a] = plane
            dist = box_gap(face_lo, face_hi, region_lo, region_hi)
            with np.errstate(divide="ignore", invalid="ignore"):
                bound = np.where(front, np.where(dist > 0.0, area / (dist * dist), np.inf), 0.0)
            best = np.maximum(best, np.nan_to_num(bound, nan=0.0, posinf=np.inf))
        total += best
    return total


def element_pixels(
    elements: Elements, region_lo, region_hi, fov: float, resolution: int, index: np.ndarray | None = None
) -> np.ndarray:
    """(k,) covered-pixel estimate of each element from the region's nearest point: ``f²`` times the
    smaller of its bounding sphere's disc at the box distance and the box's face bound
    (:func:`box_solid_angle_bound`), at most the frame (whole frame where the element meets the region)."""
    b = elements.bounds if index is None else elements.bounds[index]
    radius = 0.5 * np.linalg.norm(b[:, 1] - b[:, 0], axis=1)
    dist = box_gap(b[:, 0], b[:, 1], region_lo, region_hi)
    focal = 0.5 * resolution / math.tan(0.5 * fov)
    frame = float(resolution) * float(resolution)
    with np.errstate(divide="ignore"):
        disc = np.where(dist > 0.0, math.pi * (focal * radius / np.where(dist > 0.0, dist, 1.0)) ** 2, frame)
    faces = focal * focal * box_solid_angle_bound(b[:, 0], b[:, 1], region_lo, region_hi)
    return np.minimum(np.minimum(disc, faces), frame)


@dataclass(frozen=True, slots=True, eq=False)
class ProblemViews:
    """The CPVs and the 3D regions they lie in (see the module docstring).

    Regions are the leaf regions holding CPVs, in depth-first order; ``tree_*`` are the regions of
    the 3D hierarchy that hold any of them (the view cells of box candidates, §5.6), each with the
    range ``[tree_first, tree_last)`` of leaf regions inside it.  Per CPV the elements its
    enclosing frustum meets are stored as sorted hierarchy positions in a flat CSR layout
    (``offsets``), with each entry's estimated time and pixels.
    """

    region_lo: np.ndarray  # (r, 3)
    region_hi: np.ndarray  # (r, 3)
    tree_lo: np.ndarray  # (q, 3)
    tree_hi: np.ndarray  # (q, 3)
    tree_first: np.ndarray  # (q,)
    tree_last: np.ndarray  # (q,)
    tree_parent: np.ndarray  # (q,) index into tree_*, -1 at the top
    cpv_region: np.ndarray  # (c,)
    cpv_vdi: tuple[VDI, ...]
    time: np.ndarray  # (c,) estimated time of the enclosing frustum, model units
    fixed_time: np.ndarray  # (c,) of what no impostor may replace (plus the frame's d)
    offsets: np.ndarray  # (c + 1,)
    positions: np.ndarray  # (total,) hierarchy positions of the elements, sorted within each CPV
    entry_time: np.ndarray  # (total,)
    entry_pixels: np.ndarray  # (total,)
    entry_fixed: (
        np.ndarray
    )  # (total,) bool: no impostor may replace the element in this CPV (its leaf meets the region)
    stats: dict = field(default_factory=dict)

    @property
    def count(self) -> int:
        return int(self.cpv_region.shape[0])

    @property
    def unsolvable(self) -> np.ndarray:
        """(c,) bool, set by :func:`problem_view_space`'s ``t_max``."""
        return self.fixed_time > self.stats["t_max"]


def problem_view_space(
    elements: Elements,
    hierarchy: Hierarchy,
    view_lo,
    view_hi,
    model: CostModel,
    t_max: float,
    fov: float,
    resolution: int,
    region_size: float,
    vdi_deg: float = 11.25,
    depth_complexity: float = DEFAULT_DEPTH_COMPLEXITY,
    visible: Visibility | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> ProblemViews:
    """The CPVs of the view space ``view_lo``..``view_hi`` for ``t_max`` (see the module docstring)."""
    lo, hi = np.asarray(view_lo, dtype=np.float64), np.asarray(view_hi, dtype=np.float64)
    if lo.shape != (3,) or hi.shape != (3,) or not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise PlacementError("the view space needs two finite corners x0,y0,z0 and x1,y1,z1")
    if np.any(hi < lo):
        raise PlacementError(f"the view space needs lo <= hi on every axis, got {lo.tolist()} and {hi.tolist()}")
    if not (math.isfinite(region_size) and region_size > 0.0):
        raise PlacementError(f"the CPV size must be > 0, got {region_size!r}")
    if not (math.isfinite(t_max) and t_max > 0.0):
        raise PlacementError(f"the budget t_max must be > 0, got {t_max!r}")
    if not depth_complexity >= 1.0:
        raise PlacementError(f"the depth complexity must be >= 1 (inf: no cap), got {depth_complexity!r}")
    pixel_cap = float(depth_complexity) * float(resolution) ** 2
    min_level = level_for_angle(vdi_deg)
    widen = frame_half_diagonal(fov)
    leaf_of = np.empty(elements.count, dtype=np.int64)  # element -> its hierarchy leaf
    for node in np.flatnonzero(hierarchy.leaf):
        leaf_of[hierarchy.elements_of(node)] = node
    all_elements = np.arange(elements.count, dtype=np.int64)
    b = elements.bounds

    regions: list[tuple[np.ndarray, np.ndarray]] = []
    tree: list[list] = []  # [lo, hi, first, last]
    cpv_region, cpv_vdi, times, fixed, rows, row_time, row_pixels, row_fixed = [], [], [], [], [], [], [], []
    evaluated = 0
    # Regions to visit: (lo, hi, VDIs to test, candidate elements, tree index of the parent).
    # Depth-first, low half first, so the leaf regions of a subtree are contiguous.
    leaves_float = float(np.prod(np.maximum(1.0, np.ceil((hi - lo) / region_size))))
    if not leaves_float <= MAX_REGIONS:
        raise PlacementError(
            f"a view space of {(hi - lo).tolist()} in regions of {region_size:.6g} has {leaves_float:.3g} regions, over {MAX_REGIONS:.0e}; "
            "use a larger CPV size"
        )
    total_leaves = max(1, int(leaves_float))
    stack = [(lo, hi, [VDI(f, 0, 0, 0) for f in range(6)], all_elements, -1)]
    leaves_done = 0
    while stack:
        r_lo, r_hi, vdis, cand, parent_tree = stack.pop()
        if visible is not None:
            kept = np.unique(np.asarray(visible(r_lo, r_hi, cand), dtype=np.int64))
            if kept.size and (kept[0] < 0 or kept[-1] >= elements.count):
                raise PlacementError("the visibility hook returned element indices out of range")
            cand = kept
        sight = RegionSight.of(b[cand, 0], b[cand, 1], r_lo, r_hi)
        pixels = element_pixels(elements, r_lo, r_hi, fov, resolution, cand)
        cost = model.geometry_time(elements.draw_calls[cand], elements.triangles[cand], 0.0)  # pixels apart
        per_pixel = model.geometry[2]
        problems: list[tuple[VDI, np.ndarray, float]] = []
        todo = vdis
        while todo:
            cones = [v.cone() for v in todo]
            axes = np.array([c[0] for c in cones])
            seen = RegionSight.seen(sight, axes, np.array([c[1] for c in cones]) + widen)
            seen_f = seen.astype(np.float64)
            t = model.frame_time + seen_f @ cost + per_pixel * np.minimum(seen_f @ pixels, pixel_cap)
            evaluated += len(todo)
            nxt = []
            for v, mask, tv in zip(todo, seen, t):
                if tv <= t_max:
                    continue
                if v.level < min_level:
                    nxt.extend(v.children())
                else:
                    problems.append((v, mask, float(tv)))
            todo = nxt
        if not problems:
            continue
        splittable = (r_hi - r_lo) > region_size * (1.0 + 1e-9)  # rounding must not split a region of the size
        if np.any(splittable):
            axis = int(np.argmax(np.where(splittable, r_hi - r_lo, -1.0)))
            mid = 0.5 * (r_lo[axis] + r_hi[axis])
            low_hi, high_lo = r_hi.copy(), r_lo.copy()
            low_hi[axis], high_lo[axis] = mid, mid
            union = cand[np.any(np.array([m for _, m, _ in problems]), axis=0)]
            me = len(tree)
            tree.append([r_lo, r_hi, len(regions), -1, parent_tree])
            vd = [v for v, _, _ in problems]
            stack.append((high_lo, r_hi, vd, union, me))
            stack.append((r_lo, low_hi, vd, union, me))
            continue
        # A leaf region: its problem VDIs are CPVs.
        region = len(regions)
        regions.append((r_lo, r_hi))
        tree.append([r_lo, r_hi, region, region + 1, parent_tree])
        meets = box_gap(b[cand, 0], b[cand, 1], r_lo, r_hi) <= 0.0
        leaf_lo, leaf_hi = hierarchy.lo[leaf_of[cand]], hierarchy.hi[leaf_of[cand]]
        stuck = box_gap(leaf_lo, leaf_hi, r_lo, r_hi) <= 0.0  # no impostor may replace these here
        stuck |= meets
        for v, mask, tv in problems:
            share = min(1.0, pixel_cap / max(float(pixels[mask].sum()), 1e-300))  # the depth-complexity cap
            entry_pixels = pixels[mask] * share
            entry = cost[mask] + per_pixel * entry_pixels
            ids = cand[mask]
            pos = hierarchy.position[ids]
            order = np.argsort(pos, kind="stable")
            cpv_region.append(region)
            cpv_vdi.append(v)
            times.append(tv)
            fixed.append(model.frame_time + float(entry[stuck[mask]].sum()))
            rows.append(pos[order])
            row_time.append(entry[order])
            row_pixels.append(entry_pixels[order])
            row_fixed.append(stuck[mask][order])
        leaves_done += 1
        if progress is not None:
            progress(leaves_done, total_leaves)
    # Close the tree's leaf ranges: a region's leaves are those added while it was on the stack.
    q = len(tree)
    last = [t[3] for t in tree]
    for k in range(q - 1, -1, -1):  # children come after parents: fold each range upwards
        if last[k] < 0:
            last[k] = tree[k][2]
        parent = tree[k][4]
        if parent >= 0:
            last[parent] = max(last[parent], last[k])
    keep = [k for k in range(q) if last[k] > tree[k][2]]
    renumber = {k: i for i, k in enumerate(keep)}
    offsets = np.concatenate([[0], np.cumsum([r.size for r in rows])]).astype(np.int64)
    empty_f = np.empty(0, dtype=np.float64)
    return ProblemViews(
        region_lo=np.array([r[0] for r in regions]).reshape(-1, 3),
        region_hi=np.array([r[1] for r in regions]).reshape(-1, 3),
        tree_lo=np.array([tree[k][0] for k in keep]).reshape(-1, 3),
        tree_hi=np.array([tree[k][1] for k in keep]).reshape(-1, 3),
        tree_first=np.array([tree[k][2] for k in keep], dtype=np.int64),
        tree_last=np.array([last[k] for k in keep], dtype=np.int64),
        tree_parent=np.array([renumber.get(tree[k][4], -1) for k in keep], dtype=np.int64),
        cpv_region=np.asarray(cpv_region, dtype=np.int64),
        cpv_vdi=tuple(cpv_vdi),
        time=np.asarray(times, dtype=np.float64),
        fixed_time=np.asarray(fixed, dtype=np.float64),
        offsets=offsets,
        positions=np.concatenate(rows).astype(np.int64) if rows else np.empty(0, dtype=np.int64),
        entry_time=np.concatenate(row_time) if rows else empty_f,
        entry_pixels=np.concatenate(row_pixels) if rows else empty_f,
        entry_fixed=np.concatenate(row_fixed) if rows else np.empty(0, dtype=bool),
        stats={
            "t_max": float(t_max),
            "vdis_evaluated": evaluated,
            "min_level": min_level,
            "leaf_regions_with_cpvs": len(regions),
        },
    )


class CpvGeometry:
    """Geometry time and pixels of any hierarchy node in any CPV, from the CPVs' sorted element rows.

    A node's elements in a CPV are the CPV's entries whose hierarchy positions lie in the node's
    ``[start, end)``: two binary searches in that CPV's own sorted entries (:func:`_node_entries`,
    numba), not in all the CPVs' entries at once.  The entries found, and so the sums, are those of
    ``searchsorted`` over the keys ``cpv * stride + position`` of every entry
    (``tests/test_placement_cpv_geometry.py`` compares them), which was a third of the candidate step."""

    def __init__(self, pv: ProblemViews, hierarchy: Hierarchy) -> None:
        self.offsets = np.ascontiguousarray(pv.offsets, dtype=np.int64)
        self.positions = np.ascontiguousarray(pv.positions, dtype=np.int64)
        self.cum_time = np.concatenate([[0.0], np.cumsum(pv.entry_time)])
        self.cum_pixels = np.concatenate([[0.0], np.cumsum(pv.entry_pixels)])
        self.start = np.ascontiguousarray(hierarchy.start, dtype=np.int64)
        self.end = np.ascontiguousarray(hierarchy.end, dtype=np.int64)

    def of(self, nodes: np.ndarray, cpvs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(time, pixels) of ``nodes`` in ``cpvs`` (broadcast (k,) arrays)."""
        nodes, cpvs = np.broadcast_arrays(np.asarray(nodes, dtype=np.int64), np.asarray(cpvs, dtype=np.int64))
        lo, hi = _node_entries(
            self.offsets, self.positions, self.start, self.end, np.ascontiguousarray(nodes).reshape(-1),
            np.ascontiguousarray(cpvs).reshape(-1),
        )  # fmt: skip
        lo, hi = lo.reshape(nodes.shape), hi.reshape(nodes.shape)
        return self.cum_time[hi] - self.cum_time[lo], self.cum_pixels[hi] - self.cum_pixels[lo]


@njit(cache=True, nogil=True)
def _node_entries(offsets, positions, start, end, nodes, cpvs):
    """(first, last) entry of node ``nodes[i]``'s elements in CPV ``cpvs[i]``: the left insertion
    points of the node's ``start`` and ``end`` among the CPV's sorted positions."""
    k = nodes.shape[0]
    lo, hi = np.empty(k, np.int64), np.empty(k, np.int64)
    for i in range(k):
        a, b, n = offsets[cpvs[i]], offsets[cpvs[i] + 1], nodes[i]
        lo[i] = a + np.searchsorted(positions[a:b], start[n], side="left")
        hi[i] = a + np.searchsorted(positions[a:b], end[n], side="left")
    return lo, hi
