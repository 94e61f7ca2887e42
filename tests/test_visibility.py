"""From-region visibility (issue 57): element-id cube maps, sampled potentially visible sets, and the
planner counting only a region's PVS when ``visibility`` is on."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from farfield.core import procedural
from farfield.core.placement.cost_model import primitive_model
from farfield.core.placement.hierarchy import Elements, Hierarchy
from farfield.core.placement.planner import PlacementSettings, place
from farfield.core.placement.view_space import problem_view_space
from farfield.core.scene import Scene, SceneObject
from farfield.core.visibility.id_cubes import IdCubeRenderer, VisibilityError
from farfield.core.visibility.pvs import RegionVisibility, SampleLattice, false_invisible, halvings

FOV = math.radians(45.0)


def _box(name, low, high, n=1, **kw) -> SceneObject:
    v, f = procedural.subdivided_box(low, high, n)
    return SceneObject(name, v, f, **kw)


def _walled() -> Scene:
    """A wall (x = 10..11) between the view space (x < 0) and a dense block behind it (x = 20..24),
    and a small box beside the view space that nothing hides."""
    return Scene.from_objects(
        [
            _box("wall", (10, -50, -50), (11, 50, 50)),
            _box("hidden", (20, -2, -2), (24, 2, 2), 24),
            _box("beside", (-5, 0, 30), (-4, 1, 31)),
        ],
        "walled",
    )


def _index(elements: Elements, name: str) -> int:
    return elements.names.index(name)


def test_a_point_sees_what_is_in_front_and_not_what_is_hidden():
    scene = Scene.from_objects(
        [
            _box("near", (0, 0, 0), (1, 1, 1)),
            _box("behind", (3, 0, 0), (4, 1, 1)),
            _box("aside", (-5, -5, -5), (-4, -4, -4)),
        ],
        "three",
    )
    elements = Elements.of(scene)
    with IdCubeRenderer(scene, elements, 32) as renderer:
        sight = renderer.see([[-3.0, 0.5, 0.5], [2.0, 0.5, 5.0]])
        ids0, texels0 = sight.of(0)
        ids1, _ = sight.of(1)
    names0 = {elements.names[i] for i in ids0}
    assert names0 == {"near", "aside"}  # "behind" is exactly covered by "near"
    assert {elements.names[i] for i in ids1} == {"near", "behind", "aside"}
    assert np.all(texels0 > 0)


def test_masked_and_one_sided_geometry_hides_nothing_it_should_not():
    back = _box("back", (5, -1, -1), (6, 1, 1))
    masked = _box("masked", (2, -3, -3), (2.2, 3, 3), alpha_cutoff=0.5)
    # A one-sided quad facing -x (away from an eye at x < 2): its back is towards the eye.
    quad = SceneObject(
        "one_sided",
        np.array([[2.0, -3, -3], [2.0, 3, -3], [2.0, 3, 3], [2.0, -3, 3]]),
        np.array([[0, 1, 2], [0, 2, 3]]),
        double_sided=False,
    )
    normal = np.cross(quad.vertices[1] - quad.vertices[0], quad.vertices[2] - quad.vertices[0])
    if normal[0] < 0:  # make its front face +x, away from the eye
        quad = SceneObject("one_sided", quad.vertices, quad.faces[:, ::-1].copy(), double_sided=False)
    for occluder in (masked, quad):
        scene = Scene.from_objects([occluder, back], "s")
        elements = Elements.of(scene)
        with IdCubeRenderer(scene, elements, 32) as renderer:
            ids, _ = renderer.see([[0.0, 0.0, 0.0]]).of(0)
        assert _index(elements, "back") in ids.tolist(), occluder.name
    opaque = Scene.from_objects([_box("opaque", (2, -3, -3), (2.2, 3, 3)), back], "s")
    elements = Elements.of(opaque)
    with IdCubeRenderer(opaque, elements, 32) as renderer:
        ids, _ = renderer.see([[0.0, 0.0, 0.0]]).of(0)
    assert _index(elements, "back") not in ids.tolist()


def test_the_lattice_holds_every_corner_of_the_planners_regions():
    lo, hi, size = np.array([0.0, 0.0, 0.0]), np.array([100.0, 3.0, 60.0]), 20.0
    lattice = SampleLattice.for_regions(lo, hi, size, 2)
    steps = [2 ** halvings(float(s), size) for s in hi - lo]
    side = (hi - lo) / steps
    for ijk in np.ndindex(*steps):
        r_lo = lo + np.array(ijk) * side
        pts = lattice.points(lattice.inside(r_lo, r_lo + side))
        for corner in np.array(np.meshgrid(*zip(r_lo, r_lo + side), indexing="ij")).reshape(3, -1).T:
            assert np.min(np.linalg.norm(pts - corner, axis=1)) < 1e-9
    assert np.all(lattice.step <= 0.5 * side.max() + 1e-12)  # 2 per side of a region's longest side
    with pytest.raises(VisibilityError):
        SampleLattice.for_regions(lo, hi, 1e-3, 2)


def test_a_region_pvs_drops_the_hidden_block_and_keeps_the_rest():
    scene = _walled()
    elements = Elements.of(scene)
    vis = RegionVisibility(scene, elements, [-10, -2, -10], [0, 2, 10], 10.0, 64, FOV, margin=0.0)
    try:
        pvs = vis.pvs([-10, -2, -10], [0, 2, 10]).tolist()
        hidden = [i for i, n in enumerate(elements.names) if n.startswith("hidden")]
        assert hidden and not set(hidden) & set(pvs)
        assert _index(elements, "wall") in pvs and _index(elements, "beside") in pvs
        cand = np.arange(elements.count)
        assert vis([-10, -2, -10], [0, 2, 10], cand).tolist() == pvs
        # A child region's PVS lies within its parent's.
        assert set(vis.pvs([-10, -2, -10], [-5, 2, 0]).tolist()) <= set(pvs)
        # The margin keeps what lies near the region whatever the samples see.
        wide = RegionVisibility(
            scene, elements, [-10, -2, -10], [0, 2, 10], 10.0, 64, FOV, margin=25.0, renderer=vis.renderer
        )
        assert set(hidden) <= set(wide.pvs([-10, -2, -10], [0, 2, 10]).tolist())
        # Against itself sampled densely nothing is missing here: the wall hides the block everywhere.
        dense = RegionVisibility(
            scene,
            elements,
            [-10, -2, -10],
            [0, 2, 10],
            10.0,
            64,
            FOV,
            samples_per_side=4,
            levels=0,
            margin=0.0,
            erosion=0.0,
        )
        try:
            report = false_invisible(vis, dense, [([-10, -2, -10], [0, 2, 10])])
        finally:
            dense.release()
        assert report["missing"] == 0 and report["dense_pvs"] == report["sparse_pvs"] == len(pvs)
    finally:
        vis.release()


def test_problem_views_with_visibility_count_only_what_the_region_may_see():
    scene = _walled()
    elements = Elements.of(scene)
    hierarchy = Hierarchy.build(elements)
    lo, hi = np.array([-10.0, -2.0, -10.0]), np.array([0.0, 2.0, 10.0])
    model = primitive_model()
    args = (elements, hierarchy, lo, hi, model, 1e-9, FOV, 64, 10.0, 45.0)
    plain = problem_view_space(*args)
    vis = RegionVisibility(scene, elements, lo, hi, 10.0, 64, FOV, margin=0.0)
    try:
        culled = problem_view_space(*args, 4.0, vis)
    finally:
        vis.release()
    hidden = {int(hierarchy.position[i]) for i, n in enumerate(elements.names) if n.startswith("hidden")}
    assert hidden & set(plain.positions.tolist())
    assert not hidden & set(culled.positions.tolist())
    assert culled.time.max() < plain.time.max()


def test_a_placement_with_visibility_places_nothing_for_a_hidden_block():
    scene = _walled()
    lo, hi = [-10.0, -2.0, -10.0], [0.0, 2.0, 10.0]
    t_max = 0.5 * scene.triangle_count  # the hidden block is most of the triangles
    base = {
        "vdi_deg": 45.0,
        "options": {"resolution": 64},
        "cpv_size": 10.0,
        "model": primitive_model(),
        "t_max": t_max,
    }
    without = place(scene, lo, hi, PlacementSettings(**base))
    with_vis = place(scene, lo, hi, PlacementSettings(**base, visibility=True))
    assert without.summary["impostors"] > 0 and without.summary["cpvs"] > 0
    assert with_vis.summary["cpvs"] == 0 and with_vis.impostors == []
    assert with_vis.parameters["visibility"]["kind"] == "sampled potentially visible sets"
    assert isinstance(without.parameters["visibility"], str)


def test_a_placement_with_visibility_reports_the_lattice_and_stops_there_when_cancelled():
    """The lattice's rendering (minutes at street level on llvmpipe) is a step of its own in the
    planner's progress, reported per batch of points, so a job shows it moving and a cancel (the
    service raises from its progress callback) stops it there, before the problem views."""
    scene = _walled()
    lo, hi = [-10.0, -2.0, -10.0], [0.0, 2.0, 10.0]
    settings = PlacementSettings(
        vdi_deg=45.0, options={"resolution": 64}, cpv_size=10.0, model=primitive_model(), t_max=1.0, visibility=True
    )
    seen: list[tuple[str, int, int]] = []
    placed = place(scene, lo, hi, settings, progress=lambda step, done, total: seen.append((step, done, total)))
    lattice = [s for s in seen if s[0] == "visibility"]
    points = placed.parameters["visibility"]["points_rendered"]
    assert lattice[0] == ("visibility", 0, points) and lattice[-1] == ("visibility", points, points)
    steps = [s[0] for s in seen]
    assert steps.index("visibility") > steps.index("hierarchy")
    assert "problem views" not in steps[: steps.index("visibility") + len(lattice)]

    class Cancelled(Exception):
        pass

    def cancel(step, done, total):
        if step == "visibility":
            raise Cancelled(step)
        assert step == "hierarchy", f"planning went on to {step!r} after the cancel"

    with pytest.raises(Cancelled):
        place(scene, lo, hi, settings, progress=cancel)


def test_the_service_stores_visibility_only_when_asked_and_the_planner_reads_it():
    from farfield.service.placement.frame_time import FrameTime, planner_settings
    from farfield.service.placement.schema import PlacementSpec

    box = {"view_space": {"lo": [0, 0, 0], "hi": [10, 1, 10]}, "budget": {"primitives": 1000}}
    on = FrameTime().params("layered", {}, 64, 45.0, PlacementSpec(**box, visibility=True))
    off = FrameTime().params("layered", {}, 64, 45.0, PlacementSpec(**box))
    assert on["placement"]["visibility"] is True and planner_settings(on)[0].visibility is True
    assert "visibility" not in off["placement"] and planner_settings(off)[0].visibility is False
    from farfield.core.placement.hierarchy import PlacementError
    from farfield.service.placement.admission import placement_params

    with pytest.raises(PlacementError, match="visibility: not a knob of the primitive-budget placement"):
        placement_params(None, {}, 64, 45.0, PlacementSpec(**box, visibility=True, algorithm="primitive-budget"))


def test_place_command_takes_visibility_and_refuses_it_for_the_primitive_budget(tmp_path):
    from click.testing import CliRunner
    from scenes import write_scene

    from farfield.cli.main import _register, cli

    _register()
    scene = _walled()
    path = write_scene(scene, tmp_path, "glb", "walled")
    args = ["place", str(path), "--view-space", "-10,-2,-10,0,2,10", "--primitives", str(0.5 * scene.triangle_count),
            "--resolution", "64", "--vdi-deg", "45", "--cpv-size", "10", "--json", "--quiet"]  # fmt: skip
    runner = CliRunner()
    plain, culled = runner.invoke(cli, args), runner.invoke(cli, [*args, "--visibility"])
    assert plain.exit_code == 0 and culled.exit_code == 0, plain.output + culled.output
    assert json.loads(plain.output)["summary"]["impostors"] > 0 == json.loads(culled.output)["summary"]["impostors"]
    refused = runner.invoke(cli, [*args, "--visibility", "--algorithm", "primitive-budget"])
    assert refused.exit_code != 0 and "--visibility applies to the frame-time placement" in refused.output


def _slit() -> Scene:
    """A wall at x = 20..20.5 with a 0.5 m slit at z = 2.25..2.75, a thin post behind the slit (x = 40)
    that only eyes near z = 2.5 see through it, a back wall every eye sees through the slit, and a
    block behind the wall far from the slit that no eye of the region sees."""
    return Scene.from_objects(
        [
            _box("wall_low", (20, -50, -100), (20.5, 50, 2.25)),
            _box("wall_high", (20, -50, 2.75), (20.5, 50, 100)),
            _box("post", (40, -2, 2.2), (40.6, 3, 2.8)),
            _box("back", (60, -50, -100), (61, 50, 100)),
            _box("hidden", (40, -2, -60), (44, 2, -56)),
        ],
        "slit",
    )


def test_the_eroded_pvs_keeps_a_post_seen_only_through_a_slit_between_the_lattice_points():
    """The region x, z = 0..10 has lattice points at x, z in {0, 5, 10}: none sees the post through
    the slit (their lines through it reach x = 40 at z = 4.5..8.3 or -0.5..0.5), an eye at z = 2.5
    does.  Point sampling drops it even refined; occluder erosion keeps it, and still drops the block
    the wall hides from every eye of the region."""
    scene = _slit()
    elements = Elements.of(scene)
    post, hidden = _index(elements, "post"), _index(elements, "hidden")
    lo, hi = [0.0, 0.0, 0.0], [10.0, 1.0, 10.0]
    with IdCubeRenderer(scene, elements, 256) as truth:
        assert post in truth.see([[5.0, 0.5, 2.5]]).of(0)[0].tolist()  # a view of the region sees it
    sampled = RegionVisibility(scene, elements, lo, hi, 10.0, 64, FOV, levels=1, erosion=0.0)
    try:
        assert sampled.lattice.counts.tolist() == [3, 2, 3]
        assert post not in sampled.pvs(lo, hi).tolist()  # the points alone miss it
    finally:
        sampled.release()
    eroded = RegionVisibility(scene, elements, lo, hi, 10.0, 64, FOV)
    try:
        assert eroded.erosion == pytest.approx(0.5 * math.sqrt(5**2 + 1**2 + 5**2))
        pvs = eroded.pvs(lo, hi).tolist()
        assert post in pvs and _index(elements, "back") in pvs
        assert hidden not in pvs
    finally:
        eroded.release()


def _slits_in_a_row() -> Scene:
    """Two walls (x = 20 and x = 30) with 1 m slits at z = 2..3, a post behind both (x = 40) that an
    eye at z = 2.5 sees through the two slits in a row, and a block behind the first wall far from
    the slits that no eye of the region x, z = 0..10 sees."""
    return Scene.from_objects(
        [
            _box("wall1_low", (20, -50, -100), (20.5, 50, 2.0)),
            _box("wall1_high", (20, -50, 3.0), (20.5, 50, 100)),
            _box("wall2_low", (30, -50, -100), (30.5, 50, 2.0)),
            _box("wall2_high", (30, -50, 3.0), (30.5, 50, 100)),
            _box("post", (40, -2, 2.2), (40.6, 3, 2.8)),
            _box("back", (60, -50, -100), (61, 50, 100)),
            _box("hidden", (24, -2, -60), (27, 2, -56)),
        ],
        "slits",
    )


def test_the_eroded_pvs_keeps_a_post_seen_through_two_slits_in_a_row():
    """From the lattice points (x, z in {0, 5, 10}) the first slit shows the second wall, never the
    post: an eroded first surface alone opens only down to the second wall's depth.  Each peeled
    layer is eroded at its own silhouettes (the second wall's slit), so the layer behind it opens
    where a nearby eye may see through both, and the post is kept; the block behind the first wall,
    away from the slits, is still dropped."""
    scene = _slits_in_a_row()
    elements = Elements.of(scene)
    post, hidden = _index(elements, "post"), _index(elements, "hidden")
    lo, hi = [0.0, 0.0, 0.0], [10.0, 1.0, 10.0]
    with IdCubeRenderer(scene, elements, 256) as truth:
        assert post in truth.see([[5.0, 0.5, 2.5]]).of(0)[0].tolist()  # a view of the region sees it
    eroded = RegionVisibility(scene, elements, lo, hi, 10.0, 128, FOV)
    try:
        assert eroded.lattice.counts.tolist() == [3, 2, 3]
        pvs = eroded.pvs(lo, hi).tolist()
        assert post in pvs
        assert hidden not in pvs
    finally:
        eroded.release()
