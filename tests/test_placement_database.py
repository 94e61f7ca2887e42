"""Check-and-repair rounds (core/placement/repair.py) and the placement database with its lookup (core/placement/database.py).

Real placements of a small procedural city under a primitive budget, real EGL bakes at 64 px.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from farfield.core import procedural
from farfield.core.errors import ViewCellError
from farfield.core.impostor.database import ImpostorDatabase
from farfield.core.placement.cost_model import primitive_model
from farfield.core.placement.database import (
    UNDER_BUDGET,
    PlacementLookup,
    bake_impostor,
    bake_placement,
    placement_cells,
    placement_index,
    write_placement_database,
)
from farfield.core.placement.hierarchy import PlacementError
from farfield.core.placement.planner import PlacementSettings, place
from farfield.core.placement.repair import PlannerState
from farfield.core.placement.view_space import FACE_NAMES, VDI
from farfield.core.scene import Scene, SceneObject

VIEW = ([20.0, 110.0, 20.0], [100.0, 115.0, 100.0])  # above the roofs of the small city


def _settings(t_max: float, **kw) -> PlacementSettings:
    base = {"vdi_deg": 45.0, "options": {"resolution": 64}, "cpv_size": 20.0}
    base.update(kw)
    return PlacementSettings(t_max=t_max, model=primitive_model(), **base)


@pytest.fixture(scope="module")
def planned():
    city = procedural.city(36, seed=5, detail=6)
    placement = place(city, *VIEW, _settings(0.5 * city.triangle_count), keep_state=True)
    assert placement.summary["impostors"] > 0 and placement.summary["cpvs_solved"] == placement.summary["cpvs"]
    return city, placement, bake_placement(city, placement)


def test_the_state_survives_pickling_and_gives_the_same_placement(planned):
    _, placement, _ = planned
    again = PlannerState.loads(placement.state.dumps())
    assert again.placement().to_dict() == placement.to_dict()
    with pytest.raises(PlacementError, match="planner state"):
        PlannerState.loads(b"not a pickle")


def test_repair_puts_the_baked_figures_in_and_keeps_ids(planned):
    city, placement, impostors = planned
    state = PlannerState.loads(placement.state.dumps())
    first = state.repair({i: imp.stats for i, imp in impostors.items()})
    after = first.placement
    old = {imp["id"]: imp for imp in placement.impostors}
    for imp in after.impostors:
        if imp["id"] in old:  # an impostor keeps its id, objects and cell across rounds
            assert (imp["objects"], imp["cell"]) == (old[imp["id"]]["objects"], old[imp["id"]]["cell"])
            assert imp["baked"]["quads"] == impostors[imp["id"]].stats["quads"]
            assert imp["memory_bytes"] == impostors[imp["id"]].stats["texture_bytes"]
    assert all(i > max(old) for i in first.added)
    # Every CPV's time is recomputed with the real quads: redo the sum from the document.
    t_max = after.summary["t_max"]
    for cpv in after.cpvs:
        if cpv["status"] == "solved":
            assert cpv["time_after"] <= t_max * (1 + 1e-9)
    # No solved CPV draws an impostor slower than its node's geometry there, and no CPV got slower.
    for imp in state.greedy.chosen:
        assert all(g_p > t_p for g_p, t_p in imp.cpvs.values())
    assert after.summary["worst_after"] <= placement.summary["worst_before"]
    # The additions, baked and reported, end the rounds (bounded): a repeat with nothing new adds nothing.
    cells = {c["index"]: c for c in placement_cells(after)}
    added = {i: bake_impostor(city, cells[i], after.elements["cluster_triangles"]) for i in first.added}
    second = state.repair({i: imp.stats for i, imp in added.items()})
    third = state.repair({})
    assert third.added == [] and len(state.rounds) == 3
    assert second.placement.summary["cpvs_unsolved"] == third.placement.summary["cpvs_unsolved"]


def test_the_estimates_bias_corrects_the_candidates_not_chosen(planned):
    _, placement, impostors = planned
    state = PlannerState.loads(placement.state.dumps())
    before = state.cand.quads.copy()
    chosen = [imp.candidate for imp in state.greedy.chosen]
    step = state.repair({i: imp.stats for i, imp in impostors.items()})
    ratio = step.correction["quads"]
    baked = {state.candidate_of(i) for i in impostors}
    free = [k for k in range(state.cand.count) if k not in baked]
    assert free and np.allclose(state.cand.quads[free], before[free] * ratio)
    assert np.array_equal(
        state.cand.quads[sorted(baked)], [impostors[state.ids[k]].stats["quads"] for k in sorted(baked)]
    )
    # However far off, the greedy resumes: its earlier choices stay, in order, and it only adds.
    assert step.mode == "resumed"
    assert [imp.candidate for imp in state.greedy.chosen][: len(chosen)] == chosen


def test_a_corrected_candidate_over_the_largest_size_is_not_chosen(planned):
    _, placement, impostors = planned
    state = PlannerState.loads(placement.state.dumps())
    cap = float(np.median(state.cand.memory))
    object.__setattr__(state.settings, "max_impostor_bytes", cap)
    step = state.repair({i: imp.stats for i, imp in impostors.items()})
    assert all(state.cand.memory[state.candidate_of(i)] <= cap for i in step.added)


def test_a_state_pickled_before_the_newer_fields_still_loads(planned, monkeypatch):
    from dataclasses import fields

    from farfield.core.placement.candidates import Candidates
    from farfield.core.placement.cost_model import CostModel
    from farfield.core.placement.greedy import Greedy
    from farfield.core.placement.planner import PlacementSettings

    _, placement, _ = planned

    def before(name):  # what these slotted dataclasses pickled before their field ``name`` (and those after it) existed
        return lambda self: [getattr(self, f.name) for f in fields(self)][: [f.name for f in fields(self)].index(name)]

    assert [f.name for f in fields(PlacementSettings)][-4:] == ["max_impostor_bytes", "visibility", "also", "lod"]
    assert fields(CostModel)[-1].name == "quads_exponent" and [f.name for f in fields(Candidates)][-4:] == [
        "source",
        "prototype",
        "prototypes",
        "scale",
    ]
    monkeypatch.setattr(PlacementSettings, "__getstate__", before("max_impostor_bytes"))
    monkeypatch.setattr(CostModel, "__getstate__", before("quads_exponent"))
    monkeypatch.setattr(Candidates, "__getstate__", before("source"))
    monkeypatch.setattr(Greedy, "__getstate__", lambda self: {k: v for k, v in vars(self).items() if "atlas" not in k})
    data = placement.state.dumps()
    monkeypatch.undo()
    old = PlannerState.loads(data)
    assert old.settings.max_impostor_bytes == math.inf and old.settings.model.quads_exponent == 0.0
    assert old.settings.also is None and old.settings.visibility is False and old.cand.source is None
    assert old.settings.lod is False and old.greedy.own == 0
    assert (
        old.cand.prototype is None and old.cand.atlas_of(0) == -1 and old.greedy.memory_now().shape == (old.cand.count,)
    )
    parameters = old.placement().parameters
    assert parameters["cost_model"]["memory"]["quads_exponent"] == 0.0 and parameters["max_impostor_bytes"] is None


def test_the_database_is_written_read_and_looked_up(planned, tmp_path):
    city, placement, impostors = planned
    root = write_placement_database(tmp_path / "db", placement, impostors)
    with ImpostorDatabase(root) as db:
        assert db.placement is not None and db.technique == "layered"
        assert [c.index for c in db.cells] == [imp["id"] for imp in placement.impostors]
        for cell in db.cells:
            assert db.impostor(cell.index).quad_count == impostors[cell.index].quad_count
        entry = db.index["cells"][0]
        assert entry["objects"] == placement.impostors[0]["objects"] and entry["params"]["resolution"] == 64
        assert entry["figures"]["baked"]["quads"] == impostors[0].stats["quads"]
        lookup = PlacementLookup(db.index)
    # The centre of every CPV (its region's centre, its VDI's axis) finds that CPV and its impostors.
    for cpv in placement.cpvs:
        lo, hi = (np.asarray(v) for v in cpv["region"])
        v = cpv["vdi"]
        axis, _ = VDI(FACE_NAMES.index(v["face"]), v["level"], v["i"], v["j"]).cone()
        found = lookup.find(0.5 * (lo + hi), axis)
        assert found["cpv"] == cpv["id"] and found["impostors"] == cpv["impostors"]
        assert set(found["replaced"]) == {name for i in cpv["impostors"] for name in placement.impostors[i]["objects"]}
    # Looking up into the sky from above the roofs: no CPV, nothing replaced.
    assert lookup.find([60.0, 112.0, 60.0], [0.0, 1.0, 0.0])["status"] == UNDER_BUDGET
    with pytest.raises(ViewCellError, match="outside the placement's view space"):
        lookup.find([60.0, 0.0, 60.0], [1.0, 0.0, 0.0])
    with pytest.raises(ViewCellError, match="non-zero"):
        lookup.find([60.0, 112.0, 60.0], [0.0, 0.0, 0.0])
    json.dumps(db.index)  # plain JSON


def test_an_impostor_of_clusters_bakes_just_their_triangles():
    city = procedural.city(36, seed=5, detail=6)
    vertices, faces, offset = [], [], 0
    for obj in city.objects:
        vertices.append(obj.vertices), faces.append(obj.faces + offset)
        offset += len(obj.vertices)
    one = Scene.from_objects([SceneObject("everything", np.concatenate(vertices), np.concatenate(faces))], "one mesh")
    placement = place(one, *VIEW, _settings(0.5 * one.triangle_count))
    assert placement.elements["split"] == {"everything": placement.elements["count"]}
    imp = max(placement.impostors, key=lambda i: len(i["objects"]))
    cell = next(c for c in placement_cells(placement) if c["index"] == imp["id"])
    baked = bake_impostor(one, cell, placement.elements["cluster_triangles"])
    assert baked.stats["layers"] >= 1 and set(baked.parameters["objects"]) == set(imp["objects"])


def test_a_last_round_puts_the_figures_in_and_adds_nothing(planned):
    _, placement, impostors = planned
    state = PlannerState.loads(placement.state.dumps())
    step = state.repair({i: imp.stats for i, imp in impostors.items()}, extend=False)
    assert step.added == [] and step.mode == "resumed"
    for imp in step.placement.impostors:
        assert imp["baked"]["quads"] == impostors[imp["id"]].stats["quads"]
    # The bias is measured against the first estimates, whatever the corrections did since.
    assert all(state.estimated[i]["quads"] == state.first["quads"][state.candidate_of(i)] for i in impostors)


@pytest.mark.slow
def test_uncapped_depth_complexity_is_json_null_and_huge_directions_are_views(planned):
    city, _, _ = planned
    placement = place(city, *VIEW, _settings(0.5 * city.triangle_count, depth_complexity=float("inf")))
    assert placement.parameters["depth_complexity"] is None
    json.dumps(placement.to_dict(), allow_nan=False)
    index = {"placement": {"parameters": placement.parameters, "cpvs": placement.cpvs}, "cells": []}
    assert PlacementLookup(index).find([60.0, 112.0, 60.0], [1e200, 1e200, 0.0])["status"] in (
        "solved",
        UNDER_BUDGET,
        "unsolved",
    )


def test_an_impostor_no_cpv_draws_ships_without_a_bundle(planned, tmp_path):
    _, placement, impostors = planned
    doc = placement.to_dict()
    doc["impostors"][0]["cpvs"] = 0  # as after a repair round that replaced it by an ancestor
    cells = [
        {"index": imp["id"], "state": "done", "bundle": f"cells/{imp['id']:05d}/", "stats": impostors[imp["id"]].stats}
        for imp in doc["impostors"]
    ]
    entries = placement_index(doc, cells)["cells"]
    assert entries[0]["state"] == "unused" and entries[0]["bundle"] is None and entries[0]["figures"]["baked"]
    assert all(e["bundle"] for e in entries[1:]) and {e["state"] for e in entries[1:]} == {"done"}
