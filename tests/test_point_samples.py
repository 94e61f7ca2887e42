"""The points of a point-based impostor (core/techniques/points/samples.py, seed 001 §5.1): the three LDIs'
samples less the redundant ones leave no hole from anywhere in the view cell.

The check is independent of the removal rule: every kept point is projected (numpy) into views from
the cell's corners, centre and random points inside, as one-pixel points with a z-buffer; a pixel
the geometry covers (the first layer of that view's own depth-peeled LDI) must receive a point,
and its nearest point must lie on the first surface there, not behind it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from farfield.core.ldi.image import record_ldi
from farfield.core.quality.evaluation import compare_images
from farfield.core.render.peeling import peel
from farfield.core.render.points import PointRenderer
from farfield.core.render.raster import MeshRenderer
from farfield.core.scene import SceneObject
from farfield.core.techniques.envmap.runtime import camera_at
from farfield.core.techniques.points.cover import covering_points
from farfield.core.techniques.points.samples import CONTINUITY, _lookup, gather_point_samples, ldi_spacing
from farfield.core.techniques.points.sampling import plan_point_sampling
from farfield.core.viewcells import BoxCell
from tests.scenes import dense_mesh, real_scene

RESOLUTION = 96


def _mesh(name: str, mesh: trimesh.Trimesh, offset) -> SceneObject:
    return SceneObject(name, np.asarray(mesh.vertices) + np.asarray(offset, dtype=np.float64), np.asarray(mesh.faces))


def _ball_and_box() -> list[SceneObject]:
    return [
        _mesh("ball", trimesh.creation.icosphere(subdivisions=3, radius=1.5), [0.5, 1.0, 9.0]),
        _mesh("box", trimesh.creation.box([1.0, 1.0, 1.0]), [-1.2, -0.5, 7.0]),
    ]


def _trunks() -> list[SceneObject]:
    """Thin trunks in front of a wall: depth discontinuities everywhere."""
    rng = np.random.default_rng(4)
    trunks = [
        _mesh(f"trunk{i}", trimesh.creation.box([0.08, 3.0, 0.08]), [x, 0.0, z])
        for i, (x, z) in enumerate(zip(rng.uniform(-1.5, 1.5, 12), rng.uniform(6.0, 9.0, 12)))
    ]
    return [*trunks, _mesh("wall", trimesh.creation.box([4.0, 4.0, 0.1]), [0.0, 0.0, 10.0])]


def _bounds(objects) -> np.ndarray:
    return np.stack([np.min([o.bounds[0] for o in objects], axis=0), np.max([o.bounds[1] for o in objects], axis=0)])


def _holes_and_wrong_surface(objects, cell: BoxCell, points: np.ndarray, unseen: int = 0) -> tuple[int, int, int]:
    # From the cell's corners, centre and 8 random points, and ``unseen`` more random points (seed 7).
    bounds = _bounds(objects)
    target = 0.5 * (bounds[0] + bounds[1])
    holes = wrong = covered_total = 0
    eyes = [cell.corners(), cell.center[None], cell.sample_random(8, 1)] + (
        [cell.sample_random(unseen, 7)] if unseen else []
    )
    for eye in np.concatenate(eyes):
        camera = camera_at(eye, target - eye, 45.0, RESOLUTION, 1.0, 30.0)
        first = record_ldi(objects, camera).depth[0]
        pixels = camera.project(points)
        depth = (points - camera.eye) @ camera.forward
        column, row = np.floor(pixels[:, 0]).astype(int), np.floor(pixels[:, 1]).astype(int)
        inside = (column >= 0) & (column < RESOLUTION) & (row >= 0) & (row < RESOLUTION) & (depth > 0.0)
        nearest = np.full((RESOLUTION, RESOLUTION), np.inf)
        np.minimum.at(nearest, (row[inside], column[inside]), depth[inside])
        covered = np.isfinite(first)
        holes += int((covered & ~np.isfinite(nearest)).sum())
        wrong += int((covered & np.isfinite(nearest) & (nearest > first * 1.005)).sum())
        covered_total += int(covered.sum())
    return holes, wrong, covered_total


def _points(objects):
    cell = BoxCell.from_center([0.0, 0.0, 0.0], 1.0)
    sampling = plan_point_sampling(cell, _bounds(objects), 45.0, RESOLUTION)
    return cell, gather_point_samples(objects, sampling, cell, 45.0, RESOLUTION)


@pytest.mark.parametrize("scene", [_ball_and_box, _trunks])
@pytest.mark.slow
def test_kept_points_leave_no_hole_from_anywhere_in_the_cell(scene):
    objects = scene()
    cell, points = _points(objects)
    stats = points.stats
    assert stats["candidates"] == sum(c["candidates"] for c in stats["per_camera"]) > 1000
    # Seed 001 §5.1 reports 40-60 % removed; here 55 % on the ball and box, less among the trunks,
    # whose thin sides are all discontinuity.
    assert 0.1 < stats["removed_share"] < 0.7
    holes, wrong, covered = _holes_and_wrong_surface(objects, cell, points.positions[points.kept])
    assert covered > 5000 and holes == 0 and wrong == 0


@pytest.mark.parametrize("scene", [_ball_and_box, _trunks])
@pytest.mark.slow
def test_a_removed_point_has_a_kept_point_within_a_pixel_of_it(scene):
    # Redundant means another camera samples the same place finely enough: a kept point lies within
    # the smallest output pixel's footprint there (seen from the nearest point of the cell), or
    # somewhat more where the sample that stood for it was itself replaced by a third camera's.
    cell, points = _points(scene())
    removed = points.positions[~points.kept]
    assert removed.shape[0] > 1000
    distance, _ = cKDTree(points.positions[points.kept]).query(removed)
    beta = 2.0 * np.tan(np.radians(22.5)) / RESOLUTION / (1.0 + 2.0 * np.tan(np.radians(22.5)) ** 2)
    footprint = beta * np.linalg.norm(removed - np.clip(removed, cell.lo, cell.hi), axis=1)
    assert np.all(distance <= 1.5 * footprint), float(np.max(distance / footprint))


def test_a_sample_stands_only_for_points_on_its_own_surface():
    # Another LDI's sample covers a point only when it lies on the point's surface there: within
    # the continuity tolerance of the point's depth along that LDI's ray, not merely in its pixel.
    wall = SceneObject(
        "wall",
        np.array([[-5.0, -5.0, 8.0], [5.0, -5.0, 8.0], [5.0, 5.0, 8.0], [-5.0, 5.0, 8.0]]),
        np.array([[0, 1, 2], [0, 2, 3]]),
    )
    camera = camera_at(np.zeros(3), [0.0, 0.0, 1.0], 45.0, 32, 1.0, 20.0)
    ldi = record_ldi([wall], camera)
    spacing = np.full(ldi.depth.shape, 0.01)
    on_wall = np.array([[0.1, 0.2, 8.0], [-1.0, 0.5, 8.0]])
    in_front = np.array([[0.1, 0.2, 6.0], [-0.75, 0.375, 6.0]])  # the same pixels, 2 units nearer
    assert np.all(_lookup(ldi, spacing, on_wall) == 0.01)
    assert np.all(np.isinf(_lookup(ldi, spacing, in_front)))
    # An LDI that recorded nothing stands for nothing (and does not fail).
    empty = record_ldi([], camera)
    assert empty.layers == 0 and np.all(np.isinf(_lookup(empty, np.zeros((0, 32, 32)), on_wall)))


def test_the_one_colour_preview_draws_the_part_without_holes_and_close_in_colour():
    # Seed 001 §5.3's preview (one colour per point, 1-pixel points on the GL) against the textured
    # shared duck drawn as geometry by the same camera: no hole pixel from the cell's corners and
    # centre, and colours off only where texture detail is finer than the points (measured on
    # llvmpipe at 128 px: mean 0.77-1.38 of 255 per view, 8 of 2,833 pixels off by more than 64).
    duck = real_scene("duck/duck.obj")
    objects = list(duck.objects)
    lo, hi = duck.bounds
    size, target = float(np.max(hi - lo)), 0.5 * (lo + hi)
    cell = BoxCell.from_center([target[0], target[1], lo[2] - 2.0 * size], 0.25 * size)
    sampling = plan_point_sampling(cell, duck.bounds, 45.0, RESOLUTION)
    points = gather_point_samples(objects, sampling, cell, 45.0, RESOLUTION)
    with (
        PointRenderer(points.positions[points.kept], points.colour[points.kept]) as preview,
        MeshRenderer(objects) as geometry,
    ):
        for eye in np.concatenate([cell.corners(), cell.center[None]]):
            camera = camera_at(eye, target - eye, 45.0, RESOLUTION, 0.01 * size, 10.0 * size)
            stats = compare_images(geometry.render(camera), preview.render(camera))
            assert stats["geometry_pixels"] > 1000 and stats["hole_pixels"] == 0 and stats["bloat_beyond_1px"] == 0
            assert stats["colour_error_mean"] < 3.0


def _shifted(array: np.ndarray, dr: int, dc: int, fill) -> np.ndarray:
    """``array`` (..., h, w) moved so that [..., r, c] holds the value at [..., r + dr, c + dc]."""
    out = np.full_like(array, fill)
    h, w = array.shape[-2:]
    rs, re = max(0, -dr), min(h, h - dr)
    cs, ce = max(0, -dc), min(w, w - dc)
    out[..., rs:re, cs:ce] = array[..., rs + dr : re + dr, cs + dc : ce + dc]
    return out


def spacing_with_arrays(ldi, cell: BoxCell) -> np.ndarray:
    """:func:`farfield.core.techniques.points.samples.ldi_spacing`'s rule written with whole numpy arrays (it was the
    implementation before the numba kernel): per neighbour direction, the nearest layer of the
    shifted image, the continuity test, the edge's component across the cell's rays."""
    depth = ldi.depth
    centre, radius = cell.center, 0.5 * float(np.linalg.norm(cell.size))
    positions = ldi.sample_positions()
    pixel = 2.0 * math.tan(0.5 * ldi.camera.fov) / ldi.camera.resolution
    spacing = np.zeros(depth.shape)
    for dr, dc in ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)):
        other = _shifted(depth, dr, dc, np.nan)
        other = np.where(np.isnan(other), np.inf, other)
        other_pos = _shifted(np.moveaxis(positions, -1, 0), dr, dc, np.nan)
        step = pixel * math.hypot(dr, dc)
        for layer in range(depth.shape[0]):
            gap = np.abs(other - depth[layer])
            nearest = np.argmin(gap, axis=0)
            best = np.take_along_axis(gap, nearest[None], axis=0)[0]
            same = best <= CONTINUITY * depth[layer] * step
            q = np.take_along_axis(other_pos, np.broadcast_to(nearest[None, None], (3, 1) + nearest.shape), axis=1)[
                :, 0
            ]
            e = np.moveaxis(q, 0, -1) - positions[layer]
            length = np.linalg.norm(e, axis=-1)
            seen = positions[layer] - centre
            distance = np.linalg.norm(seen, axis=-1)
            with np.errstate(invalid="ignore", divide="ignore"):
                cos_theta = np.abs(np.einsum("...i,...i->...", e, seen)) / (length * distance)
                gamma = np.arcsin(np.clip(radius / distance, 0.0, 1.0))
            theta = np.arccos(np.clip(cos_theta, 0.0, 1.0))
            across = length * np.minimum(1.0, np.sin(np.minimum(theta + gamma, 0.5 * math.pi)))
            spacing[layer] = np.maximum(spacing[layer], np.where(same, across, np.inf))
    if ldi.touched is not None:
        spacing = np.where(ldi.touched, np.inf, spacing)
    return np.where(np.isfinite(depth), spacing, np.nan)


@pytest.mark.parametrize("scene", ["ball and box", "trunks"])
def test_the_spacing_kernel_keeps_the_rule_written_with_arrays(scene):
    objects = _ball_and_box() if scene == "ball and box" else _trunks()
    cell = BoxCell.from_center([0.0, 0.0, 0.0], 1.0)
    lo = np.min([o.bounds[0] for o in objects], axis=0)
    hi = np.max([o.bounds[1] for o in objects], axis=0)
    sampling = plan_point_sampling(cell, np.stack([lo, hi]), 45.0, RESOLUTION)
    for camera in sampling.cameras:
        ldi = record_ldi(objects, camera.camera(), conservative=True)
        fast, plain = ldi_spacing(ldi, cell), spacing_with_arrays(ldi, cell)
        assert np.isinf(fast).any() and np.isfinite(fast).any()
        assert np.allclose(fast, plain, rtol=1e-12, atol=0.0, equal_nan=True)


@pytest.mark.parametrize("scene", [_ball_and_box, _trunks])
def test_ldis_recorded_in_tiles_keep_the_whole_ldis_samples_and_leave_no_hole(scene):
    # A bake records each LDI tile by tile (each tile with a one-pixel border for the spacing's
    # neighbours, drawing only the triangles near it), so it holds one tile's layers at a time:
    # 40-pixel tiles (3 x 3 of them here) give the samples of the LDI recorded whole, at the same
    # places, and the kept points still leave no hole from anywhere in the cell.
    objects = scene()
    cell = BoxCell.from_center([0.0, 0.0, 0.0], 1.0)
    sampling = plan_point_sampling(cell, _bounds(objects), 45.0, RESOLUTION)
    assert min(c.resolution for c in sampling.cameras) > 80
    whole = gather_point_samples(objects, sampling, cell, 45.0, RESOLUTION)
    tiled = gather_point_samples(objects, sampling, cell, 45.0, RESOLUTION, tile=40)
    n = whole.stats["candidates"]
    assert abs(tiled.stats["candidates"] - n) <= 0.001 * n
    distance, _ = cKDTree(whole.positions).query(tiled.positions)
    assert np.mean(distance < 1e-4) > 0.99  # depths read back from a narrower frustum: float32 apart
    assert abs(tiled.stats["kept"] - whole.stats["kept"]) <= 0.03 * whole.stats["kept"]
    holes, wrong, covered = _holes_and_wrong_surface(objects, cell, tiled.positions[tiled.kept])
    assert covered > 5000 and holes == 0 and wrong == 0


def test_a_rough_dense_surface_keeps_at_most_four_points_per_bounding_box_pixel_without_holes():
    # Issue 60: a scan-like surface (20,480 triangles, ±2 % noise per vertex: folds finer than an
    # LDI pixel) from a cell a tenth of its distance away.  The points that win a pixel in 64 views
    # (the earlier visibility test) were 4.9 per pixel of the screen bounding box from the cell's
    # centre (Table 1 has 2.35-2.8) and left hole pixels from viewpoints between those views; the
    # cover of every pixel-sized window of 17 views keeps 3.9 (measured on llvmpipe) and leaves no
    # hole pixel from 17 views of the cell nor from 16 random viewpoints it never used.
    objects = list(dense_mesh(5).objects)
    cell = BoxCell.from_center([0.0, 0.0, -5.0], 0.5)
    sampling = plan_point_sampling(cell, _bounds(objects), 45.0, RESOLUTION)
    points = gather_point_samples(objects, sampling, cell, 45.0, RESOLUTION)
    kept = points.positions[points.kept]
    centre = camera_at(cell.center, -cell.center, 45.0, RESOLUTION, 1.0, 30.0)
    rows, columns = np.nonzero(np.isfinite(peel(objects, centre, 1, truncate=True)[0][0, ..., 0]))
    box = (np.ptp(rows) + 1) * (np.ptp(columns) + 1)
    needed = kept[covering_points(objects, kept, cell, 45.0, RESOLUTION)]
    assert needed.shape[0] <= 4.0 * box, needed.shape[0] / box
    holes, wrong, covered = _holes_and_wrong_surface(objects, cell, needed, unseen=16)
    assert covered > 10000 and holes == 0 and wrong <= 1, (holes, wrong)


@pytest.mark.parametrize("scene", [_ball_and_box, _trunks])
@pytest.mark.slow
def test_the_covering_points_leave_no_hole_from_views_the_cover_never_used(scene):
    # The cover keeps a fraction of the points and still leaves no hole pixel, nor a pixel whose
    # nearest point lies behind the first surface, from the cell's corners, centre and 16 random
    # viewpoints (8 of them used by no selection).
    objects = scene()
    cell, points = _points(objects)
    kept = points.positions[points.kept]
    needed = covering_points(objects, kept, cell, 45.0, RESOLUTION)
    assert 0 < needed.sum() < 0.8 * kept.shape[0]
    holes, wrong, covered = _holes_and_wrong_surface(objects, cell, kept[needed], unseen=8)
    assert covered > 10000 and holes == 0 and wrong == 0, (holes, wrong)
