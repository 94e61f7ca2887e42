"""A node's geometry time and pixels in a CPV (farfield.core.placement.view_space.CpvGeometry), found by
binary searches in each CPV's own entries, are the sums the search over every CPV's keys found."""

from __future__ import annotations

import math

import numpy as np

from farfield.core import procedural
from farfield.core.placement.cost_model import primitive_model
from farfield.core.placement.hierarchy import Elements, Hierarchy
from farfield.core.placement.view_space import CpvGeometry, problem_view_space


def _reference(pv, hierarchy, nodes, cpvs):
    """The former CpvGeometry.of: ``searchsorted`` over the keys ``cpv * stride + position`` of all entries."""
    stride = np.int64(hierarchy.order.size + 1)
    keys = np.repeat(np.arange(pv.count, dtype=np.int64), np.diff(pv.offsets)) * stride + pv.positions
    cum_time = np.concatenate([[0.0], np.cumsum(pv.entry_time)])
    cum_pixels = np.concatenate([[0.0], np.cumsum(pv.entry_pixels)])
    lo = np.searchsorted(keys, cpvs * stride + hierarchy.start[nodes])
    hi = np.searchsorted(keys, cpvs * stride + hierarchy.end[nodes])
    return cum_time[hi] - cum_time[lo], cum_pixels[hi] - cum_pixels[lo]


def test_node_sums_per_cpv_are_the_sums_over_all_keys():
    scene = procedural.city(49, seed=4, detail=6)
    elements = Elements.of(scene)
    hierarchy = Hierarchy.build(elements)
    lo, hi = scene.bounds[0].copy(), scene.bounds[1].copy()
    lo[1] = hi[1] = float(scene.bounds[1][1]) + 5.0
    model = primitive_model()
    pv = problem_view_space(
        elements, hierarchy, lo, hi, model, 1e-9, math.radians(45.0), 128, 0.25 * float(np.max(hi - lo)), 22.5
    )
    assert pv.count > 10 and hierarchy.count > 10
    geometry = CpvGeometry(pv, hierarchy)
    rng = np.random.default_rng(0)
    nodes = rng.integers(0, hierarchy.count, 5000)
    cpvs = rng.integers(0, pv.count, 5000)
    time, pixels = geometry.of(nodes, cpvs)
    want_time, want_pixels = _reference(pv, hierarchy, nodes, cpvs)
    assert np.any(want_time > 0.0) and np.any(want_time == 0.0)
    assert time.tobytes() == want_time.tobytes() and pixels.tobytes() == want_pixels.tobytes()
    # every node in every CPV, broadcast as the candidate step asks (one node, all CPVs)
    for n in range(hierarchy.count):
        every = np.arange(pv.count)
        got = geometry.of(np.full(every.size, n), every)
        want = _reference(pv, hierarchy, np.full(every.size, n), every)
        assert got[0].tobytes() == want[0].tobytes() and got[1].tobytes() == want[1].tobytes()
