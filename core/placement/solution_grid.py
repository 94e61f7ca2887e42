"""Primitive-budget image placement (seed 004, Aliaga & Lastra): a grid of solution points with
star-shapes, and at each point the images that keep every view within ``P`` primitives.

**The guarantee** (§3.1, Fig. 3).  A view at eye ``e`` and yaw ``theta`` uses a grid point ``g`` whose
frustum of the same direction and field of view holds ``e``.  The eye's frustum then lies inside
``g``'s, so it meets no cell that ``g``'s view does not (:mod:`farfield.core.placement.yaw_ranges`).  The
preprocessing makes every yaw range of every grid point draw at most ``P`` after culling one subset
(at most one image per view); the primitives of any such view are then at most ``P``, whatever the
eye.

**Star-shapes** (§3.2.1).  An image must lie ahead of every eye that can use its grid point.  The
paper bounds those eyes by a sphere of diameter ``4 r`` (``6 r`` on odd levels) for fields of view
of at least 54°.  Sampling a cubic lattice shows that in 3D the farthest eye reaches ``2.11 r`` at
54° (``1.97 r`` at 60°; ``tests/test_primitive_budget.py``).  So the radius here is a bound that is
proved instead.  At depth ``D`` behind the eye, the reverse frustum holds a ball of radius
``D sin(alpha)``.  A ball of radius ``sqrt(3)/2 r`` holds a lattice point.  So some grid point lies
within ``R = sqrt(3)/2 (1 + 1/sin(alpha)) r`` (2.60 r at 60°, 2.09 r at 90°) wherever the lattice is
complete.  An image is placed only where its plane lies more than ``R`` ahead of its grid point.
At run time an eye takes the closest grid point whose frustum holds it *and whose sphere holds it*.
Such an eye is therefore in front of every image of that point, by construction.  The paper takes
the closest point and relies on the sphere approximation; in a uniform grid the two rules agree.
Fields of view below ``2 atan(1/2)`` (53.13°, where the paper's ``s = r / (2 tan alpha)`` passes
``r``) are refused.

**Subdivision** (§3.2.2).  A grid point that cannot be solved is moved to the next level and
re-solved with its smaller sphere.  Every point of the next level's lattice near it is added: within
``R_k + R_{k+1}`` (a cube), and within ``R_{k+1}`` of the view space.  An eye that could use it
before then finds a point of the finer lattice in its reverse frustum within ``R_{k+1}``.  Points
keep their level when a neighbour is refined, so their spheres stay valid.

The paper alternates cubic (even) and centred (odd) lattices (Fig. 6).  Its odd level is
approximated by a sphere of ``6 r_{2k+1}``, and with ``r_{2k+1} = r_{2k} / sqrt 2`` in the plane
that is no smaller than the even level's ``4 r_{2k}``.  So each level here halves the cubic lattice
(an octree's rule), and the star radius halves with it.  Points at ``max_level`` that still fail are
kept and reported: their failing ranges are *unsolved*, and views there may exceed ``P``.

**Pre-test** (§5).  A view whose cells within ``R`` ahead of the grid point already exceed ``p_opt``
cannot be solved at this level: the point is subdivided without a search.

**Per grid point** (§3.3.2, Fig. 2).  The yaw ranges are computed, and the most expensive range over
``P`` gets a subset (:mod:`farfield.core.placement.cell_subsets`).  Every range that the subset's culling
brings within ``P`` uses that image, and the next most expensive range left over ``P`` gets its own
subset, computed from the full model.  This repeats until every range is within ``P``.  The default
``p_opt`` is ``P`` less 5 % of the model's triangles, at least ``P / 2``: the paper found a
difference of 5-10 % of the model gives 1-4 images per grid point (§6).
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from farfield.core.placement.cell_subsets import DEFAULT_LOOKAHEAD, corners_of, place_image
from farfield.core.placement.hierarchy import PlacementError
from farfield.core.placement.octree_cells import DEFAULT_DEPTH, OctreeCells, octree_cells
from farfield.core.placement.yaw_ranges import YawRanges, drawn_cells, forward
from farfield.core.scene import Scene

MIN_FOV_DEG = math.degrees(2.0 * math.atan(0.5))  # 53.13: s = r / (2 tan alpha) <= r (seed 004 §3.2.1)
NO_IMAGE, UNSOLVED = -1, -2
MAX_GRID_POINTS = 200_000  # a guard against a view space far finer than its geometry
MAX_LATTICE_SIDE = 58  # grid_points: the initial lattice alone (58^3) would pass MAX_GRID_POINTS
MAX_LEVEL = 20  # a millionth of the initial spacing
FORMAT_VERSION = 1


def star_radius(spacing: float, half: float) -> float:
    """The radius around a grid point of lattice spacing ``spacing`` that holds every eye that may use it
    (module docstring): ``sqrt(3)/2 (1 + 1/sin(half)) spacing``.

    >>> round(star_radius(1.0, math.radians(30)), 4)
    2.5981
    """
    return 0.5 * math.sqrt(3.0) * (1.0 + 1.0 / math.sin(half)) * spacing


@dataclass(frozen=True)
class BudgetSettings:
    """The knobs of a primitive-budget placement (seed 004 §5)."""

    primitives: float  # P: no view draws more
    p_opt: float | None = None  # the optimisation budget (< P) [default: P - 5 % of the model, at least P / 2]
    fov_deg: float = 60.0  # square frame, the same at run time
    octree_depth: int = DEFAULT_DEPTH
    grid_points: int = 3  # initial lattice points along the view space's longest side (the paper's minimum 3)
    spacing: float | None = None  # the initial lattice spacing [default: from grid_points]
    max_level: int = 4
    lookahead: int = DEFAULT_LOOKAHEAD

    def checked(self, model_triangles: int) -> tuple[float, float, float]:
        """(P, p_opt, half-angle) after checking; raises PlacementError naming the knob."""
        p = float(self.primitives)
        if not (math.isfinite(p) and p >= 1):
            raise PlacementError(f"the primitive budget must be a finite number >= 1, got {self.primitives!r}")
        p_opt = max(p - 0.05 * model_triangles, 0.5 * p) if self.p_opt is None else float(self.p_opt)
        if not (math.isfinite(p_opt) and 0 < p_opt <= p):
            raise PlacementError(f"p_opt must lie in (0, P] = (0, {p:g}], got {self.p_opt!r}")
        if not (math.isfinite(self.fov_deg) and MIN_FOV_DEG <= self.fov_deg < 180.0):
            raise PlacementError(
                f"field of view {self.fov_deg!r}° is below the star-shape bound: the primitive-budget placement needs "
                f"{MIN_FOV_DEG:.2f}° <= fov < 180° (seed 004 §3.2.1; 60° or more in the paper)"
            )
        for name, low, high in (
            ("grid_points", 2, MAX_LATTICE_SIDE),
            ("max_level", 0, MAX_LEVEL),
            ("lookahead", 0, None),
        ):
            value = getattr(self, name)
            if isinstance(value, bool) or int(value) != value or value < low or (high is not None and value > high):
                raise PlacementError(
                    f"{name} must be an integer >= {low}"
                    + (f" and <= {high}" if high is not None else "")
                    + f", got {value!r}"
                )
        if self.spacing is not None and not (math.isfinite(self.spacing) and self.spacing > 0):
            raise PlacementError(f"grid spacing must be > 0, got {self.spacing!r}")
        return p, p_opt, math.radians(self.fov_deg) / 2.0


@dataclass
class GridPoint:
    """A solution point: where it is, its level and star radius, and its images by yaw range.

    ``breaks`` start runs of yaw (radians, ``[0, 2 pi)``) and ``image[i]`` is what the run from
    ``breaks[i]`` uses: an index into ``images``, NO_IMAGE (the view is within ``P`` as it is) or
    UNSOLVED (over ``P``, reported).
    """

    position: np.ndarray
    level: int
    radius: float
    breaks: np.ndarray = field(default_factory=lambda: np.zeros(1))
    image: np.ndarray = field(default_factory=lambda: np.full(1, NO_IMAGE, dtype=np.int64))
    images: list[dict] = field(default_factory=list)  # yaw, depth, quad (4, 3), cells (k,), drawn, score
    worst_before: float = 0.0
    failure: str | None = None

    def image_for(self, yaw: float) -> int:
        y = float(np.mod(yaw, 2.0 * math.pi))
        return int(self.image[(np.searchsorted(self.breaks, y, side="right") - 1) % self.breaks.size])


@dataclass
class PrimitivePlacement:
    """A primitive-budget placement: the cells, the grid points and their images, and the settings."""

    cells: OctreeCells
    points: list[GridPoint]
    view_lo: np.ndarray
    view_hi: np.ndarray
    primitives: float
    p_opt: float
    half: float
    spacing: float
    max_level: int
    seconds: dict[str, float]
    _tree: cKDTree | None = None

    @property
    def images(self) -> int:
        return sum(len(p.images) for p in self.points)

    def tree(self) -> cKDTree:
        if self._tree is None:
            self._tree = cKDTree(np.array([p.position for p in self.points]))
        return self._tree

    def select(self, eye, yaw: float) -> int:
        """The grid point a view uses (Fig. 12): the closest whose frustum and star sphere hold ``eye``; -1 if none."""
        eye = np.asarray(eye, dtype=np.float64)
        reach = max(p.radius for p in self.points)
        near = self.tree().query_ball_point(eye, reach * (1 + 1e-9))
        if not near:
            return -1
        near = np.asarray(near)
        pos = np.array([self.points[i].position for i in near])
        rad = np.array([self.points[i].radius for i in near])
        d = eye - pos
        dist = np.linalg.norm(d, axis=1)
        f, t = forward(yaw), math.tan(self.half)
        ahead = d @ f
        side = d[:, 0] * math.cos(yaw) + d[:, 2] * math.sin(yaw)
        ok = (dist <= rad) & (ahead >= 0) & (np.abs(side) <= t * ahead + 1e-12) & (np.abs(d[:, 1]) <= t * ahead + 1e-12)
        if not ok.any():
            return -1
        return int(near[ok][np.argmin(dist[ok])])

    def view(self, eye, yaw: float) -> dict:
        """What a run time draws at (eye, yaw): the grid point, its image, the cells drawn as geometry and their primitives."""
        g = self.select(eye, yaw)
        drawn = drawn_cells(self.cells.lo, self.cells.hi, eye, yaw, self.half)
        out = {"point": g, "image": NO_IMAGE, "past_quad": False}
        if g >= 0:
            point = self.points[g]
            i = point.image_for(yaw)
            out["image"] = i
            if i >= 0:
                im = point.images[i]
                drawn[im["cells"]] = False
                out["past_quad"] = bool(np.dot(np.asarray(eye) - point.position, forward(im["yaw"])) >= im["depth"])
        out["cells"] = drawn
        out["primitives"] = int(self.cells.triangles[drawn].sum())
        return out

    def summary(self) -> dict:
        levels = np.bincount([p.level for p in self.points], minlength=self.max_level + 1)
        per_point = np.bincount([len(p.images) for p in self.points])
        ratios = [im["drawn"] / self.p_opt for p in self.points for im in p.images]
        return {
            "primitives": self.primitives, "p_opt": self.p_opt, "fov_deg": math.degrees(2 * self.half),
            "model_triangles": self.cells.total_triangles, "cells": self.cells.count, "octree_depth": self.cells.depth,
            "grid_points": len(self.points), "points_per_level": levels.tolist(), "spacing": self.spacing,
            "images": self.images, "points_with_images": {str(k): int(v) for k, v in enumerate(per_point) if v},
            "unsolved_points": sum(p.failure is not None for p in self.points),
            "image_drawn_over_p_opt": ({"min": float(np.min(ratios)), "median": float(np.median(ratios)), "max": float(np.max(ratios))}
                                       if ratios else None),
        }  # fmt: skip

    def to_dict(self) -> dict:
        return {
            "format": "farfield.primitive_placement", "version": FORMAT_VERSION,
            "view_space": [self.view_lo.tolist(), self.view_hi.tolist()],
            "summary": self.summary(), "seconds": self.seconds,
            "cells": {"lo": self.cells.lo.tolist(), "hi": self.cells.hi.tolist(), "triangles": self.cells.triangles.tolist(),
                      "depth": self.cells.depth, "cube_lo": self.cells.cube_lo.tolist(), "cube_size": self.cells.cube_size},
            "points": [{
                "position": p.position.tolist(), "level": p.level, "radius": p.radius, "breaks": p.breaks.tolist(),
                "image": p.image.tolist(), "failure": p.failure,
                "images": [{"yaw": im["yaw"], "depth": im["depth"], "quad": np.asarray(im["quad"]).tolist(),
                            "cells": np.asarray(im["cells"]).tolist(), "drawn": im["drawn"], "score": im["score"]} for im in p.images],
            } for p in self.points],
        }  # fmt: skip


def _merge_runs(breaks: np.ndarray, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    keep = np.ones(image.size, dtype=bool)
    keep[1:] = image[1:] != image[:-1]
    return breaks[keep], image[keep]


def solve_point(cells: OctreeCells, position: np.ndarray, radius: float, p: float, p_opt: float, half: float,
                extent: float, lookahead: int) -> GridPoint:  # fmt: skip
    """Images at one grid point so that every yaw range draws at most ``p`` (§3.3.2); ``failure`` says why not."""
    point = GridPoint(position=position, level=0, radius=radius)
    tris = cells.triangles.astype(np.float64)
    ranges = YawRanges.of(cells.lo, cells.hi, position, half)
    counts = ranges.sums(tris)
    point.worst_before = float(counts.max())
    image = np.full(ranges.count, NO_IMAGE, dtype=np.int64)
    over = counts > p
    corners = None
    while over.any():
        v = int(np.flatnonzero(over)[np.argmax(counts[over])])
        yaw = ranges.middle(v)
        members = ranges.members(v)
        if corners is None:
            corners = corners_of(cells.lo, cells.hi) - position  # (n, 8, 3)
        near = (corners @ forward(yaw)).min(axis=1)
        candidates = np.flatnonzero(members & (near > radius))
        fixed = counts[v] - tris[candidates].sum()
        if fixed > p_opt:  # §5's pre-test: what lies within the star sphere's depth alone is too much
            point.failure = (f"yaw {math.degrees(yaw):.1f}°: {fixed:.0f} primitives lie within {radius:.4g} ahead "
                             f"(p_opt {p_opt:.0f}); no image may come that close")  # fmt: skip
            image[over] = UNSOLVED
            break
        found = place_image(
            cells.lo[candidates],
            cells.hi[candidates],
            tris[candidates],
            position,
            yaw,
            half,
            counts[v],
            p_opt,
            extent,
            lookahead,
        )
        if found is None:  # cannot happen after the pre-test, kept for safety
            point.failure = f"yaw {math.degrees(yaw):.1f}: no subset culls enough"
            image[over] = UNSOLVED
            break
        culled = candidates[found.cells]
        keep = np.ones(cells.count, dtype=bool)
        keep[culled] = False
        now = ranges.sums(tris, keep)
        fixed_now = over & (now <= p)
        image[fixed_now] = len(point.images)
        over &= ~fixed_now
        point.images.append(
            {
                "yaw": yaw,
                "depth": found.depth,
                "quad": found.quad,
                "cells": culled,
                "drawn": found.drawn,
                "score": found.score,
            }
        )
    point.breaks, point.image = _merge_runs(ranges.breaks, image)
    return point


def _box_distance(points: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    return np.linalg.norm(np.maximum(np.maximum(lo - points, points - hi), 0.0), axis=-1)


def _lattice(centre_lo: np.ndarray, centre_hi: np.ndarray, origin: np.ndarray, step: float) -> np.ndarray:
    """(k, 3) int64 lattice indices ``origin + i step`` inside the box ``centre_lo``..``centre_hi``."""
    a = np.ceil((centre_lo - origin) / step - 1e-9).astype(np.int64)
    b = np.floor((centre_hi - origin) / step + 1e-9).astype(np.int64)
    axes = [np.arange(a[i], b[i] + 1) for i in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def place_primitives(scene: Scene, view_lo, view_hi, settings: BudgetSettings,
                     progress: Callable[[str, int, int], None] | None = None, cells: OctreeCells | None = None) -> PrimitivePlacement:  # fmt: skip
    """The primitive-budget placement of ``scene`` over the view space box (seed 004 Fig. 2)."""
    view_lo, view_hi = np.asarray(view_lo, dtype=np.float64), np.asarray(view_hi, dtype=np.float64)
    if (
        view_lo.shape != (3,)
        or view_hi.shape != (3,)
        or not (np.all(np.isfinite(view_lo)) and np.all(np.isfinite(view_hi)))
    ):
        raise PlacementError("the view space needs two finite corners of 3 numbers")
    if np.any(view_hi < view_lo):
        raise PlacementError(
            f"the view space is empty: max corner {view_hi.tolist()} below min corner {view_lo.tolist()}"
        )
    p, p_opt, half = settings.checked(scene.triangle_count)
    clock = {}
    t0 = time.perf_counter()
    if cells is None:
        cells = octree_cells(scene, settings.octree_depth)
    clock["cells"] = time.perf_counter() - t0
    extent = float((scene.bounds[1] - scene.bounds[0]).max())
    side = float((view_hi - view_lo).max())
    r0 = (
        settings.spacing
        if settings.spacing is not None
        else (side / (settings.grid_points - 1) if side > 0 else extent / 8.0)
    )
    radii = [star_radius(r0 / 2**k, half) for k in range(settings.max_level + 1)]
    # An eye inside a cell's bounds draws the cell from every yaw and no image can replace it (an
    # image lies ahead of its grid point, which lies within reach of the eye): a cell that meets the
    # view space with more than P triangles leaves no valid answer.  (Cells nearby with more than
    # p_opt may still fail; those grid points are reported as unsolved.)
    inside = np.all((cells.lo <= view_hi) & (cells.hi >= view_lo), axis=1) & (cells.triangles > p)
    if inside.any():
        worst = int(cells.triangles[inside].max())
        raise PlacementError(
            f"an octree cell that meets the view space holds {worst} triangles, more than P = {p:g}: a view from inside it "
            f"draws them all; raise --primitives, or --octree-depth (now {cells.depth}) for smaller cells"
        )
    scale = 2**settings.max_level  # keys: lattice indices at the finest level
    points: dict[tuple, GridPoint] = {}
    queue: deque[tuple] = deque()

    def add(level: int, index: np.ndarray) -> None:
        step = r0 / 2**level
        pos = view_lo + index * step
        near = _box_distance(pos, view_lo, view_hi) <= radii[level] * (1 + 1e-9)
        for i, x in zip(index[near], pos[near]):
            key = tuple(int(v) * (scale >> level) for v in i)
            # A point already there keeps its level: the queue is first in, first out, so every point
            # of level k is solved (and refined) before one of level k + 1, and an existing point is
            # never finer than the level being added.
            if key not in points:
                points[key] = GridPoint(position=x, level=level, radius=radii[level])
                queue.append(key)
        if len(points) > MAX_GRID_POINTS:
            raise PlacementError(
                f"more than {MAX_GRID_POINTS} grid points: raise the budget, or lower --max-level or the grid resolution"
            )

    add(0, _lattice(view_lo - radii[0], view_hi + radii[0], view_lo, r0))
    t1 = time.perf_counter()
    solved = 0
    while queue:
        key = queue.popleft()
        old = points[key]
        point = solve_point(cells, old.position, old.radius, p, p_opt, half, extent, settings.lookahead)
        point.level = old.level
        solved += 1
        if point.failure is not None and old.level < settings.max_level:
            level = old.level + 1
            points[key] = GridPoint(position=old.position, level=level, radius=radii[level])
            queue.append(key)
            reach = radii[level - 1] + radii[level]
            add(level, _lattice(old.position - reach, old.position + reach, view_lo, r0 / 2**level))
        else:
            points[key] = point
        if progress is not None:
            progress("grid", solved, solved + len(queue))
    clock["grid"] = time.perf_counter() - t1
    ordered = [points[k] for k in sorted(points)]
    return PrimitivePlacement(cells, ordered, view_lo, view_hi, p, p_opt, half, r0, settings.max_level, clock)


def check_views(
    placement: PrimitivePlacement,
    views: int = 10_000,
    seed: int = 0,
    progress: Callable[[str, int, int], None] | None = None,
) -> dict:
    """Sample (eye, yaw) pairs uniformly in the view space (pitch 0) and count what each draws: the
    guarantee's check (share within ``P``), p99 against ``p_opt``, views without a grid point, eyes
    past their image's quad, views in unsolved ranges."""
    if isinstance(views, bool) or int(views) != views or views < 1:
        raise PlacementError(f"the number of views to check must be an integer >= 1, got {views!r}")
    rng = np.random.default_rng(seed)
    eyes = placement.view_lo + rng.random((views, 3)) * (placement.view_hi - placement.view_lo)
    yaws = rng.random(views) * 2.0 * math.pi
    prims = np.zeros(views)
    no_point = past = unsolved = with_image = 0
    for k in range(views):
        v = placement.view(eyes[k], yaws[k])
        prims[k] = v["primitives"]
        no_point += v["point"] < 0
        past += v["past_quad"]
        unsolved += v["image"] == UNSOLVED
        with_image += v["image"] >= 0
        if progress is not None and ((k + 1) % 256 == 0 or k + 1 == views):
            progress("check views", k + 1, views)
    return {
        "views": views, "seed": seed, "within_p": float(np.mean(prims <= placement.primitives)),
        "max": float(prims.max()), "p99": float(np.percentile(prims, 99)), "median": float(np.median(prims)),
        "p99_over_p_opt": float(np.percentile(prims, 99) / placement.p_opt), "without_grid_point": int(no_point),
        "eye_past_quad": int(past), "in_unsolved_range": int(unsolved), "with_image": int(with_image),
    }  # fmt: skip
