"""Layered impostors end to end on real EGL: the no-hole promise, culling, and what breaks without them."""

from __future__ import annotations

import numpy as np
import pytest
import scenes

from farfield.core.quality.evaluation import compare_images, evaluate, impostor_objects
from farfield.core.render.raster import Camera, MeshRenderer, depth_bounds
from farfield.core.scene import Scene
from farfield.core.techniques.layered import BakeOptions, bake_layered
from farfield.core.viewcells import BoxCell, box_corners


def cell_in_front(scene: Scene, distance: float, size: float, axis: int = 0, lift: float = 0.0) -> BoxCell:
    """A cubic view cell of ``size`` whose centre lies ``distance`` part-diameters before the part along -axis."""
    b = scene.bounds
    diameter = float(np.max(b[1] - b[0]))
    centre = 0.5 * (b[0] + b[1])
    centre[axis] = b[0][axis] - distance * diameter - 0.5 * size
    centre[1] += lift
    return BoxCell.from_center(centre, size)


def thin_forest() -> Scene:
    """Trunks 0.1-0.4 units thick seen from about 150 units: narrower than one texel."""
    return scenes.forest(trees=60, seed=4)


def city_block() -> Scene:
    return scenes.city(buildings=36, seed=5)


def dense() -> Scene:
    """Two bumpy icospheres side by side: 163,840 triangles."""
    one = scenes.dense_mesh(subdivisions=6, seed=3).objects[0]
    other = type(one)(name="dense_b", vertices=one.vertices + [2.5, 0.0, 0.0], faces=one.faces)
    return Scene.from_objects([one, other], "dense-pair")


CASES = {
    # name: (scene factory, cell distance in part diameters, cell size in part diameters, lift)
    "bunny": (lambda: scenes.real_scene("stanford_bunny/bun_zipper.ply"), 4.0, 0.6, 0.0),
    "scrub_pine": (lambda: scenes.real_scene("scrub_pine/scrubPine.obj"), 3.0, 0.5, 0.0),
    "helmet": (lambda: scenes.real_scene("damaged_helmet/DamagedHelmet.glb"), 4.0, 0.5, 0.0),
    "thin_forest": (thin_forest, 1.5, 0.1, 2.0),
    "city_grazing": (city_block, 1.0, 0.1, 3.0),  # eye level: the ground plane at grazing angles
    "dense_mesh": (dense, 3.0, 0.5, 0.0),
}


def needs_shared(name: str) -> None:
    if name in ("bunny", "scrub_pine", "helmet") and not scenes.SHARED_SCENES.exists():
        pytest.skip("../shared/scenes is not beside the checkout")


@pytest.fixture(scope="module")
def ctx(gl):
    context = gl
    yield context
    assert context.error == "GL_NO_ERROR"


@pytest.mark.parametrize("name", sorted(CASES))
@pytest.mark.slow
def test_no_hole_pixels_from_inside_the_view_cell(name, ctx):
    needs_shared(name)
    factory, distance, size, lift = CASES[name]
    scene = factory()
    diameter = float(np.max(scene.bounds[1] - scene.bounds[0]))
    cell = cell_in_front(scene, distance, size * diameter, lift=lift)
    impostor = bake_layered(scene, cell, BakeOptions(resolution=256))
    result = evaluate(scene, impostor, cell, random_count=8, seed=11)
    totals = result.totals
    assert totals["viewpoints"] == 8 + 1 + 8
    assert totals["geometry_pixels"] > 1000, "the part should be visible from the cell"
    assert totals["hole_pixels"] == 0, [r["stats"]["hole_pixels"] for r in result.viewpoints]
    assert ctx.error == "GL_NO_ERROR"


@pytest.mark.slow
def test_without_conservative_recording_the_thin_forest_has_holes(ctx):
    scene = thin_forest()
    diameter = float(np.max(scene.bounds[1] - scene.bounds[0]))
    cell = cell_in_front(scene, 1.5, 0.1 * diameter, lift=2.0)
    broken = bake_layered(scene, cell, BakeOptions(resolution=256, conservative=False))
    assert evaluate(scene, broken, cell, random_count=8, seed=11).totals["hole_pixels"] > 50


def test_culling_removes_no_texel_seen_from_the_view_cell(ctx):
    scene = city_block()
    diameter = float(np.max(scene.bounds[1] - scene.bounds[0]))
    cell = cell_in_front(scene, 1.0, 0.1 * diameter, lift=3.0)
    full = bake_layered(scene, cell, BakeOptions(resolution=256, culling="off"))
    culled = bake_layered(scene, cell, BakeOptions(resolution=256, culling="penumbra"))
    assert culled.stats["texels_culled"] > 0.2 * culled.stats["texels_covered"]
    assert culled.texture_bytes < full.texture_bytes
    target = 0.5 * (scene.bounds[0] + scene.bounds[1])
    extent = np.concatenate([box_corners(scene.bounds), full.quad_corners.reshape(-1, 3)])
    with MeshRenderer(impostor_objects(full)) as a, MeshRenderer(impostor_objects(culled)) as b:
        for position in np.concatenate([cell.corners(), cell.sample_random(12, seed=5)]):
            forward = (target - position) / np.linalg.norm(target - position)
            camera = Camera.look_at(position, target, np.radians(45), 256, *depth_bounds(position, forward, extent))
            stats = compare_images(a.render(camera), b.render(camera))
            assert stats["hole_pixels"] == 0 and stats["hole_pixels_1spp"] == 0
            # Culled texels are hidden; colours differ only where bilinear filtering meets a quad
            # seam (the two impostors are cut into different quads), a handful of pixels.
            assert stats["colour_error_p99"] == 0
            assert stats["colour_error_mean"] < 0.2


