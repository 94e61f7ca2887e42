"""Instances of one prototype share one octahedral atlas in a frame-time placement (issue 56).

A small forest (32 trees of 2 prototypes, a hierarchy node per tree) seen from a square in its
middle: the trees beyond the octahedral distance bound get octahedral candidates.  The layered
impostors' memory is made dear (the primitive model's memory times 1,000) so that an octahedral
atlas wins on a tree where it is the only such impostor; the test is what instancing changes:
each prototype's atlas counted once, and less memory than layered-only and than the same forest
without instancing.  Then, nothing inflated, a forest of 48 trees seen from all sides where no
single tree justifies the atlas: the greedy ranks an unpaid atlas as a group of its instances and
takes it (the old myopic rule, ``Greedy(groups=False)``, does not), and memory falls against
layered-only.  And on random small instances: the lazy heap with groups chooses what full
re-ranking chooses.  Nothing here asserts a wall-clock time.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from test_placement import _instance

from farfield.core import procedural
from farfield.core.placement.candidates import OUTSIDE_SPHERE, Candidates
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


# An atlas no single instance justifies, taken for its instances (the greedy ranks an unpaid
# atlas as a group): the primitive model as it is (nothing inflated), a small atlas, box cells.
SMALL = {"grid": 5, "frame_resolution": 8, "padding": 1}  # 10,000 bytes


def _place_wide(scene: Scene, also, keep_state: bool = False):
    """48 trees seen from the middle 480 m of an 800 m forest: 16 regions, each tree seen from all
    sides (a layered impostor per box cell, an octahedral one for every far region)."""
    lo, hi = np.array([160.0, 2.0, 160.0]), np.array([640.0, 2.0, 640.0])
    settings = PlacementSettings(t_max=0.3 * scene.triangle_count, model=primitive_model(), options={"resolution": RESOLUTION},
                                 also=also, vdi_deg=90.0, cpv_size=160.0, cells="boxes", cluster_triangles=10**6,
                                 leaf_size=1)  # fmt: skip
    return place(scene, lo, hi, settings, keep_state=keep_state)


def test_an_atlas_no_single_instance_justifies_is_taken_for_its_instances():
    forest = procedural.tree_forest(48, prototypes=2, size=SIZE, detail=1)
    layered = _place_wide(forest, None)
    shared = _place_wide(forest, {"octahedral": SMALL}, keep_state=True)
    atlas = atlas_bytes(get_technique("octahedral").options(SMALL, resolution=RESOLUTION))
    state = shared.state
    # Every layered impostor alone is far cheaper than the atlas: no single tree's saving pays it.
    assert layered.memory_bytes / layered.summary["impostors"] < 0.1 * atlas
    # The same budget everywhere: what layered-only solves stays solved.
    assert layered.summary["cpvs_solved"] == layered.summary["cpvs"] > 0
    assert all(s["status"] == "solved" for s in shared.cpvs)
    # Octahedral impostors drawn, each atlas counted once, and memory falls against layered-only.
    rows = shared.summary["shared_atlases"]
    octahedral = shared.summary["by_technique"]["octahedral"]
    assert octahedral["impostors"] >= 10 and 1 <= len(rows) <= 2
    assert octahedral["memory_bytes"] == len(rows) * atlas
    assert shared.memory_bytes < layered.memory_bytes
    assert state.greedy.memory_bytes() == pytest.approx(shared.memory_bytes)
    # The old myopic rule (each candidate of an unpaid atlas ranked alone, paying the whole atlas)
    # on the same candidates takes no octahedral impostor and ends as dear as layered-only.
    myopic = Greedy(state.hierarchy, state.pv, state.cand, state.greedy.t_max, groups=False)
    myopic.run()
    drawn = [c.candidate for k, c in enumerate(myopic.chosen) if k not in myopic.deleted]
    assert not any(state.cand.kind[i] == OUTSIDE_SPHERE for i in drawn)
    assert myopic.memory_bytes() == pytest.approx(layered.memory_bytes)


def _synthetic(seed: int):
    """test_placement's random small instance (6 unit boxes, a hierarchy leaf each, CPVs seeing
    them all, layered candidates on random nodes) with shared candidates added on the leaves: two
    atlases, each dearer than any layered candidate, an instance saving a random share of its
    leaf's time in the CPVs it serves."""
    h, pv, cand, t_max = _instance(seed, candidates=10, cpvs=6)
    rng = np.random.default_rng(1000 + seed)
    cpvs = pv.count
    entry = pv.entry_time.reshape(cpvs, -1)  # in the hierarchy's order
    cum = np.concatenate([np.zeros((cpvs, 1)), np.cumsum(entry, axis=1)], axis=1)
    leaves = np.flatnonzero(h.leaf)
    atlas = rng.integers(0, 2, leaves.size)
    served, g, ti = [], [], []
    sizes = []
    for n in leaves:
        s = np.flatnonzero(rng.random(cpvs) < 0.7)
        sizes.append(s.size)
        gn = cum[s, h.end[n]] - cum[s, h.start[n]]
        served.append(s), g.append(gn), ti.append(rng.uniform(0.2, 0.6) * gn)
    served, g, ti = (np.concatenate(rows) for rows in (served, g, ti))
    m = cand.count + leaves.size
    shared = Candidates(
        node=np.concatenate([cand.node, leaves]), kind=np.zeros(m, dtype=np.int64), cells=tuple([None] * m),
        memory=np.concatenate([cand.memory, np.where(atlas == 0, 60.0, 80.0)]), layers=np.ones(m), texels=np.ones(m), quads=np.ones(m),
        served_offsets=np.concatenate([cand.served_offsets, cand.served_offsets[-1] + np.cumsum(sizes)]),
        served=np.concatenate([cand.served, served]), g=np.concatenate([cand.g, g]), ti=np.concatenate([cand.ti, ti]), stats={},
        prototype=np.concatenate([np.full(cand.count, -1), atlas]), prototypes=(("a", 0), ("a", 1)),
    )  # fmt: skip
    return h, pv, shared, t_max


@pytest.mark.parametrize("seed", range(30))
def test_grouped_atlases_lazy_equals_full_re_ranking_and_memory_counts_each_atlas_once(seed):
    h, pv, cand, t_max = _synthetic(seed)
    lazy, full = Greedy(h, pv, cand, t_max), Greedy(h, pv, cand, t_max)
    lazy.run(lazy=True)
    full.run(lazy=False)
    assert [c.candidate for c in lazy.chosen] == [c.candidate for c in full.chosen]
    assert np.array_equal(lazy.t, full.t)
    drawn = [c.candidate for k, c in enumerate(lazy.chosen) if k not in lazy.deleted]
    own = sum(cand.memory[i] for i in drawn if cand.prototype[i] < 0)
    atlases = {int(cand.prototype[i]) for i in drawn if cand.prototype[i] >= 0}
    assert lazy.memory_bytes() == pytest.approx(own + sum({0: 60.0, 1: 80.0}[a] for a in atlases))
    # Against the myopic rule on the same instance: no CPV it solves is left unsolved.
    myopic = Greedy(h, pv, cand, t_max, groups=False)
    myopic.run()
    assert not np.any((myopic.t <= t_max * (1 + 1e-9)) & (lazy.t > t_max * (1 + 1e-9)))
    for p in range(pv.count):  # no two drawn impostors on one path of the hierarchy
        nodes = [lazy.chosen[k].node for k in lazy.drawn[p]]
        assert not any(h.is_ancestor_or_self(a, b) for a in nodes for b in nodes if a != b)
