"""Layered environment-map impostors (seed 002): bake, near field, compression, runtime, database, walkthrough.

Everything renders for real (EGL: llvmpipe here, the NVIDIA driver on a GPU machine).  The hole and
error checks compare the reference runtime (near field + impostor quads) with the full scene drawn
by the same renderer from viewpoints inside the cell, corners included, in every recorded
direction and the diagonals between them.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from farfield.cli.main import _register, cli
from farfield.core.errors import LayerPlanError, ViewCellError
from farfield.core.impostor.database import ImpostorDatabase, write_database
from farfield.core.quality.evaluation import impostor_objects
from farfield.core.quality.walkthrough import generate_path, walkthrough, write_plot
from farfield.core.render.raster import MeshRenderer
from farfield.core.scene import Scene, SceneObject
from farfield.core.techniques.envmap.arrangement import near_field_distance
from farfield.core.techniques.envmap.gap_fill import fill_gaps
from farfield.core.techniques.envmap.near_field import NearField, near_field
from farfield.core.techniques.envmap.runtime import (
    NEAR_FIELD_RUN,
    QUAD_RUN,
    EnvmapCellRenderer,
    camera_at,
    evaluate_envmap,
    nearest_first,
    view_directions,
)
from farfield.core.techniques.envmap.technique import EnvmapOptions, bake_envmap, face_plan, plan_envmap
from farfield.core.viewcells import BoxCell, grid_boxes
from tests.scenes import box_object, city, real_scene, write_scene

pytestmark = pytest.mark.filterwarnings("ignore::farfield.core.scene.SceneWarning")

SMALL = dict(resolution=96, fov_deg=90.0, layers=12)


@pytest.fixture(scope="module")
def town() -> Scene:
    """The 300-building city with its ground 1 cm below the buildings' floors.

    Two of ``town_cell``'s corners lie inside buildings, whose floors would otherwise be coplanar
    with the ground.  Coplanar overlaps z-fight, and which surface wins depends on the GPU and on
    clipping: on the NVIDIA driver (H200, 2026-12-04) the near field's clip planes let the ground
    win over a floor that the unclipped full scene showed (22 of 255 mean error in that view, on
    llvmpipe 0.3), which says nothing about the impostor.  One centimetre is ~10x the depth
    buffer's resolution at the near field's 42 m."""
    scene = city(300)
    ground, *buildings = scene.objects
    assert ground.name == "ground"
    lowered = replace(ground, vertices=ground.vertices - np.array([0.0, 0.01, 0.0]))
    return Scene.from_objects([lowered, *buildings], source=scene.source)


@pytest.fixture(scope="module")
def coplanar_town() -> Scene:
    """The city as made, its buildings' floors coplanar with the ground: depth ties that the
    runtime must resolve as the order it was given resolves them."""
    return city(300)


@pytest.fixture(scope="module")
def town_cell() -> BoxCell:
    # Between lots of the 18 x 18 city, at eye height, 10 units wide; buildings within a few metres.
    return BoxCell.from_center([170.0, 5.0, 170.0], 10.0)


@pytest.fixture(scope="module")
def town_impostor(town, town_cell):
    return bake_envmap(town, town_cell, EnvmapOptions(**SMALL))


def _assert_faithful(result: dict) -> None:
    totals = result["totals"]
    assert totals["views"] > 0 and totals["geometry_pixels"] > 0
    assert totals["hole_pixels"] == 0, [r["stats"]["hole_pixels"] for r in result["views"]]
    views = [r["stats"] for r in result["views"]]
    # Per pixel where both cover: what differs is resampling at silhouettes and texel edges.  Measured
    # (llvmpipe, the four scenes below): means 0.09-1.63 over all views, at most 22.7 in one view
    # (the worst views see only ~700 pixels of geometry, mostly silhouette).
    assert totals["colour_error_mean"] < 2.5
    assert all(v["colour_error_mean"] < 30.0 for v in views)
    # Within one pixel (forgiving a one-pixel shift): 0.03-0.46 over all views, at most 7.5 in one.
    assert totals["colour_error_1px_mean"] < 1.0
    assert all(v["colour_error_1px_mean"] < 8.0 for v in views)


@pytest.mark.slow
def test_city_has_no_holes_from_anywhere_in_the_cell(town, town_impostor):
    stats = town_impostor.stats
    assert stats["faces"] == 6 and stats["quads"] > 0 and stats["near_field_triangles"] > 0
    _assert_faithful(evaluate_envmap(town, town_impostor, random_count=2, seed=1))


@pytest.mark.slow
def test_replicated_real_scene_has_no_holes():
    duck = real_scene("duck/duck.obj")
    objects = []
    for i in range(5):
        for j in range(5):
            for obj in duck.objects:
                offset = np.array([3.0 * i, 0.0, 3.0 * j])
                objects.append(
                    SceneObject(
                        f"{obj.name}_{i}_{j}",
                        obj.vertices + offset,
                        obj.faces,
                        obj.uv,
                        obj.vertex_colors,
                        obj.base_color,
                        obj.texture,
                        obj.alpha_cutoff,
                    )
                )
    scene = Scene.from_objects(objects, source="duck-5x5")
    cell = BoxCell.from_center([4.5, 0.8, 4.5], 0.5)  # between four ducks
    impostor = bake_envmap(scene, cell, EnvmapOptions(resolution=96, fov_deg=90.0, layers=8))
    assert impostor.stats["quads"] > 0
    _assert_faithful(evaluate_envmap(scene, impostor, random_count=1, seed=2))


def _long_beam() -> tuple[Scene, BoxCell]:
    """A long deck just below the cell, crossing the near-field border along +x, and a far wall."""
    beam = box_object("beam", (2.0, -1.5, -10.0), (400.0, -1.2, 10.0), (0.9, 0.2, 0.1, 1.0))  # within the ±x faces
    wall = box_object("wall", (500.0, -50.0, -50.0), (501.0, 50.0, 50.0), (0.2, 0.3, 0.8, 1.0))
    return Scene.from_objects([beam, wall], source="beam"), BoxCell.from_center([0.0, 0.0, 0.0], 2.0)


def test_near_field_border_neither_gap_nor_double_drawn():
    scene, cell = _long_beam()
    impostor = bake_envmap(
        scene, cell, EnvmapOptions(resolution=128, fov_deg=90.0, layers=6, directions=("+x", "-x", "+y", "-y"))
    )
    near = NearField.from_dict(impostor.parameters["near_field"])
    assert 2.0 < near.half_size < 400.0, "the beam must cross the border"
    assert list(near.ranges) == ["beam"] and 0 < near.triangle_count < 12  # the far end cap is outside
    _assert_faithful(evaluate_envmap(scene, impostor, random_count=2, seed=3))

    # Seen from the top of the cell along the deck, zoomed onto the border: the near field (clipped
    # to its cube) and the layers meet in a one-pixel seam, where unclipped near-field drawing would
    # cover the whole far part of the deck a second time.
    angle = np.arctan2(2.1, near.half_size)
    camera = camera_at(cell.center + [0.0, 0.9, 0.0], [np.cos(angle), -np.sin(angle), 0.0], 30.0, 128, 0.01, 2000.0)
    objects = near.objects(scene)
    clip = [near.clip] * len(objects)
    with (
        MeshRenderer(objects, clip) as clipped,
        MeshRenderer(objects) as unclipped,
        MeshRenderer(impostor_objects(impostor)) as quads,
    ):
        n_clip, n_all, q = (r.render(camera)[..., 3] > 0 for r in (clipped, unclipped, quads))
    seam = int((n_clip & q).sum())
    # The conservative recording may widen the layer by one face texel: that many camera rows.
    texel_rows = (2.0 * near.half_size / 128) / (2.0 * near.half_size * np.tan(np.radians(15.0)) / 128)
    assert n_clip.any() and q.any()
    assert seam <= (2 * texel_rows + 2) * 128, (seam, texel_rows)
    assert int((n_all & q).sum()) > 4 * seam, (int((n_all & q).sum()), seam)


def test_clip_planes_cut_what_the_fragment_clip_cuts():
    # A closed clip cube is cut by the GL's clip planes in an opaque program; a cube with an open
    # face by discards.  Opening -x, where nothing lies, must draw the same pixels, and both must
    # draw fewer than no clip at all.
    scene, cell = _long_beam()
    beam = scene.objects[0]
    camera = camera_at([0.0, 0.9, 0.0], [1.0, -0.2, 0.3], 60.0, 128, 0.01, 2000.0)
    clip = (np.zeros(3), 5.0)
    with (
        MeshRenderer([beam], [clip]) as planes,
        MeshRenderer([beam], [(*clip, ("-x",))]) as discards,
        MeshRenderer([beam]) as whole,
    ):
        by_planes, by_discards, unclipped = (r.render(camera) for r in (planes, discards, whole))
    assert by_planes[..., 3].any()
    # Identical on llvmpipe; a GPU's clipper and fragment test may split pixels whose centre lies
    # on the cube's face differently, a thin line at most.
    assert (by_planes != by_discards).any(axis=2).sum() <= 0.01 * (by_planes[..., 3] > 0).sum()
    inside, everything = by_planes[..., 3] > 0, unclipped[..., 3] > 0
    assert not (inside & ~everything).any() and (everything & ~inside).sum() > 1000


def test_clip_planes_follow_each_draw_in_a_mixed_renderer():
    # The planes are enabled only around the draws cut by a closed cube: a clipped object drawn
    # after an unclipped one must still be cut, whatever the order.  llvmpipe clips by every clip
    # distance the shader writes, enabled or not, so only a driver that follows the enables (the
    # NVIDIA one: this test failed there with the planes never enabled) can fail this.
    scene, _ = _long_beam()
    beam, wall = scene.objects
    raised = replace(beam, name="raised", vertices=beam.vertices + np.array([0.0, 0.5, 0.0]))
    camera = camera_at([0.0, 0.9, 0.0], [1.0, -0.2, 0.3], 60.0, 128, 0.01, 2000.0)
    clip = (np.zeros(3), 5.0)
    with (
        MeshRenderer([beam, wall, raised], [clip, None, clip]) as mixed,
        MeshRenderer([wall, beam, raised], [None, clip, clip]) as wall_first,
        MeshRenderer([beam, raised, wall], [clip, clip, None]) as grouped,
        MeshRenderer([beam, wall, raised], [clip, None, None]) as uncut,
    ):
        images = [r.render(camera) for r in (mixed, wall_first, grouped, uncut)]
    np.testing.assert_array_equal(images[0], images[2])
    np.testing.assert_array_equal(images[1], images[2])
    assert (images[3][..., 3] > 0).sum() > (images[0][..., 3] > 0).sum() + 500


@pytest.mark.parametrize("run", [1, 4, 64])
def test_nearest_first_moves_whole_runs_by_their_nearest_triangle(run):
    rng = np.random.default_rng(run)
    vertices = rng.uniform(-50.0, 50.0, (600, 3))
    obj = SceneObject("cloud", vertices, rng.permutation(600).reshape(200, 3))
    centre = np.array([3.0, -2.0, 1.0])
    key = np.max(np.abs(vertices[obj.faces].mean(axis=1) - centre), axis=1)
    runs = [list(range(start, min(start + run, 200))) for start in range(0, 200, run)]
    expected = [i for r in sorted(runs, key=lambda r: min(key[r])) for i in r]  # Python's sort is stable
    drawn = nearest_first([obj], centre, run=run)[0]
    np.testing.assert_array_equal(drawn.faces, obj.faces[expected])


def test_runtime_draws_nearest_first_and_sees_what_payload_order_sees(coplanar_town, town_cell):
    # The runtime sorts the near field's triangles (within each object) and the layers' quads
    # nearest first, so the depth test rejects hidden fragments before shading; the image must be
    # the one drawn in the stored order, also where the floors and the ground tie in depth (the
    # cell's corners lie inside buildings).
    town, town_impostor = coplanar_town, bake_envmap(coplanar_town, town_cell, EnvmapOptions(**SMALL))
    runtime = EnvmapCellRenderer(town, town_impostor)
    near = runtime.near
    objects = near.objects(town)
    stored = objects + impostor_objects(town_impostor)
    clips = [near.clip] * len(objects) + [None] * (len(stored) - len(objects))
    drawn = [obj for obj, *_ in runtime.renderer._draws]
    key = lambda obj: np.max(np.abs(obj.vertices[obj.faces].mean(axis=1) - near.centre), axis=1)  # noqa: E731
    assert [obj.name for obj in drawn[: len(objects)]] == [obj.name for obj in objects]  # the scene's object order
    stored_by_name = {obj.name: obj for obj in stored}
    for n, obj in enumerate(drawn):  # every object's triangles nearest first, in runs of the stored order kept whole
        run = NEAR_FIELD_RUN if n < len(objects) else QUAD_RUN
        where = {tuple(f): i for i, f in enumerate(stored_by_name[obj.name].faces.tolist())}
        index = np.array([where[tuple(f)] for f in obj.faces.tolist()])
        assert sorted(index.tolist()) == list(range(len(where)))
        starts = np.flatnonzero(np.diff(index, prepend=-2) != 1)  # where the drawn order jumps
        blocks = np.split(index, starts[1:])
        assert all(b[0] % run == 0 and (len(b) % run == 0 or b[-1] == len(where) - 1) for b in blocks)
        stored_key = key(stored_by_name[obj.name])
        run_key = np.minimum.reduceat(stored_key, np.arange(0, stored_key.size, run))[index // run]
        assert np.all(np.diff(run_key) >= 0.0)  # each triangle's run key, in the drawn order
    quads = drawn[len(objects) :]
    firsts = [float(key(quad)[:2].min()) for quad in quads]
    assert len(firsts) >= 1 and firsts == sorted(firsts)  # the layers' pages innermost first
    for quad in quads:  # a quad's two triangles one after the other
        pairs = quad.faces.reshape(-1, 6)
        assert np.array_equal(pairs[:, 0], pairs[:, 3]) and np.array_equal(pairs[:, 2], pairs[:, 4])
    try:
        with MeshRenderer(stored, clips) as in_stored_order:
            for position in [town_cell.center, town_cell.lo, town_cell.hi]:
                for forward in view_directions(town_impostor.parameters["directions"]):
                    camera = camera_at(position, forward, 90.0, 96, 0.05, 2000.0)
                    assert np.array_equal(runtime.renderer.render(camera), in_stored_order.render(camera))
    finally:
        runtime.release()


@pytest.mark.slow
def test_directions_subset_records_only_those_faces(town, town_cell):
    impostor = bake_envmap(
        town, town_cell, EnvmapOptions(resolution=64, fov_deg=90.0, layers=6, directions=("-z", "+x"))
    )
    assert impostor.parameters["directions"] == ["+x", "-z"]
    assert {layer["face"] for layer in impostor.layers} <= {"+x", "-z"}
    assert impostor.stats["raw_layer_bytes"] == 2 * 6 * 64 * 64 * 4
    # The other four pyramids are drawn as geometry: no view from the cell, in any direction, has a hole.
    near = NearField.from_dict(impostor.parameters["near_field"])
    assert near.open_faces == ("-x", "+y", "-y", "+z")
    everywhere = view_directions(["+x", "-x", "+y", "-y", "+z", "-z"])
    _assert_faithful(evaluate_envmap(town, impostor, random_count=1, directions=everywhere))


def test_compression_steps_shrink_memory(town_impostor):
    s = town_impostor.stats
    # Seed 002 Table 2's chain: raw layers -> macrotextures -> PNG, each much smaller.
    assert s["raw_layer_bytes"] > 4 * s["texture_bytes"] > 0
    assert s["texture_bytes"] > s["png_bytes"] > 0
    assert s["texels_culled"] > 0  # §5.2 removed hidden texels
    assert s["texels_kept"] == s["texels_covered"] - s["texels_culled"]


def test_near_field_distance_option_round_trips(town_cell):
    wanted = near_field_distance(10.0, 96, 12, EnvmapOptions(**SMALL).alpha)
    by_distance = plan_envmap(
        town_cell, EnvmapOptions(resolution=96, fov_deg=90.0, layers=None, near_field=wanted * (1 + 1e-9))
    )
    assert by_distance.count == 12
    assert by_distance.near_field == pytest.approx(wanted, rel=1e-12)


def test_default_face_resolution_matches_output_pixels():
    assert EnvmapOptions(resolution=512, fov_deg=90.0).texels_per_face == 512
    assert EnvmapOptions(resolution=256, fov_deg=60.0).texels_per_face == 444  # 256 / tan(30°) = 443.4


@pytest.mark.parametrize(
    ("kwargs", "cell", "match"),
    [
        ({"layers": 4, "near_field": 50.0}, None, "exactly one"),
        ({"layers": 0}, None, "layers"),
        ({"directions": ("+w",)}, None, "directions"),
        ({"directions": ()}, None, "directions"),
        ({"layers": None, "near_field": 1.0}, None, "outside the view cell"),
        ({}, BoxCell([0, 0, 0], [10, 10, 5]), "cubic"),
    ],
)
def test_bad_settings_are_clear_errors(kwargs, cell, match):
    with pytest.raises((LayerPlanError, ViewCellError), match=match):
        plan_envmap(cell or BoxCell.from_center([0, 0, 0], 10.0), EnvmapOptions(**{**SMALL, **kwargs}))


def test_face_beyond_the_scene_is_not_recorded(town, town_cell):
    plan = plan_envmap(town_cell, EnvmapOptions(**SMALL))
    assert face_plan("-y", plan, town_cell.center, town.bounds) is None  # the ground is in the near field
    up = face_plan("+x", plan, town_cell.center, town.bounds)
    assert np.all(np.diff(up.borders) > 0) and np.isfinite(up.borders).all()


def test_near_field_lists_exactly_the_triangles_meeting_the_cube():
    a = box_object("inside", (-1, -1, -1), (1, 1, 1))
    b = box_object("outside", (10, 10, 10), (11, 11, 11))
    c = box_object("crossing", (4, -1, -1), (20, 1, 1))
    nf = near_field(Scene.from_objects([a, b, c], source="t"), np.zeros(3), 5.0)
    assert nf.ranges["inside"] == [[0, 12]] and "outside" not in nf.ranges
    assert 0 < nf.ranges["crossing"][0][1] - nf.ranges["crossing"][0][0] <= 12
    assert NearField.from_dict(json.loads(json.dumps(nf.to_dict()))).ranges == nf.ranges
    # With +x left to geometry, "outside" (beyond the cube, in the +x pyramid) is drawn too.
    opened = near_field(Scene.from_objects([a, b, c], source="t"), np.zeros(3), 5.0, ["+x"])
    assert opened.ranges["outside"] == [[0, 12]] and opened.open_faces == ("+x",)
    assert "outside" not in near_field(Scene.from_objects([a, b, c], source="t"), np.zeros(3), 5.0, ["-x", "-y"]).ranges


def test_gap_fill_copies_border_texels_into_the_farther_layer():
    near = np.zeros((5, 5, 4), np.uint8)
    near[1:4, 0:2] = (200, 0, 0, 255)  # columns 0-1; column 1 is its opaque border
    far = np.zeros((5, 5, 4), np.uint8)
    far[1:4, 3:5] = (0, 0, 200, 255)  # two texels apart: column 2 is far's transparent border
    filled, added = fill_gaps(near, far)
    assert added == 0 and np.array_equal(filled, far)
    far[1:4, 2] = (0, 0, 200, 255)  # now column 1 is far's transparent border, behind near's border
    filled, added = fill_gaps(near, far)
    assert added == 3 and filled[1:4, 1].tolist() == [[200, 0, 0, 255]] * 3
    assert filled[1:4, 0, 3].tolist() == [0, 0, 0]  # not a border of far: stays empty


@pytest.mark.slow
def test_grid_database_and_walkthrough(tmp_path, town):
    options = EnvmapOptions(resolution=64, fov_deg=90.0, layers=6, directions=("+x", "-x", "+z", "-z"))
    cells = [
        (list(ijk), bake_envmap(town, box, options))
        for ijk, box in grid_boxes([160, 0.5, 160], [180, 10.5, 180], [2, 1, 2])
    ]
    root = write_database(tmp_path / "db", "envmap", {}, cells)
    with ImpostorDatabase(root) as db:
        assert [c.neighbours for c in db.cells] == [(1, 2, 3), (0, 2, 3), (0, 1, 3), (0, 1, 2)]
        assert db.find([175.0, 5.0, 165.0]).index == 1
        assert db.find([0.0, 0.0, 0.0]) is None
        positions, forwards = generate_path(db, 8)
        result = walkthrough(town, db, positions, forwards, repeats=1)
    s = result["summary"]
    assert s["frames_served"] == 8 and s["cell_switches"] >= 3
    assert s["hole_pixels"] == 0
    assert all(f["impostor_ms"] > 0 and f["full_ms"] > 0 for f in result["frames"])
    write_plot(result, tmp_path / "walk.png")
    assert Image.open(tmp_path / "walk.png").size[0] > 100

    # The CLI on the same database: a scene file, a recorded path, JSON and a plot.
    scene_file = write_scene(town, tmp_path, "glb", "town")
    path_file = tmp_path / "path.json"
    path_file.write_text(
        json.dumps([{"position": p.tolist(), "forward": f.tolist()} for p, f in zip(positions[:3], forwards[:3])])
    )
    _register()
    run = CliRunner().invoke(
        cli,
        [
            "walkthrough",
            str(root),
            str(scene_file),
            "--path",
            str(path_file),
            "--repeats",
            "1",
            "--plot",
            str(tmp_path / "cli.png"),
            "--json",
        ],
    )
    assert run.exit_code == 0, run.output
    data = json.loads(run.output)
    assert data["summary"]["frames"] == 3 and data["summary"]["hole_pixels"] == 0
    assert (tmp_path / "cli.png").stat().st_size > 0

    bad = CliRunner().invoke(cli, ["walkthrough", str(tmp_path), str(scene_file)])
    assert bad.exit_code != 0 and "not an impostor database" in bad.output


@pytest.mark.slow
def test_cli_bake_and_evaluate_envmap(tmp_path, town):
    scene_file = write_scene(town, tmp_path, "glb", "town")
    _register()
    out = tmp_path / "bundle"
    run = CliRunner().invoke(cli, ["bake", str(scene_file), "--technique", "envmap", "--viewcell", "box-center:170,5,170,10",
                                   "--out", str(out), "--resolution", "64", "--layers", "6", "--directions", "+x,-x,+z,-z", "--json"])  # fmt: skip
    assert run.exit_code == 0, run.output
    assert json.loads(run.output)["stats"]["faces"] == 4
    run = CliRunner().invoke(cli, ["evaluate", str(out), str(scene_file), "--random", "1", "--json"])
    assert run.exit_code == 0, run.output
    assert json.loads(run.output)["totals"]["hole_pixels"] == 0
    run = CliRunner().invoke(
        cli,
        [
            "bake",
            str(scene_file),
            "--technique",
            "envmap",
            "--viewcell",
            "box:0,0,0,10,10,5",
            "--out",
            str(tmp_path / "x"),
        ],
    )
    assert run.exit_code != 0 and "cubic" in run.output


def test_the_bundle_encodes_no_page_the_bake_measured(town, town_cell, tmp_path, monkeypatch):
    """The bake encodes its pages to report ``png_bytes``; writing the bundle then reuses those
    bytes for the page files and the GLB (it encoded each page a second time), and they are the
    bytes the stat counted."""
    import farfield.core.impostor.png_pages as png_pages
    from farfield.core.impostor.bundle import write_bundle

    impostor = bake_envmap(town, town_cell, EnvmapOptions(**{**SMALL, "directions": ("+x",)}))
    encoded = []
    real = png_pages.page_png
    monkeypatch.setattr(png_pages, "page_png", lambda page: encoded.append(page.shape) or real(page))
    paths = write_bundle(impostor, tmp_path / "b")
    assert impostor.pages and encoded == []
    assert sum(len(p.read_bytes()) for p in paths.pages) == impostor.stats["png_bytes"]
    assert [p.read_bytes() for p in paths.pages] == [real(page) for page in impostor.pages]
