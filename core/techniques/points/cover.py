"""The points a view cell needs: (n,) bool over (n, 3) float64 candidate points, a greedy cover of
every pixel-sized window of some views of the cell (issue 60, item 3).

Seed 001 §5.1 removes the redundant LDI samples; what is left still holds every fold of a rough
surface, most of them hidden from the whole cell.  Keeping the points that *win* a pixel in some of
the appearance's views (the earlier test) keeps the nearest point of every pixel of every view: on a
surface whose noise lies within a pixel's depth a different point wins each jittered view, so the
union grows with the views (5.04 points per bounding-box pixel at 512 px on a 327,680-triangle rough
sphere) and still leaves holes from viewpoints between them (a point that loses its pixel in every
sampled view can be the only one in a pixel of another: docs/measurements/points.md).

Here the candidates are projected (float64, numpy) into ``views`` views of the cell (the
appearance's viewpoints and windows, :func:`farfield.core.techniques.points.appearance._views`: the
cell's corners, its centre, then a scrambled Sobol sequence; taken nearest the part first, whose
windows are the finest) on a grid of :data:`CELLS` cells per output pixel side.  A **window** is
every square of :data:`BLOCK` × :data:`BLOCK` grid cells, at every cell offset.  A window's **front**
is the depth of its nearest candidate; a point **covers** a window it lies in when its depth is
within :data:`DEPTH_TOLERANCE` (relative) of the front: it shows the surface the window shows (the
hole tests' 0.5 %, ``tests/test_point_samples.py``).

- **Greedy**, view by view: every window that holds a candidate and that no kept point covers gets
  one, the front-most candidate of one of its grid cells that covers it and closes the most windows
  still open (ties: the window's last cells, which the next windows share).
- **Pruning**, over all views at once: a kept point goes when every window it covers, in every view,
  is covered by another kept point (the later views' points make many of the earlier views' choices
  redundant: about 7 % fewer points on the rough sphere).

Why :data:`BLOCK` = :data:`CELLS` - 1: a length L holds m whole grid cells of 1/k pixel wherever it
lies when L ≥ (m + 1)/k, so an output pixel at any offset holds a whole window exactly when
m = k - 1: every pixel of a sampled view, at any sub-pixel shift, holds a kept point of the surface
it shows.  Viewpoints between the sampled ones shift the image by such amounts (and scale and shear
it by far less than a pixel over a pixel); measured on views the cover did not use (random points
of the cell): 0 hole pixels on the rough sphere and the test scenes (docs/measurements/points.md).
A finer grid keeps slightly fewer points (windows nearer a whole pixel) for more memory.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from farfield.core.scene import SceneObject
from farfield.core.techniques.points.appearance import _extent, _views, _window
from farfield.core.viewcells import BoxCell

# The cell's corners, its centre and 8 Sobol points: no hole pixel from views between them (module docstring).
VIEWS = 17
CELLS = 8  # grid cells per output pixel side
BLOCK = 7  # grid cells per window side: CELLS - 1, so a pixel at any offset holds a whole window
DEPTH_TOLERANCE = 0.005  # relative depth behind a window's front that still shows its surface (the hole tests' 0.5 %)


def covering_points(
    objects: list[SceneObject] | tuple[SceneObject, ...],
    points: np.ndarray,
    cell: BoxCell,
    fov_deg: float,
    resolution: int,
    views: int = VIEWS,
    seed: int = 0,
    cells: int = CELLS,
    block: int = BLOCK,
    tolerance: float = DEPTH_TOLERANCE,
    prune: bool = True,
) -> np.ndarray:
    """(n,) bool: the ``points`` (n, 3) kept to cover every window of the first ``views`` views of
    :func:`farfield.core.techniques.points.appearance.integrate_appearance` (same viewpoints and
    windows; module docstring)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n = points.shape[0]
    kept = np.zeros(n, dtype=np.bool_)
    if n == 0:
        return kept
    fov = math.radians(float(fov_deg))
    extent = _extent(objects, points)
    target = 0.5 * (extent.min(axis=0) + extent.max(axis=0))
    chosen = np.concatenate(list(_views(cell, seed, views)))
    eyes = cell.lo + chosen[:, :3] * (cell.hi - cell.lo)
    order = np.argsort(np.linalg.norm(eyes - target, axis=1), kind="stable")  # the nearest first: the finest windows
    grids = []
    for q in chosen[order]:
        _eye, camera, x0, y0, size = _window(q, cell, target, fov, resolution, extent)
        grids.append((camera.window(x0, y0, size, size * cells), size * cells))
    # Every view's window fronts, float32, held for the pruning (one array: no second copy).
    side = max(grid_side for _grid, grid_side in grids) - block + 1
    fronts = np.full((len(grids), side, side), np.inf, np.float32) if prune else None
    for v, (grid, grid_side) in enumerate(grids):
        pixel, depth = _cells(grid, points, grid_side)
        _added, front = _cover_view(pixel[:, 0], pixel[:, 1], depth, kept, grid_side, block, tolerance)
        if prune:
            fronts[v, : front.shape[0], : front.shape[1]] = front
        del pixel, depth, front
    if not prune:
        return kept
    # Drop the points every window of theirs can spare (the greedy's choices of earlier views that
    # later views' points made redundant), over all views at once.
    index = np.flatnonzero(kept)
    xs = np.full((len(grids), index.size), -1, np.int64)
    ys = np.full((len(grids), index.size), -1, np.int64)
    zs = np.zeros((len(grids), index.size), np.float64)
    for v, (grid, grid_side) in enumerate(grids):
        pixel, depth = _cells(grid, points[index], grid_side)
        xs[v], ys[v], zs[v] = pixel[:, 0], pixel[:, 1], depth
    keep = _prune(xs, ys, zs, fronts, block, tolerance)
    kept[index[~keep]] = False
    return kept


