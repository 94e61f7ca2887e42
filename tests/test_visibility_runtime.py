"""The runtime uses the potentially visible sets (issue 57 item 2): a placement planned with
visibility stores each smallest region's PVS in its database, the reference runtime and the
walkthrough draw only those elements, the walkthrough counts what a PVS dropped as hole pixels, and
``farfield lookup`` answers the PVS.  Real EGL rendering of a small scene: a wall between the view
space and a dense block."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
from click.testing import CliRunner
from scenes import write_scene

from farfield.cli.main import _register, cli
from farfield.core import procedural
from farfield.core.impostor.database import ImpostorDatabase
from farfield.core.placement.cost_model import primitive_model
from farfield.core.placement.database import PlacementLookup, write_placement_database
from farfield.core.placement.hierarchy import PlacementError
from farfield.core.placement.planner import PlacementSettings, place
from farfield.core.placement.runtime import PlacementRenderer
from farfield.core.quality.walkthrough import placement_walkthrough
from farfield.core.scene import Scene, SceneObject
from farfield.core.visibility.region_sets import StoredSets, decode_set, encode_set, raw_size, stored_size

LO, HI = [-10.0, -2.0, -10.0], [0.0, 2.0, 10.0]  # the view space, in front of the wall (x = 10..11)
# Views towards the wall: the block behind it (x = 20..24) lies in every frustum.
POSITIONS = np.array([[-5.0, 0.0, 0.0], [-9.0, 1.0, -8.0], [-1.0, -1.0, 9.0], [-2.0, 0.5, -3.0]])
FORWARDS = np.array([[1.0, 0.0, 0.0], [1.0, 0.1, 0.2], [1.0, 0.0, -0.3], [1.0, -0.05, 0.1]])


def _box(name, low, high, n=1) -> SceneObject:
    v, f = procedural.subdivided_box(low, high, n)
    return SceneObject(name, v, f)


def _walled() -> Scene:
    return Scene.from_objects(
        [
            _box("wall", (10, -50, -50), (11, 50, 50)),
            _box("hidden", (20, -2, -2), (24, 2, 2), 24),
            _box("beside", (-5, 0, 30), (-4, 1, 31)),
        ],
        "walled",
    )


def _settings(scene: Scene, visibility: bool) -> PlacementSettings:
    return PlacementSettings(t_max=0.5 * scene.triangle_count, model=primitive_model(), options={"resolution": 64},
                             vdi_deg=45.0, cpv_size=10.0, visibility=visibility)  # fmt: skip


@pytest.fixture(scope="module")
def walled(tmp_path_factory):
    """(scene, placement with visibility, its database folder)."""
    scene = _walled()
    placement = place(scene, LO, HI, _settings(scene, True))
    root = write_placement_database(tmp_path_factory.mktemp("pvs") / "db", placement, {})
    return scene, placement, root


def _with_index(root, tmp_path, change) -> ImpostorDatabase:
    """A copy of the database at ``root`` whose index ``change`` edited."""
    index = json.loads((root / "index.json").read_text())
    change(index)
    (tmp_path / "index.json").write_text(json.dumps(index))
    return ImpostorDatabase(tmp_path)


def test_compact_sets_round_trip():
    rng = np.random.default_rng(3)
    for count in (0, 1, 7, 8, 9, 130, 5000):
        for share in (0.0, 0.2, 1.0):
            members = np.flatnonzero(rng.random(count) < share)
            text = encode_set(members, count)
            assert decode_set(text, count).tolist() == members.tolist()
    # A dense or sparse set of 5,000 elements takes a few dozen bytes, not 625.
    assert len(encode_set(np.arange(5000), 5000)) < 60 and len(encode_set([], 5000)) < 60
    with pytest.raises(PlacementError, match="bytes, not"):
        decode_set(encode_set([1], 9), 20)


def test_the_database_holds_a_pvs_without_the_hidden_block(walled):
    scene, placement, root = walled
    hidden = {name for name in placement.visibility["names"] if name.startswith("hidden")}
    assert hidden and placement.visibility["grid"]["counts"] == [1, 1, 2]
    with ImpostorDatabase(root) as db:
        section = db.placement["visibility"]
        assert stored_size(section) < raw_size(section)
        sets = StoredSets(section)
        names = section["names"]
        for region in range(len(section["sets"])):
            kept = {names[i] for i in sets.pvs(region)}
            assert "wall" in kept and not kept & hidden
        lookup = PlacementLookup(db.index)
        answer = lookup.find(POSITIONS[0], FORWARDS[0])["pvs"]
        assert answer["elements"] == ["wall", "beside"] and answer["of"] == len(names)
        assert lookup.pvs_answer([50.0, 0.0, 0.0]) is None  # outside every region
    # Planned without visibility, the document has no PVS.
    assert "visibility" not in place(scene, LO, HI, _settings(scene, False)).to_dict()


def test_the_runtime_draws_only_the_pvs_and_the_walkthrough_finds_no_hole(walled, tmp_path):
    scene, _, root = walled
    with ImpostorDatabase(root) as db, PlacementRenderer(scene, db) as runtime:
        for p, d in zip(POSITIONS, FORWARDS):
            camera, _, culled = runtime.prepare(p, d)
            _, _, every = runtime.prepare(p, d, camera=camera, pvs=False)
            assert culled.pvs == 2 and every.pvs is None
            assert culled.elements < every.elements and culled.geometry_triangles < every.geometry_triangles
            assert culled.pvs_culled == every.elements - culled.elements
        result = placement_walkthrough(scene, db, POSITIONS, FORWARDS, repeats=1)
    s = result["summary"]
    assert s["frames_with_pvs"] == len(POSITIONS) and s["pvs_culled_mean"] > 100
    assert s["hole_pixels"] == 0 and s["pvs_dropped_pixels"] == 0
    assert all(f["geometry_pixels"] > 0 for f in result["frames"])  # the wall is in every frame
    # A database without the stored sets reads as before: every element in the frustum is drawn.
    with _with_index(root, tmp_path, lambda index: index["placement"].pop("visibility")) as db:
        with PlacementRenderer(scene, db) as runtime:
            _, _, fig = runtime.prepare(POSITIONS[0], FORWARDS[0])
            assert fig.pvs is None and fig.elements == runtime.elements.count - 1  # all but "beside" (behind)


def test_a_pvs_that_drops_a_visible_element_is_counted_as_holes(walled, tmp_path):
    scene, _, root = walled

    def drop_the_wall(index):  # the wrong PVS: every element but the wall, which every view sees
        section = index["placement"]["visibility"]
        everything = np.arange(section["elements"])
        section["sets"] = [encode_set(everything[1:], section["elements"]) for _ in section["sets"]]
        assert section["names"][0] == "wall"

    with _with_index(root, tmp_path, drop_the_wall) as db:
        result = placement_walkthrough(scene, db, POSITIONS, FORWARDS, repeats=1)
    frames = result["frames"]
    assert all(f["pvs_dropped_pixels"] > 0 and f["hole_pixels"] >= f["pvs_dropped_pixels"] for f in frames)
    # Where the block behind the wall shows instead, the runtime's image is covered: still holes.
    assert result["summary"]["hole_pixels"] > 0 and result["summary"]["pvs_dropped_pixels"] > 0


def test_another_scenes_elements_are_refused(walled):
    _, _, root = walled
    other = Scene.from_objects(
        [_box("wall", (10, -50, -50), (11, 50, 50)), _box("beside", (-5, 0, 30), (-4, 1, 31))], "o"
    )
    with ImpostorDatabase(root) as db, pytest.raises(PlacementError, match="placement's scene"):
        PlacementRenderer(other, db)


def test_farfield_lookup_shows_the_pvs(walled):
    _, _, root = walled
    _register()
    runner = CliRunner()
    at = ["--at", "-5", "0", "0", "--look", "1", "0", "0"]
    done = runner.invoke(cli, ["lookup", str(root), *at, "--json"])
    assert done.exit_code == 0, done.output
    assert json.loads(done.output)["pvs"]["elements"] == ["wall", "beside"]
    text = runner.invoke(cli, ["lookup", str(root), *at])
    assert text.exit_code == 0, text.output
    assert "potentially visible set of region 1" in text.output and "2 of 130 elements" in text.output
    assert "wall, beside" in text.output


def test_stored_sets_refuse_what_does_not_read():
    good = {"encoding": "zlib-packbits-base64", "elements": 2, "grid": {"lo": [0, 0, 0], "hi": [1, 1, 1], "counts": [1, 1, 1]},
            "sets": [encode_set([0], 2)]}  # fmt: skip
    assert StoredSets(good).at([0.5, 0.5, 0.5]).tolist() == [0]
    for bad, message in (
        ({**good, "encoding": "ranges"}, "unknown potentially visible set encoding"),
        ({**good, "sets": []}, "0 stored potentially visible sets"),
        ({k: v for k, v in good.items() if k != "grid"}, "do not read"),
    ):
        with pytest.raises(PlacementError, match=message):
            StoredSets(copy.deepcopy(bad))


def test_walkthrough_command_culls_unless_told_not_to(walled, tmp_path):
    """From the scene written as GLB (its objects perhaps in another order: the runtime maps the
    stored sets by element name)."""
    scene, _, root = walled
    _register()
    path = write_scene(scene, tmp_path, "glb", "walled")
    runner = CliRunner()
    views = tmp_path / "path.json"
    views.write_text(
        json.dumps([{"position": p.tolist(), "forward": d.tolist()} for p, d in zip(POSITIONS[:3], FORWARDS)])
    )
    args = ["walkthrough", str(root), str(path), "--path", str(views), "--repeats", "1"]
    culled = runner.invoke(cli, [*args, "--json"])
    assert culled.exit_code == 0, culled.output
    s = json.loads(culled.output)["summary"]
    assert s["frames_with_pvs"] == 3 and s["hole_pixels"] == 0 and s["pvs_dropped_pixels"] == 0
    every = runner.invoke(cli, [*args, "--json", "--no-pvs"])
    assert every.exit_code == 0, every.output
    assert "frames_with_pvs" not in json.loads(every.output)["summary"]
    assert json.loads(every.output)["summary"]["triangles_mean"] > s["triangles_mean"]
    text = runner.invoke(cli, args)
    assert text.exit_code == 0 and "visibility: 3 frames drew only their region's PVS" in text.output
