"""The candidate step cut into node ranges (farfield.core.placement.candidate_parts), each computed
from pickled inputs as another process would, and merged: the placement is the one-pass placement,
byte for byte (shared octahedral atlases included, renumbered by first use)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from farfield.core import procedural
from farfield.core.placement.candidate_parts import candidate_part, merge_candidates, node_ranges
from farfield.core.placement.cost_model import CostModel, primitive_model
from farfield.core.placement.part_inputs import PartInputs
from farfield.core.placement.planner import PlacementSettings, place


def _in_parts(parts: int, seen: list):
    def candidates(inputs: PartInputs, progress):
        ranges = node_ranges(inputs, parts)
        seen.append(ranges)
        again = PartInputs.loads(inputs.dumps())  # as a worker receives them
        return merge_candidates([candidate_part(again, r) for r in ranges])

    return candidates


def _dump(placement) -> str:
    return json.dumps(placement.to_dict(), sort_keys=True)


def test_a_city_planned_in_parts_is_the_city_planned_in_one_pass():
    city = procedural.city(36, seed=5, detail=6)
    settings = PlacementSettings(t_max=0.5 * city.triangle_count, model=primitive_model(), vdi_deg=45.0,
                                 options={"resolution": 128}, cpv_size=20.0, cells="both")  # fmt: skip
    view = ([20.0, 110.0, 20.0], [100.0, 115.0, 100.0])
    one = place(city, *view, settings)
    for parts in (3,):
        seen: list = []
        split = place(city, *view, settings, candidates=_in_parts(parts, seen))
        ranges = seen[0]
        assert len(ranges) == parts and ranges[0].start == 0
        assert all(a.stop == b.start for a, b in zip(ranges, ranges[1:]))
        assert one.summary["candidates"] > 10 and one.impostors
        assert _dump(split) == _dump(one)


def test_shared_atlases_are_numbered_as_one_pass_numbers_them():
    forest = procedural.tree_forest(32, prototypes=2, size=800.0, detail=1)
    m = primitive_model()
    model = CostModel(m.kind, m.geometry, m.impostor, (1e3 * m.memory[0], m.memory[1], m.memory[2]),
                      memory_exponent=m.memory_exponent, quads_exponent=m.quads_exponent)  # fmt: skip
    settings = PlacementSettings(t_max=0.3 * forest.triangle_count, model=model, options={"resolution": 32},
                                 also={"octahedral": {"grid": 9, "frame_resolution": 16, "padding": 2}}, vdi_deg=45.0,
                                 cpv_size=10.0, cells="both", cluster_triangles=10**6, leaf_size=1)  # fmt: skip
    view = (np.array([390.0, 2.0, 390.0]), np.array([410.0, 2.0, 410.0]))
    one = place(forest, *view, settings, keep_state=True)
    split = place(forest, *view, settings, keep_state=True, candidates=_in_parts(4, []))
    assert len(one.state.cand.prototypes) == 2 and one.summary.get("shared_atlases")
    assert split.state.cand.prototypes == one.state.cand.prototypes
    assert np.array_equal(split.state.cand.prototype, one.state.cand.prototype)
    assert _dump(split) == _dump(one)


def test_node_ranges_cover_every_node_once_and_never_more_parts_than_nodes():
    city = procedural.city(4, seed=1, detail=2)
    settings = PlacementSettings(t_max=0.5 * city.triangle_count, model=primitive_model(), vdi_deg=90.0,
                                 options={"resolution": 32}, cpv_size=40.0)  # fmt: skip
    seen: list = []
    place(city, [0.0, 30.0, 0.0], [40.0, 31.0, 40.0], settings, candidates=_in_parts(10**6, seen))
    ranges = seen[0]
    nodes = [n for r in ranges for n in r]
    assert nodes == list(range(len(nodes))) and all(len(r) >= 1 for r in ranges)


@pytest.mark.parametrize("parts", [0, -3])
def test_no_parts_is_one_part(parts):
    city = procedural.city(4, seed=1, detail=2)
    settings = PlacementSettings(t_max=0.5 * city.triangle_count, model=primitive_model(), vdi_deg=90.0,
                                 options={"resolution": 32}, cpv_size=40.0)  # fmt: skip
    seen: list = []
    place(city, [0.0, 30.0, 0.0], [40.0, 31.0, 40.0], settings, candidates=_in_parts(parts, seen))
    assert len(seen[0]) == 1 and seen[0][0].start == 0