def warm_cover() -> None:
    """Compile (or load from numba's cache) this module's kernels on tiny arrays."""
    x = np.array([0, 1, -1], np.int64)
    z = np.array([1.0, 1.0, 1.0])
    _added, front = _cover_view(x, x, z, np.zeros(3, np.bool_), 2, 1, DEPTH_TOLERANCE)
    _prune(x[None, :2], x[None, :2], z[None, :2], front[None].astype(np.float32), 1, DEPTH_TOLERANCE)


def _cells(grid, points: np.ndarray, side: int) -> tuple[np.ndarray, np.ndarray]:
    """((n, 2) int64 grid cell of each of ``points`` (-1 outside the ``side`` x ``side`` grid), (n,) depth)."""
    pixel = np.floor(grid.project(points)).astype(np.int64)
    depth = (points - grid.eye) @ grid.forward
    pixel[(depth <= 0.0) | np.any((pixel < 0) | (pixel >= side), axis=1)] = -1
    return pixel, depth


@numba.njit(cache=True, nogil=True)
def _prune(xs, ys, zs, front, block, tolerance):
    """(m,) bool: which of m kept points stay: ``xs``, ``ys``, ``zs`` (views, m) their cells and
    depths, ``front`` (views, w, w) the windows' fronts; a point goes when every window it covers
    in every view is covered by another point still kept (the last index first)."""
    views, m = xs.shape
    count = np.zeros(front.shape, np.int16)  # kept points covering each window (a few dozen at most)
    for v in range(views):
        for i in range(m):
            _count(count[v], front[v], xs[v, i], ys[v, i], zs[v, i], block, tolerance, 1)
    keep = np.ones(m, np.bool_)
    for i in range(m - 1, -1, -1):
        spare = True
        for v in range(views):
            if _count(count[v], front[v], xs[v, i], ys[v, i], zs[v, i], block, tolerance, 0) < 2:
                spare = False
                break
        if spare:
            keep[i] = False
            for v in range(views):
                _count(count[v], front[v], xs[v, i], ys[v, i], zs[v, i], block, tolerance, -1)
    return keep


