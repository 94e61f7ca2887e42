"""Seed 004's layered depth images: nine construction images, the CPU warp in occlusion-compatible
order, the GPU splats, the 3x3 pass, and hybrid frames of a primitive-budget placement."""

from __future__ import annotations

import math

import numpy as np
import pytest

from farfield.core import procedural
from farfield.core.ldi.construction import construct_ldi, construction_cops
from farfield.core.ldi.warp import _frame, epipole, fill_pin_holes, warp_cpu
from farfield.core.placement.image_frames import boundary_eyes, frame_holes, image_ldi, view_camera
from farfield.core.placement.solution_grid import BudgetSettings, place_primitives
from farfield.core.render.splats import SplatRenderer
from farfield.core.scene import SceneObject

FOV = math.radians(60)


def _boxes():
    """A near box hiding part of a far one, both ahead (-z) of the origin, coloured apart."""
    v1, f1 = procedural.subdivided_box([-1.0, -1.0, -8.0], [1.0, 1.0, -6.0], 4)
    v2, f2 = procedural.subdivided_box([-3.0, -2.0, -16.0], [3.0, 2.0, -12.0], 6)
    return [SceneObject("near", v1, f1, base_color=np.array([0.8, 0.1, 0.1, 1.0])),
            SceneObject("far", v2, f2, base_color=np.array([0.1, 0.2, 0.8, 1.0]))]  # fmt: skip


def _quad(depth=5.0, half=3.2):
    return np.array([[-half, -half, -depth], [half, -half, -depth], [half, half, -depth], [-half, half, -depth]])


def test_the_construction_cops_are_fig_11s():
    g, quad = np.zeros(3), _quad()
    cops = construction_cops(g, quad)
    mids = 0.5 * (quad + np.roll(quad, -1, axis=0))
    assert cops.shape == (9, 3)
    assert np.allclose(cops[:4], mids / 2) and np.allclose(cops[4], g) and np.allclose(cops[5:], -mids / 2)
    assert np.allclose(construction_cops(g, quad, 1), g[None])


def test_nine_images_sample_what_the_grid_point_cannot_see():
    objs = _boxes()
    one = construct_ldi(objs, np.zeros(3), 0.0, _quad(), 5.0, 64, images=1)
    nine = construct_ldi(objs, np.zeros(3), 0.0, _quad(), 5.0, 64, images=9)
    assert one.ldi.layers == 1 and nine.ldi.layers >= 2
    far_one = np.count_nonzero(one.ldi.obj == 1)
    far_nine = np.count_nonzero(nine.ldi.obj == 1)
    assert far_nine > far_one * 1.1  # the far box behind the near one, seen from the off-centre COPs
    d = nine.ldi.depth
    assert np.all(np.diff(np.where(np.isfinite(d), d, np.inf), axis=0)[np.isfinite(d[1:])] >= 0)  # nearest first
    assert np.all(d[np.isfinite(d)] >= 5.0 * (1 - 1e-6))  # nothing before the quad's plane
    ids = nine.ldi.obj * 10**6 + nine.ldi.triangle
    for layer in range(1, nine.ldi.layers):  # no triangle twice in one pixel
        assert not np.any((ids[layer] >= 0) & np.any(ids[:layer] == ids[layer], axis=0))
    assert nine.kept == nine.ldi.count and nine.dropped_full == 0


