"""Octahedral impostors as a frame-time placement candidate (issue 56, Build 5).

The estimate (no bake) bounds the bake's accuracy distance and gives its memory exactly; a placement
with octahedral candidates beside layered ones chooses between them by memory per saving, draws an
octahedral impostor only in problem views whose whole region lies beyond its accuracy distance,
stores which technique each impostor is, and its runtime draws the octahedral cards (real EGL).
Nothing here asserts a wall-clock time.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from click.testing import CliRunner
from scenes import write_scene

from farfield.cli.main import _register, cli
from farfield.core import procedural
from farfield.core.impostor.database import ImpostorDatabase
from farfield.core.placement.cost_model import CostModel, primitive_model
from farfield.core.placement.database import bake_placement, placement_cells, write_placement_database
from farfield.core.placement.hierarchy import PlacementError
from farfield.core.placement.planner import PlacementSettings, place
from farfield.core.placement.runtime import PlacementRenderer
from farfield.core.quality.walkthrough import random_views
from farfield.core.scene import Scene
from farfield.core.techniques import get_technique
from farfield.core.techniques.octahedral.estimate import atlas_bytes, distance_bound
from farfield.core.techniques.octahedral.runtime import OctahedralRenderer
from farfield.core.viewcells import SphereOutsideCell, viewcell_from_dict

OCTAHEDRAL = {"grid": 9, "frame_resolution": 16, "padding": 2}
RESOLUTION = 64
# Far from the six trees (about 23 x 11 x 21 m): beyond the octahedral bound of the whole group (864 m at 64 px).
VIEW = (np.array([1000.0, 5.0, -20.0]), np.array([1040.0, 10.0, 40.0]))


def _trees() -> Scene:
    return procedural.tree_forest(6, prototypes=3, size=20.0, detail=4)


def _dear_layers(model: CostModel) -> CostModel:
    """``model`` with a layered impostor's estimated memory a million times dearer (octahedral
    candidates keep their own, exact memory): the greedy then prefers octahedral ones."""
    return CostModel(model.kind, model.geometry, model.impostor, (1e6 * model.memory[0], model.memory[1], model.memory[2]),
                     memory_exponent=model.memory_exponent, quads_exponent=model.quads_exponent)  # fmt: skip


def _settings(scene: Scene, model: CostModel, also=None) -> PlacementSettings:
    return PlacementSettings(t_max=0.3 * scene.triangle_count, model=model, options={"resolution": RESOLUTION}, also=also,
                             vdi_deg=45.0, cpv_size=20.0, cells="both", cluster_triangles=10**6)  # fmt: skip


@pytest.mark.parametrize(
    "options",
    [
        {"grid": 5, "frame_resolution": 16},
        {"grid": 6, "frame_resolution": 32, "padding": 2},
        {"grid": 5, "frame_resolution": 16, "channels": "albedo+normal+depth"},  # two-sided columns: the gap's bound
        {"grid": 4, "frame_resolution": 16, "channels": "albedo+normal+depth"},  # one-sided
    ],
)
def test_the_estimate_bounds_the_bakes_accuracy_distance_and_gives_its_memory(options):
    technique = get_technique("octahedral")
    values = technique.options(options, resolution=RESOLUTION)
    forest = procedural.tree_forest(3, prototypes=3, size=10.0, detail=2)
    parts = [forest.subset([name]) for name in forest.names[1:]] + [
        Scene.from_objects([procedural.box_object("slab", [0.0, 0.0, 0.0], [4.0, 0.5, 1.0])], source="slab"),
        forest,  # several objects and the ground
    ]
    for part in parts:
        bound = distance_bound(values, part.bounds)
        cell = SphereOutsideCell(0.5 * (part.bounds[0] + part.bounds[1]), bound.distance)
        impostor = technique.bake(part, cell, values)
        assert impostor.stats["accuracy_distance"] <= bound.distance, (part.names, options)
        assert impostor.stats["texture_bytes"] + sum(
            p.nbytes for p in impostor.channels.get("normal", [])
        ) == atlas_bytes(values)


def test_the_estimate_refuses_a_cell_nearer_than_its_bound():
    technique = get_technique("octahedral")
    options = technique.options(OCTAHEDRAL, resolution=RESOLUTION)
    part = np.array([[0.0, 0.0, 0.0], [2.0, 10.0, 2.0]])
    far = distance_bound(options, part).distance
    centre = part.mean(axis=0)
    assert technique.estimate(SphereOutsideCell(centre, far), options, part) == (81.0, 256.0)
    with pytest.raises(Exception, match="within one pixel beyond"):
        technique.estimate(SphereOutsideCell(centre, 0.9 * far), options, part)


def test_octahedral_candidates_compete_by_memory_per_saving_and_serve_only_views_beyond_their_distance():
    scene = _trees()
    alone = place(scene, *VIEW, _settings(scene, primitive_model()))
    cheap = place(scene, *VIEW, _settings(scene, primitive_model(), {"octahedral": OCTAHEDRAL}))
    dear = place(scene, *VIEW, _settings(scene, _dear_layers(primitive_model()), {"octahedral": OCTAHEDRAL}))
    # Octahedral candidates are offered (one per node whose problem views lie beyond its bound) ...
    assert cheap.summary["candidates"] > alone.summary["candidates"]
    # ... and lose to layered ones of a few hundred bytes: the same choice as without them.
    assert "octahedral" not in cheap.summary["by_technique"] and cheap.memory_bytes == alone.memory_bytes
    assert all(imp["technique"] == "layered" for imp in cheap.impostors)
    # With layered memory made dear, octahedral ones win and meet the budget.
    assert dear.summary["cpvs_solved"] == dear.summary["cpvs"] > 0
    chosen = [imp for imp in dear.impostors if imp["cpvs"]]
    assert chosen and all(imp["technique"] == "octahedral" and imp["kind"] == "outside-sphere" for imp in chosen)
    options = get_technique("octahedral").options(OCTAHEDRAL, resolution=RESOLUTION)
    for imp in chosen:
        cell = viewcell_from_dict(imp["cell"])
        assert imp["memory_bytes"] == atlas_bytes(options)
        for cpv in dear.cpvs:  # every CPV drawing it lies wholly beyond its cell's radius
            if imp["id"] in cpv["impostors"]:
                lo, hi = np.asarray(cpv["region"][0]), np.asarray(cpv["region"][1])
                gap = np.maximum(0.0, np.maximum(lo - cell.centre, cell.centre - hi))
                assert np.linalg.norm(gap) >= cell.radius
    assert dear.summary["by_technique"]["octahedral"]["impostors"] == len(chosen)
    assert dear.parameters["also"]["octahedral"]["grid"] == 9
    # Each cell bakes with its own technique's options and the placement's resolution.
    cells = placement_cells(dear)
    assert {c["technique"] for c in cells} == {"octahedral"}
    assert all(c["params"]["resolution"] == RESOLUTION and c["params"]["options"]["grid"] == 9 for c in cells)


def test_the_placement_runtime_draws_octahedral_cards_as_the_octahedral_runtime_does(tmp_path):
    scene = _trees()
    placement = place(
        scene, *VIEW, _settings(scene, _dear_layers(primitive_model()), {"octahedral": OCTAHEDRAL}), keep_state=True
    )
    impostors = bake_placement(scene, placement)
    for imp in placement.impostors:  # the bake's own distance never exceeds the cell the planner gave it
        if imp["cpvs"]:
            assert impostors[imp["id"]].stats["accuracy_distance"] <= imp["cell"]["radius"]
    # The check-and-repair round with the baked figures: an octahedral estimate is exact, nothing moves.
    checked = placement.state.repair({i: imp.stats for i, imp in impostors.items()}, extend=False).placement
    assert checked.memory_bytes == placement.memory_bytes and checked.summary["cpvs_solved"] == checked.summary["cpvs"]
    assert checked.summary["by_technique"] == placement.summary["by_technique"]
    root = write_placement_database(tmp_path / "db", placement, impostors)
    index = json.loads((root / "index.json").read_text())
    assert {c["technique"] for c in index["cells"] if c["bundle"]} == {"octahedral"}
    assert all(c["kind"] == "outside-sphere" for c in index["cells"])
    positions, _ = random_views(*VIEW, 3, seed=3)
    with ImpostorDatabase(root) as db, PlacementRenderer(scene, db) as runtime:
        for p in positions:
            forward = np.array([11.0, 5.0, 10.0]) - p  # towards the trees, 256 px: several pixels wide
            camera, draws, figures = runtime.prepare(p, forward, resolution=256)
            assert figures.status == "solved" and figures.impostors == 1 and figures.elements == 0
            mixed = runtime.render(camera, draws)
            cell = next(i for i in db.placement["cpvs"][figures.cpv]["impostors"])
            with OctahedralRenderer(db.impostor(cell)) as alone:
                expected = alone.render(camera)
            assert (mixed[..., 3] > 0).sum() > 4 and np.array_equal(mixed, expected)
            # With the geometry drawn too (the card depth-tested against it), the image covers both.
            both = runtime.render(camera, runtime.prepare(p, forward, plain=True, camera=camera)[1] + draws[-1:])
            assert ((both[..., 3] > 0) >= (mixed[..., 3] > 0)).all()


def test_place_command_takes_octahedral_candidates_and_refuses_bad_ones(tmp_path):
    _register()
    path = write_scene(procedural.tree_forest(3, prototypes=2, size=10.0), tmp_path, "glb", "trees")
    runner = CliRunner()
    args = ["place", str(path), "--view-space", ",".join(map(str, [*VIEW[0], *VIEW[1]])), "--primitives", "100",
            "--resolution", str(RESOLUTION), "--vdi-deg", "45", "--cpv-size", "40", "--cells", "boxes", "--quiet"]  # fmt: skip
    result = runner.invoke(
        cli, [*args, "--also", "octahedral:grid=9,frame_resolution=16,padding=2", "--out", str(tmp_path / "p.json")]
    )
    assert result.exit_code == 0, result.output
    assert "impostors by technique:" in result.output and "octahedral" in result.output
    document = json.loads((tmp_path / "p.json").read_text())
    assert document["parameters"]["also"]["octahedral"]["frame_resolution"] == 16
    for bad, message in (
        (["--also", "nope"], "unknown technique 'nope'"),
        (["--also", "octahedral:grid"], "expected TECHNIQUE:NAME=VALUE"),
        (["--also", "layered"], "names the placement's own technique"),
        (["--also", "envmap"], "cannot be placed"),
        (["--also", "octahedral:channels=albedo+normal"], "colour only"),
    ):
        out = runner.invoke(cli, [*args, *bad])
        assert out.exit_code != 0 and message in out.output, (bad, out.output)
        assert len(out.output.strip().splitlines()) == 1, out.output


def test_a_placement_job_stores_its_octahedral_candidates_options_or_refuses_them():
    from farfield.service.placement.admission import placement_params
    from farfield.service.placement.frame_time import planner_settings
    from farfield.service.placement.schema import PlacementSpec

    base = {"view_space": {"lo": [0, 0, 0], "hi": [10, 2, 10]}, "budget": {"primitives": 100}}
    params = placement_params("layered", {}, 64, None, PlacementSpec(**base, also={"octahedral": {"grid": 9}}))
    assert (
        params["placement"]["also"]["octahedral"]["grid"] == 9
        and "resolution" not in params["placement"]["also"]["octahedral"]
    )
    settings, _, _ = planner_settings(params)
    assert settings.also["octahedral"]["grid"] == 9
    assert (
        "also" not in placement_params("layered", {}, 64, None, PlacementSpec(**base))["placement"]
    )  # stored as before
    for also, message in (
        ({"mystery": {}}, "unknown techniques ['mystery']"),
        ({"octahedral": {"resolution": 32}}, "the job's own fields"),
        ({"octahedral": {"grid": 1}}, "grid"),
        ({"layered": {}}, "names the placement's own technique"),
    ):
        with pytest.raises(PlacementError if message != "grid" else Exception, match=re.escape(message)):
            placement_params("layered", {}, 64, None, PlacementSpec(**base, also=also))