@pytest.mark.slow
def test_guarantee_ends_outside_the_view_cell(ctx):
    """Seed 000 Fig. 3.18: far enough outside (here, much closer to the part) errors appear.

    The viewpoints lie 1.8 to 3 cell sizes from the cell's centre: an impostor whose texels and
    parallax share one pixel (texel_share) still holds a cell size away."""
    scene = city_block()
    diameter = float(np.max(scene.bounds[1] - scene.bounds[0]))
    cell = cell_in_front(scene, 1.0, 0.1 * diameter, lift=3.0)
    impostor = bake_layered(scene, cell, BakeOptions(resolution=256))
    assert evaluate(scene, impostor, cell, random_count=0, outside_count=0).totals["hole_pixels"] == 0
    around = BoxCell.from_center(cell.center, 2.0 * cell.size)
    outside = evaluate(scene, impostor, around, random_count=0, outside_count=6, seed=2).totals["outside"]
    assert outside["hole_pixels"] > 0


# The box of issue 23: 10 x 8 x 10, its front face 18 units before a 4-unit cell.
ISSUE_BOX = Scene.from_objects(
    [scenes.box_object("block", (-5.0, 0.0, -5.0), (5.0, 8.0, 5.0), (0.8, 0.35, 0.2, 1.0))], "issue-23-box"
)
ISSUE_BOX_CELL = BoxCell(np.array([-2.0, 3.0, -27.0]), np.array([2.0, 7.0, -23.0]))


@pytest.mark.parametrize("resolution", [64, 128, 256])
def test_a_box_silhouette_stays_within_one_pixel_from_the_whole_cell(resolution, ctx):
    """A silhouette grows by up to one texel (gap-free recording) and moves by parallax: with the
    thesis's budget (texels and parallax each one pixel) the box bloated 18 and 8 pixels beyond
    one at 64 and 128 px; with texels and parallax sharing the pixel, none."""
    impostor = bake_layered(ISSUE_BOX, ISSUE_BOX_CELL, BakeOptions(resolution=resolution))
    totals = evaluate(ISSUE_BOX, impostor, ISSUE_BOX_CELL, random_count=8, seed=0).totals
    assert totals["hole_pixels"] == 0
    assert totals["bloat_beyond_1px"] == 0
    plan = impostor.parameters["plan"]
    assert plan["texel_angle_rad"] + plan["parallax_angle_rad"] <= plan["alpha_rad"]


def test_bake_is_deterministic(ctx):
    scene = thin_forest()
    diameter = float(np.max(scene.bounds[1] - scene.bounds[0]))
    cell = cell_in_front(scene, 1.5, 0.1 * diameter, lift=2.0)
    a = bake_layered(scene, cell, BakeOptions(resolution=128))
    b = bake_layered(scene, cell, BakeOptions(resolution=128))
    np.testing.assert_array_equal(a.quad_corners, b.quad_corners)
    assert all(np.array_equal(p, q) for p, q in zip(a.pages, b.pages))


@pytest.mark.slow
def test_memory_grows_with_kept_texels_not_layers_times_image(ctx):
    """Peak memory of a many-layer bake of few triangles stays far below holding every layer at
    once (the per-pair clipping temporaries grow with triangles x spans, which this scene keeps small)."""
    import tracemalloc

    scene = city_block()
    diameter = float(np.max(scene.bounds[1] - scene.bounds[0]))
    cell = cell_in_front(scene, 0.3, 0.1 * diameter, lift=3.0)
    options = BakeOptions(resolution=384)
    bake_layered(scene, cell, options)  # warm caches (shaders, scene-independent state)
    tracemalloc.start()
    impostor = bake_layered(scene, cell, options)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    res_x, res_y = impostor.stats["texture_resolution"]
    all_layers = impostor.stats["layers_planned"] * res_x * res_y * 4
    assert impostor.stats["layers_planned"] >= 40
    assert peak < 0.25 * all_layers, (peak, all_layers)


@pytest.mark.slow
def test_small_pages_cut_the_quads_that_would_not_fit_and_draw_the_same(ctx):
    """max_page 64 (the option's least) with padding 2: box-grown quads up to a layer wide used to
    end the bake with AtlasOverflowError; they are cut into pieces of at most 60 texels a side,
    every page is at most 64, and the impostor draws what the default one draws."""
    scene = city_block()
    diameter = float(np.max(scene.bounds[1] - scene.bounds[0]))
    cell = cell_in_front(scene, 1.0, 0.1 * diameter, lift=3.0)
    default = bake_layered(scene, cell, BakeOptions(resolution=128))
    small = bake_layered(scene, cell, BakeOptions(resolution=128, max_page=64))
    assert max(max(p.shape[:2]) for p in default.pages) > 64  # the default needed a larger page
    assert max(max(p.shape[:2]) for p in small.pages) <= 64 and small.quad_count > default.quad_count
    assert small.stats["texels_kept"] == default.stats["texels_kept"]
    a, b = (evaluate(scene, impostor, cell, random_count=4).totals for impostor in (default, small))
    assert a["hole_pixels"] == b["hole_pixels"] == 0 and a["bloat_beyond_1px"] == b["bloat_beyond_1px"] == 0
    assert abs(a["colour_error_mean"] - b["colour_error_mean"]) < 0.05, (a, b)