def _zbuffer_warp(ldi, camera):
    """Brute force: every sample's splat with a depth test (the order-free answer)."""
    frame, ox, oy, half = _frame(camera)
    positions, index = ldi.samples()
    d = (positions - camera.eye) @ frame.T
    z = d[:, 2]
    n, m = ldi.camera.resolution, camera.resolution
    ref_pixel = 2 * math.tan(0.5 * ldi.camera.fov) / n
    width = ref_pixel * ldi.depth[index[:, 0], index[:, 1], index[:, 2]] / (z * 2 * half / m)
    size = np.clip(np.ceil(width - 1e-9), 1, 8).astype(int)
    wx = (d[:, 0] / z - ox + half) / (2 * half) * m
    wy = (half - (d[:, 1] / z - oy)) / (2 * half) * m
    depth = np.full((m, m), np.inf)
    for x, y, s, zz, ok in zip(wx, wy, size, z, z > camera.near):
        if not ok:
            continue
        c0 = int(math.floor(x)) - (s - 1) // 2 if s % 2 else int(math.floor(x + 0.5)) - s // 2
        r0 = int(math.floor(y)) - (s - 1) // 2 if s % 2 else int(math.floor(y + 0.5)) - s // 2
        block = depth[max(r0, 0) : max(r0 + s, 0), max(c0, 0) : max(c0 + s, 0)]
        np.minimum(block, zz, out=block)
    return np.where(np.isfinite(depth), depth, np.nan)


@pytest.fixture(scope="module")
def boxes_ldi():
    return construct_ldi(_boxes(), np.zeros(3), 0.0, _quad(), 5.0, 96, images=9).ldi


@pytest.mark.parametrize("eye, yaw, exact", [
    ((0.0, 0.0, 0.0), 0.0, True), ((0.0, 0.0, 2.0), 0.0, True), ((1.0, 0.3, 3.0), 0.2, True), ((2.0, 0.5, 1.0), 0.0, True),
    ((0.0, 0.0, -2.5), 0.0, True), ((1.5, -0.5, -1.0), 0.3, False), ((2.5, 0.0, 0.0), -0.4, False),
])  # fmt: skip
def test_the_cpu_warp_paints_in_occlusion_compatible_order_and_agrees_with_the_gpu(boxes_ldi, eye, yaw, exact):
    """Painter's order leaves the nearest surface on top, as a depth test does: never a farther
    surface (the sheets split at the epipole between pixel centres; splitting at its pixel's edge
    once painted the far box over the near one along the epipole's row and column).  Where splats
    wider than a pixel overlap on one slanted surface, which of its samples stays on top may differ
    by a few per cent of depth."""
    ldi = boxes_ldi
    camera = view_camera(eye, yaw, FOV, 96, 0.05, 100.0)
    image, depth = warp_cpu(ldi, camera)
    brute = _zbuffer_warp(ldi, camera)
    reached = np.isfinite(depth)
    assert reached.sum() > 500 and np.array_equal(reached, np.isfinite(brute))
    assert not np.any(depth[reached] > 1.1 * brute[reached])  # never a farther surface
    same = np.isclose(depth[reached], brute[reached], rtol=0.01)
    assert np.mean(same) >= (0.999 if exact else 0.97)
    with SplatRenderer([], [ldi]) as gpu:
        raw = gpu.render_raw(camera)
    both = reached & (raw[..., 3] > 0)
    assert np.mean(reached == (raw[..., 3] > 0)) >= 0.995
    assert np.mean(np.all(np.abs(image[both, :3].astype(int) - raw[both, :3].astype(int)) <= 2, axis=-1)) >= 0.97


def test_the_epipole_is_the_eye_projected_and_its_sign_says_in_front_or_behind(boxes_ldi):
    cam = boxes_ldi.camera
    c, r, w = epipole(cam, cam.eye + 3.0 * cam.forward)
    n = cam.resolution
    t = math.tan(0.5 * cam.fov)
    assert (
        w == pytest.approx(3.0)
        and c == pytest.approx((-cam.offset[0] + t) / (2 * t) * n)
        and r == pytest.approx((t + cam.offset[1]) / (2 * t) * n)
    )
    assert epipole(cam, cam.eye - 3.0 * cam.forward)[2] == pytest.approx(-3.0)
    assert epipole(cam, cam.eye + cam.right)[2] > 0  # w = 0 is clamped to a tiny value of its sign