@numba.njit(cache=True, nogil=True)
def _count(count, front, x, y, z, block, tolerance, change):
    """Add ``change`` to the count of every window holding cell (x, y) that depth ``z`` covers; the
    smallest count among them before (a large number where it covers none, or lies outside)."""
    least = 1 << 30
    if x < 0:
        return least
    nb = count.shape[0]
    for by in range(max(0, y - block + 1), min(y, nb - 1) + 1):
        for bx in range(max(0, x - block + 1), min(x, nb - 1) + 1):
            if z <= front[by, bx] * (1.0 + tolerance):
                least = min(least, count[by, bx])
                count[by, bx] += change
    return least


@numba.njit(cache=True, nogil=True)
def _mark(covered, front, x, y, z, block, tolerance):
    """Mark the windows holding cell (x, y) whose front ``z`` lies within ``tolerance`` of."""
    nb = covered.shape[0]
    for by in range(max(0, y - block + 1), min(y, nb - 1) + 1):
        for bx in range(max(0, x - block + 1), min(x, nb - 1) + 1):
            if z <= front[by, bx] * (1.0 + tolerance):
                covered[by, bx] = True


@numba.njit(cache=True, nogil=True)
def _gain(covered, front, x, y, z, block, tolerance):
    """How many windows still open :func:`_mark` would close."""
    nb = covered.shape[0]
    gain = 0
    for by in range(max(0, y - block + 1), min(y, nb - 1) + 1):
        for bx in range(max(0, x - block + 1), min(x, nb - 1) + 1):
            if not covered[by, bx] and z <= front[by, bx] * (1.0 + tolerance):
                gain += 1
    return gain


@numba.njit(cache=True, nogil=True)
def _cover_view(x, y, z, kept, side, block, tolerance):
    """One view of :func:`covering_points`: ``x``, ``y`` (n,) int64 grid cells (-1 outside),
    ``z`` (n,) depths; sets ``kept`` where a window needs a point; (the points added, (w, w) each
    window's front)."""
    n = x.shape[0]
    cell_front = np.full((side, side), np.inf)
    cell_point = np.full((side, side), -1, np.int64)
    for i in range(n):
        if x[i] >= 0 and z[i] < cell_front[y[i], x[i]]:
            cell_front[y[i], x[i]] = z[i]
            cell_point[y[i], x[i]] = i
    nb = side - block + 1
    rows = np.full((side, nb), np.inf)  # the window's front, separably: along x, then along y
    for r in range(side):
        for c in range(nb):
            m = np.inf
            for d in range(block):
                m = min(m, cell_front[r, c + d])
            rows[r, c] = m
    front = np.full((nb, nb), np.inf)
    for r in range(nb):
        for c in range(nb):
            m = np.inf
            for d in range(block):
                m = min(m, rows[r + d, c])
            front[r, c] = m
    covered = np.zeros((nb, nb), np.bool_)
    for i in range(n):
        if kept[i] and x[i] >= 0:
            _mark(covered, front, x[i], y[i], z[i], block, tolerance)
    added = 0
    for r in range(nb):
        for c in range(nb):
            if covered[r, c] or not np.isfinite(front[r, c]):
                continue
            limit = front[r, c] * (1.0 + tolerance)
            chosen, best = -1, -1
            for dy in range(block - 1, -1, -1):  # the most windows still open; ties: the last cells first
                for dx in range(block - 1, -1, -1):
                    j = cell_point[r + dy, c + dx]
                    if j >= 0 and cell_front[r + dy, c + dx] <= limit:
                        gain = _gain(covered, front, x[j], y[j], z[j], block, tolerance)
                        if gain > best:
                            chosen, best = j, gain
            kept[chosen] = True
            added += 1
            _mark(covered, front, x[chosen], y[chosen], z[chosen], block, tolerance)
    return added, front
