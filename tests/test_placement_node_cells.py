"""A node's shafts and boxes found for all their cells at once (farfield.core.placement.candidates:
NodeCells in CSR form) are the cells, and the regions each serves, of the former loop over cells;
the box cells' frames built elementwise (part_estimates._box_frames) are the scalar ones bit for bit."""

from __future__ import annotations

import math

import numpy as np

from farfield.core import procedural
from farfield.core.placement.candidates import (
    APEX_ANGLES_DEG,
    DISTANCE_STEPS,
    _box_cells,
    _leaf_box_cells,
    _shaft_cells,
    direction_grid,
)
from farfield.core.placement.cost_model import primitive_model
from farfield.core.placement.hierarchy import Elements, Hierarchy
from farfield.core.placement.part_estimates import _box_frames
from farfield.core.placement.view_space import box_gap, problem_view_space
from farfield.core.viewcells import _orthonormal_frame, length_and_unit


def _shafts_one_by_one(centre, size, regions, region_centre, region_radius, grid, halves, distance_steps):
    """The former _shaft_cells: (a, d, k, served regions) built one (direction, distance) pair at a time."""
    out = []
    vec = region_centre[regions] - centre
    dist = np.linalg.norm(vec, axis=1)
    far = dist > region_radius[regions]
    regions, vec, dist = regions[far], vec[far], dist[far]
    if regions.size == 0:
        return out
    unit = vec / dist[:, None]
    radius = region_radius[regions]
    gamma = np.arcsin(np.minimum(radius / dist, 1.0))
    need = np.arccos(np.clip(unit @ grid.T, -1.0, 1.0)) + gamma[:, None]
    a_index = np.searchsorted(halves, need, side="left")
    along = dist[:, None] * np.cos(np.minimum(need, 0.5 * math.pi)) - radius[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        k_index = np.floor(np.log2(np.clip(np.where(along > 0.0, along / size, 0.5), 0.5, 2.0**62))).astype(np.int64)
    k_index = np.minimum(k_index, distance_steps - 1)
    ok = (a_index < len(halves)) & (k_index >= 0)
    steps = np.int64(distance_steps + 1)
    for a in range(len(halves)):
        fits = ok & (a_index <= a)
        rows, cols = np.nonzero(fits)
        pairs = np.unique(cols * steps + k_index[rows, cols])
        ds, ks = pairs // steps, pairs % steps
        if a > 0:
            reach = np.where(fits & (a_index == a), k_index, -1).max(axis=0)
            keep = reach[ds] >= ks
            ds, ks = ds[keep], ks[keep]
        for d, k in zip(ds.tolist(), ks.tolist()):
            out.append((a, d, k, regions[fits[:, d] & (k_index[:, d] >= k)]))
    return out


def _boxes_one_by_one(pv, lo, hi, region_relevant):
    """The former _box_cells: (lo, hi, served regions) one view-space region at a time."""
    counts = np.concatenate([[0], np.cumsum(region_relevant)])
    cnt = counts[pv.tree_last] - counts[pv.tree_first]
    apart = box_gap(pv.tree_lo, pv.tree_hi, lo, hi) > 0.0
    same = (pv.tree_parent >= 0) & apart & (cnt == cnt[np.maximum(pv.tree_parent, 0)])
    dominated = np.zeros(cnt.shape, dtype=bool)
    dominated[pv.tree_parent[same]] = True
    span = pv.tree_hi - pv.tree_lo
    pad = np.where(span > 0.0, 0.0, np.maximum(1e-6 * span.max(axis=1, keepdims=True), 1e-9))
    out = []
    for q in np.flatnonzero((cnt > 0) & apart & ~dominated):
        served = pv.tree_first[q] + np.flatnonzero(region_relevant[pv.tree_first[q] : pv.tree_last[q]])
        out.append((pv.tree_lo[q] - pad[q], pv.tree_hi[q] + pad[q], served))
    return out


def test_node_cells_are_the_cells_of_the_loop_over_cells():
    scene = procedural.city(64, seed=2, detail=6)
    elements = Elements.of(scene)
    hierarchy = Hierarchy.build(elements)
    lo, hi = scene.bounds[0].copy(), scene.bounds[1].copy()
    lo[1], hi[1] = float(scene.bounds[1][1]) + 2.0, float(scene.bounds[1][1]) + 12.0
    pv = problem_view_space(elements, hierarchy, lo, hi, primitive_model(), 1e-9, math.radians(45.0), 128, 0.125 * float(np.max(hi - lo)), 22.5)  # fmt: skip
    region_centre = 0.5 * (pv.region_lo + pv.region_hi)
    region_radius = 0.5 * np.linalg.norm(pv.region_hi - pv.region_lo, axis=1)
    grid, halves = direction_grid(), np.radians(np.asarray(APEX_ANGLES_DEG)) * 0.5
    rng = np.random.default_rng(7)
    shafts_seen = boxes_seen = 0
    for n in range(hierarchy.count):
        relevant = rng.random(pv.region_lo.shape[0]) < rng.uniform(0.2, 1.0)  # a random set of relevant regions
        centre, size = 0.5 * (hierarchy.lo[n] + hierarchy.hi[n]), float(hierarchy.diagonal[n])
        got, _ = _shaft_cells(
            n, centre, size, np.flatnonzero(relevant), region_centre, region_radius, grid, halves, DISTANCE_STEPS
        )
        want = _shafts_one_by_one(centre, size, np.flatnonzero(relevant), region_centre, region_radius, grid, halves, DISTANCE_STEPS)  # fmt: skip
        assert got.count == len(want)
        for i, (a, d, k, served) in enumerate(want):
            assert got.keys[i].tolist() == [a, d, k]
            assert got.regions(i).tolist() == served.tolist()
        shafts_seen += got.count
        boxes, _ = _box_cells(pv, hierarchy.lo[n], hierarchy.hi[n], relevant)
        want = _boxes_one_by_one(pv, hierarchy.lo[n], hierarchy.hi[n], relevant)
        assert boxes.count == len(want)
        for i, (blo, bhi, served) in enumerate(want):
            assert boxes.lo[i].tobytes() == blo.tobytes() and boxes.hi[i].tobytes() == bhi.tobytes()
            assert boxes.regions(i).tolist() == served.tolist()
        boxes_seen += boxes.count
        leaves, _ = _leaf_box_cells(pv, hierarchy.lo[n], hierarchy.hi[n], relevant)
        apart = relevant & (box_gap(pv.region_lo, pv.region_hi, hierarchy.lo[n], hierarchy.hi[n]) > 0.0)
        assert [leaves.regions(i).tolist() for i in range(leaves.count)] == [[r] for r in np.flatnonzero(apart)]
    assert shafts_seen > 1000 and boxes_seen > 100


def test_box_frames_are_the_scalar_frames():
    rng = np.random.default_rng(5)
    towards = rng.normal(size=(4000, 3)) * rng.uniform(1e-3, 1e4, (4000, 1))
    towards[:40, :2] *= 1e-3  # nearly vertical: the other helper vector
    towards[40] = 0.0
    towards[41] = [3e300, -4e300, 1e299]  # squares overflow
    towards[42] = [1e-170, 2e-170, 0.0]  # squares underflow
    dist, frame = _box_frames(towards)
    for i, t in enumerate(towards):
        length, axis = length_and_unit(t)
        assert dist[i] == length
        want = np.zeros((3, 3))
        if length > 0.0:
            want[0], want[1] = _orthonormal_frame(axis)
            want[2] = axis
        assert frame[i].tobytes() == want.tobytes(), i