def test_the_3x3_pass_fills_pin_holes_and_does_not_grow_edges():
    image = np.zeros((5, 5, 4), np.uint8)
    image[1:4, 1:4] = [100, 150, 200, 255]
    image[2, 2] = 0
    reached = image[..., 3] > 0
    out = fill_pin_holes(image, reached)
    assert tuple(out[2, 2]) == (100, 150, 200, 255)
    assert np.all(out[0] == 0) and np.all(out[:, 0] == 0)  # outside pixels have at most 3 reached neighbours


@pytest.fixture(scope="module")
def city_images():
    scene = procedural.city(64, seed=1, detail=8)
    lo, hi = scene.bounds
    a, b = 0.75 * lo + 0.25 * hi, 0.25 * lo + 0.75 * hi
    placement = place_primitives(
        scene, [a[0], 3, a[2]], [b[0], 7, b[2]], BudgetSettings(primitives=0.3 * scene.triangle_count, max_level=3)
    )
    return scene, placement


@pytest.mark.slow
def test_hybrid_frames_have_few_holes_and_nine_images_fewer_than_one(city_images):
    scene, placement = city_images
    rng = np.random.default_rng(0)
    with_images = [i for i, p in enumerate(placement.points) if p.images]
    holes = {1: 0, 9: 0}
    footprint = 0
    for pi in rng.choice(with_images, 4, replace=False):
        point = placement.points[pi]
        image = point.images[0]
        eyes = boundary_eyes(point, image, placement.half, 4, rng)
        ldis = {n: image_ldi(scene, placement, point, image, 128, n).ldi for n in (1, 9)}
        at_point, _ = frame_holes(scene, placement, point.position, image["yaw"], pi, 0, ldis[9], 128, 0.1, 5000.0)
        assert at_point.share <= 0.01  # from the grid point itself the LDI is the central image
        for eye, yaw in eyes:
            for n in (1, 9):
                result, _ = frame_holes(scene, placement, eye, yaw, pi, 0, ldis[n], 128, 0.1, 5000.0)
                holes[n] += result.holes
            footprint += result.footprint
    assert footprint > 1000 and holes[9] < 0.6 * holes[1]  # seed 004 Fig. 10: nine images leave far fewer gaps
    assert holes[9] < 0.05 * footprint


def test_the_ldi_technique_refuses_a_part_that_reaches_into_its_cell_and_bad_payloads():
    from farfield.core.errors import BundleFormatError, LayerPlanError
    from farfield.core.impostor.impostor import LdiPayload
    from farfield.core.scene import Scene
    from farfield.core.techniques import get_technique
    from farfield.core.viewcells import BoxCell

    technique = get_technique("ldi")
    scene = Scene.from_objects(_boxes(), "boxes")
    options = technique.options({"images": 1}, 64)
    far_cell = BoxCell(np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0]))
    assert technique.check(far_cell, options, scene.bounds).layers == 1
    one = technique.bake(scene, far_cell, options, None, None)
    assert one.stats["construction_images"] == 1 and one.payload.count == one.stats["samples"] > 0
    near_cell = BoxCell(
        np.array([-3.0, -3.0, -6.0]), np.array([3.0, 3.0, 0.0])
    )  # half-diagonal 5.8, the part starts 6 ahead of -3
    with pytest.raises(LayerPlanError, match="half-diagonal"):
        technique.check(near_cell, options, scene.bounds)
    with pytest.raises(LayerPlanError, match="1 or 9"):
        technique.options({"images": 4}, 64)
    good = one.payload
    bad = LdiPayload(good.eye, 2 * good.axes, good.window, good.size, good.quad)
    with pytest.raises(BundleFormatError, match="orthonormal"):
        bad.check(len(one.pages))
    with pytest.raises(BundleFormatError, match="pages"):
        good.check(len(one.pages) - 1)
    # the pages hold the LDI: depth and colour come back bit for bit
    from farfield.core.ldi.image import ldi_of

    back = ldi_of(one)
    assert back.count == one.payload.count and back.layers == one.stats["layers"]
