"""Instances of one prototype share one octahedral atlas in a frame-time placement (issue 56).

A small forest (32 trees of 2 prototypes, a hierarchy node per tree) seen from a square in its
middle: the trees beyond the octahedral distance bound get octahedral candidates.  The layered
impostors' memory is made dear (the primitive model's memory times 1,000) so that an octahedral
atlas wins on a tree where it is the only such impostor; the test is what instancing changes:
each prototype's atlas counted once, and less memory than layered-only and than the same forest
without instancing.  Nothing here asserts a wall-clock time.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from farfield.core import procedural
from farfield.core.placement.cost_model import CostModel, primitive_model
from farfield.core.placement.database import placement_index
from farfield.core.placement.greedy import Greedy
from farfield.core.placement.planner import PlacementSettings, place
from farfield.core.scene import Scene
from farfield.core.techniques import get_technique
from farfield.core.techniques.octahedral.estimate import atlas_bytes
from farfield.core.techniques.octahedral.instancing import local_cell
from farfield.core.viewcells import viewcell_from_dict

OCTAHEDRAL = {"grid": 9, "frame_resolution": 16, "padding": 2}
RESOLUTION = 32  # a tree's distance bound about 176 m
SIZE = 800.0
VIEW = (np.array([0.5 * SIZE - 10.0, 2.0, 0.5 * SIZE - 10.0]), np.array([0.5 * SIZE + 10.0, 2.0, 0.5 * SIZE + 10.0]))


def _model() -> CostModel:
    m = primitive_model()
    return CostModel(m.kind, m.geometry, m.impostor, (1e3 * m.memory[0], m.memory[1], m.memory[2]),
                     memory_exponent=m.memory_exponent, quads_exponent=m.quads_exponent)  # fmt: skip


def _place(scene: Scene, also, keep_state: bool = False):
    settings = PlacementSettings(t_max=0.3 * scene.triangle_count, model=_model(), options={"resolution": RESOLUTION},
                                 also=also, vdi_deg=45.0, cpv_size=10.0, cells="both", cluster_triangles=10**6,
                                 leaf_size=1)  # fmt: skip
    return place(scene, *VIEW, settings, keep_state=keep_state)


@pytest.fixture(scope="module")
def forest() -> Scene:
    return procedural.tree_forest(32, prototypes=2, size=SIZE, detail=1)


def test_the_procedural_forest_is_instanced(forest):
    instances = forest.instances()
    assert len(instances) == 2 and sum(len(v) for v in instances.values()) == 32
    tree = next(o for o in forest.objects if o.prototype is not None)
    moved = tree.local.vertices @ tree.instance_matrix[:3, :3].T + tree.instance_matrix[:3, 3]
    assert np.allclose(moved, tree.vertices)


def test_instances_share_their_prototypes_atlas_and_memory_falls(forest):
    atlas = atlas_bytes(get_technique("octahedral").options(OCTAHEDRAL, resolution=RESOLUTION))
    layered = _place(forest, None)
    shared = _place(forest, {"octahedral": OCTAHEDRAL}, keep_state=True)
    plain = Scene.from_objects(
        [replace(o, prototype=None, instance_matrix=None, local=None) for o in forest.objects], "no instancing"
    )
    alone = _place(plain, {"octahedral": OCTAHEDRAL})
    for p in (layered, shared, alone):
        assert p.summary["cpvs_solved"] == p.summary["cpvs"] > 0

    drawn = [imp for imp in shared.impostors if imp["cpvs"] and imp["technique"] == "octahedral"]
    rows = shared.summary["shared_atlases"]
    # Many trees drawn octahedral, each prototype's atlas counted once.
    assert len(drawn) >= 5 and len(rows) <= 2 and len(drawn) > len(rows)
    assert shared.summary["by_technique"]["octahedral"]["memory_bytes"] == len(rows) * atlas
    assert sorted(i for r in rows for i in r["impostors"]) == sorted(imp["id"] for imp in drawn)
    prototypes = forest.instances()
    for row in rows:  # one row per prototype: its instances' impostors, the owner among them
        mine = {names for names in prototypes[row["prototype"]]}
        assert row["owner"] in row["impostors"] and row["memory_bytes"] == atlas
        for imp in drawn:
            if imp["id"] in row["impostors"]:
                assert tuple(imp["objects"]) in mine
                assert imp["atlas"] == {"prototype": row["prototype"], "scale": imp["atlas"]["scale"],
                                        "shared": imp["atlas"]["shared"], "owner": row["owner"]}  # fmt: skip
    # The instances' cells are one cell of the prototype: one bake serves them all.
    by_name = {o.name: o for o in forest.objects}
    for row in rows:
        local = {
            json.dumps(
                local_cell(viewcell_from_dict(imp["cell"]), by_name[imp["objects"][0]].instance_matrix).to_dict()
            )
            for imp in drawn
            if imp["id"] in row["impostors"]
        }
        assert len(local) == 1, local
    # Memory falls against layered-only, and against the same forest without instancing (one atlas each).
    assert shared.memory_bytes < layered.memory_bytes
    assert not alone.summary.get("shared_atlases")
    oc_alone = alone.summary["by_technique"].get("octahedral", {"impostors": 0})["impostors"]
    assert oc_alone > len(rows) and shared.memory_bytes < alone.memory_bytes
    # The placement database says which impostors share an atlas.
    doc = shared.to_dict()
    index = placement_index(doc, [{"index": imp["id"], "state": "done", "bundle": None} for imp in doc["impostors"]])
    entries = {c["index"]: c for c in index["cells"]}
    assert all(entries[imp["id"]]["atlas"]["owner"] == imp["atlas"]["owner"] for imp in drawn)

    # The lazy heap (free candidates pushed again when an atlas is paid) chooses as re-scoring all does.
    state = shared.state
    runs = []
    for lazy in (True, False):
        greedy = Greedy(state.hierarchy, state.pv, state.cand, state.greedy.t_max)
        greedy.run(lazy=lazy)
        runs.append([imp.candidate for imp in greedy.chosen])
    assert runs[0] == runs[1] == [imp.candidate for imp in state.greedy.chosen]
