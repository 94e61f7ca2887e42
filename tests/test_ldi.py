"""Layered depth images by depth peeling on EGL (core/ldi/image.py, core/render/peeling.py): every surface
along every pixel ray, checked against the geometry the rays were cast at."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from farfield.core.errors import LayerPlanError
from farfield.core.ldi.image import record_ldi
from farfield.core.render.raster import Camera
from farfield.core.scene import SceneObject
from farfield.core.techniques.points.sampling import plan_point_sampling
from farfield.core.viewcells import BoxCell


def _quad(name: str, z: float, half: float = 1.0, **kwargs) -> SceneObject:
    vertices = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]])
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    return SceneObject(name, vertices, np.array([[0, 1, 2], [0, 2, 3]]), uv=uv, **kwargs)


def _camera(resolution: int = 48, near: float = 0.5, far: float = 20.0) -> Camera:
    return Camera.look_at(np.zeros(3), np.array([0.0, 0.0, 1.0]), math.radians(50.0), resolution, near, far)


def test_a_stack_of_planes_gives_one_layer_per_plane_nearest_first():
    planes = [_quad(f"q{z}", float(z), half=50.0) for z in (7, 3, 9, 5, 4)]  # drawn out of order
    ldi = record_ldi(planes, _camera())
    assert ldi.layers == 5 and ldi.count == 5 * 48 * 48
    assert np.allclose(ldi.depth[:, 24, 24], [3.0, 4.0, 5.0, 7.0, 9.0], rtol=1e-6)
    assert [int(np.unique(ldi.obj[k])[0]) for k in range(5)] == [1, 4, 3, 0, 2]
    positions, index = ldi.samples()
    assert np.allclose(positions[:, 2], ldi.depth[index[:, 0], index[:, 1], index[:, 2]], rtol=1e-6)
    # Every sample lies on its pixel's centre ray.
    assert np.abs(ldi.camera.project(positions) - (index[:, [2, 1]] + 0.5)).max() < 1e-3
    with pytest.raises(LayerPlanError, match="more than 3 surfaces"):
        record_ldi(planes, _camera(), max_layers=3)


def test_back_faces_count_so_a_closed_mesh_gives_two_hits_a_ray():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=2.0)
    obj = SceneObject("ball", np.asarray(sphere.vertices) + [0.3, -0.2, 8.0], np.asarray(sphere.faces))
    ldi = record_ldi([obj], _camera(64, 5.0, 11.0))
    hits = np.isfinite(ldi.depth).sum(axis=0)
    assert ldi.layers == 2 and hits.max() == 2
    assert (hits == 2).sum() > 0.2 * 64 * 64 and (hits == 1).sum() <= 0.02 * (hits > 0).sum()  # grazing rays only
    positions, index = ldi.samples()
    # Each sample lies on the triangle it names: in its plane and inside it.
    faces = obj.faces[ldi.triangle[index[:, 0], index[:, 1], index[:, 2]]]
    a, b, c = (obj.vertices[faces[:, k]] for k in range(3))
    normal = np.cross(b - a, c - a)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    assert np.abs(np.einsum("ij,ij->i", positions - a, normal)).max() < 1e-4
    barycentric = trimesh.triangles.points_to_barycentric(np.stack([a, b, c], axis=1), positions)
    assert barycentric.min() > -1e-3


def test_alpha_cut_texels_are_not_surfaces():
    texture = np.zeros((8, 8, 4), dtype=np.uint8)
    texture[..., :3] = 200
    texture[..., 3] = np.where(
        (np.arange(8)[:, None] // 2 + np.arange(8)[None, :] // 2) % 2 == 0, 255, 0
    )  # 2x2-texel checker
    screen = _quad("screen", 4.0, half=1.0, texture=texture, alpha_cutoff=0.5)
    wall = _quad("wall", 6.0, half=50.0)
    ldi = record_ldi([screen, wall], _camera(96))
    positions, index = ldi.samples()
    on_screen = ldi.obj[index[:, 0], index[:, 1], index[:, 2]] == 0
    # Texel of each screen sample (u right, v up; the texture's first row is the top, v = 1).
    u = (positions[on_screen, 0] + 1.0) / 2.0
    v = (positions[on_screen, 1] + 1.0) / 2.0
    column, row = np.floor(u * 8).astype(int).clip(0, 7), np.floor((1.0 - v) * 8).astype(int).clip(0, 7)
    texel_u, texel_v = (u * 8) % 1.0, ((1.0 - v) * 8) % 1.0
    inner = (np.abs(texel_u - 0.5) < 0.3) & (np.abs(texel_v - 0.5) < 0.3)  # away from bilinear blending
    assert on_screen.sum() > 100 and np.all(texture[row[inner], column[inner], 3] == 255)
    # Behind transparent texels the wall is the first surface; behind opaque ones the second.
    inside = (np.abs(positions[:, 0]) < 0.99) & (np.abs(positions[:, 1]) < 0.99) & ~on_screen
    first = index[inside, 0] == 0
    assert 0.35 < first.mean() < 0.65


def test_ldi_cameras_of_a_point_impostor_see_the_part_in_their_window():
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=1.5)
    obj = SceneObject("part", np.asarray(sphere.vertices) + [0.5, 1.0, 9.0], np.asarray(sphere.faces))
    sampling = plan_point_sampling(BoxCell.from_center([0.0, 0.0, 0.0], 1.0), obj.bounds, 45.0, 64)
    for camera in sampling.cameras:
        ldi = record_ldi([obj], camera.camera())
        positions, index = ldi.samples()
        assert ldi.count > 0.3 * camera.resolution**2  # the off-axis window is filled by the sphere
        assert np.abs(np.linalg.norm(positions - [0.5, 1.0, 9.0], axis=1) - 1.5).max() < 0.05  # on the sphere
        assert np.abs(ldi.camera.project(positions) - (index[:, [2, 1]] + 0.5)).max() < 1e-3


def test_a_conservative_ldi_samples_geometry_thinner_than_a_pixel_in_every_pixel_it_crosses():
    # A sliver a fifth of a pixel wide, between two pixel centres: no centre ray meets it.
    camera = _camera(64, 1.0, 10.0)
    pixel = 2.0 * math.tan(0.5 * camera.fov) / 64 * 5.0  # one pixel's width at depth 5
    x0 = 0.6 * pixel
    sliver = SceneObject(
        "sliver",
        np.array([[x0, -1.0, 5.0], [x0 + 0.2 * pixel, -1.0, 5.0], [x0 + 0.2 * pixel, 1.0, 5.0], [x0, 1.0, 5.0]]),
        np.array([[0, 1, 2], [0, 2, 3]]),
    )
    wall = _quad("wall", 8.0, half=50.0)
    plain = record_ldi([sliver, wall], camera)
    assert not (plain.obj == 0).any()  # missed by every centre ray
    ldi = record_ldi([sliver, wall], camera, conservative=True)
    on_sliver = (ldi.obj == 0) & np.isfinite(ldi.depth)
    rows = np.unique(np.argwhere(on_sliver)[:, 1])
    expected = np.flatnonzero(
        np.any(
            np.abs(
                camera.project(np.array([[x0, y, 5.0] for y in np.linspace(-1.0, 1.0, 2001)]))[:, 1][:, None]
                - (np.arange(64) + 0.5)[None, :]
            )
            <= 0.5,
            axis=0,
        )
    )
    assert set(expected.tolist()) <= set(rows.tolist())  # every row the sliver crosses has a sample
    assert on_sliver.sum() <= 2 * len(rows)  # one surface, one sample a pixel (its two triangles merged)
    positions, index = ldi.samples()
    mine = ldi.obj[index[:, 0], index[:, 1], index[:, 2]] == 0
    assert np.allclose(positions[mine, 2], 5.0) and np.all(
        (positions[mine, 0] >= x0 - 1e-9) & (positions[mine, 0] <= x0 + 0.2 * pixel + 1e-9)
    )
    # Within its pixel's square, on the sliver's edge nearest the pixel centre.
    pixels = camera.project(positions[mine]) - index[mine][:, [2, 1]]
    assert np.all((pixels >= -1e-6) & (pixels <= 1.0 + 1e-6))
    # The wall behind keeps its centre samples; nothing else is added on it.
    assert (ldi.obj == 1).sum() == (plain.obj == 1).sum()


def test_a_conservative_ldi_samples_an_alpha_cut_needle_in_every_pixel_it_crosses():
    # A card whose only opaque texels are a red column a fifth of a pixel wide, beside the centres.
    camera = _camera(64, 1.0, 10.0)
    pixel = 2.0 * math.tan(0.5 * camera.fov) / 64 * 5.0  # one pixel's width at depth 5
    texture = np.zeros((16, 512, 4), dtype=np.uint8)
    half = 40.0 * pixel  # the card spans 80 pixels: a texel is 80 / 512 of a pixel
    column = int(round((0.6 * pixel + half) / (2.0 * half) * 512))
    texture[:, column : column + 1] = (255, 0, 0, 255)
    card = _quad("card", 5.0, half=half, texture=texture, alpha_cutoff=0.5)
    wall = _quad("wall", 8.0, half=50.0)
    plain = record_ldi([card, wall], camera)
    assert not (plain.obj == 0).any()  # every centre ray meets a cut texel
    ldi = record_ldi([card, wall], camera, conservative=True)
    on_card = (ldi.obj == 0) & np.isfinite(ldi.depth)
    rows, cols = np.argwhere(on_card)[:, 1], np.argwhere(on_card)[:, 2]
    needle_x = (column + 0.5) / 512 * 2.0 * half - half
    expected = int(np.floor(camera.project(np.array([[needle_x, 0.0, 5.0]]))[0, 0]))
    assert set(range(64)) <= set(rows.tolist()) and set(cols.tolist()) == {
        expected
    }  # every row, the column the needle crosses
    assert on_card.sum() == 64  # one sample a pixel
    positions, index = ldi.samples()
    mine = ldi.obj[index[:, 0], index[:, 1], index[:, 2]] == 0
    assert np.allclose(positions[mine, 2], 5.0)
    pixels = camera.project(positions[mine]) - index[mine][:, [2, 1]]
    assert np.all((pixels >= -1e-6) & (pixels <= 1.0 + 1e-6))  # in its own pixel (the centre: the card covers it)
    red = ldi.colour[on_card]
    assert np.all(red[:, 0] > 200) and np.all(red[:, 1:3] < 30), red[:4]  # the needle's colour, not a cut texel's


def merge_with_arrays(camera, centre, touched, objects):
    """:func:`farfield.core.ldi.image._merge` written with whole numpy arrays (it was the implementation before the
    numba kernels): touched layers nearest first, each sample kept unless a kept sample of its
    pixel lies within the same-surface tolerance; then every pixel's samples sorted by depth."""
    from farfield.core.ldi.image import SAME_SURFACE, LayeredDepthImage, _touch_positions

    (centre, centre_colours), (touched, touched_colours) = centre, touched
    pixel = 2.0 * math.tan(0.5 * camera.fov) / camera.resolution
    plain = LayeredDepthImage(camera, centre[..., 0], centre[..., 1].astype(np.int64), centre[..., 2].astype(np.int64))
    positions, depth, obj, tri = [plain.sample_positions()], [plain.depth], [plain.obj], [plain.triangle]
    kind, shade, kept_depth = [np.zeros(plain.depth.shape, dtype=bool)], [centre_colours], plain.depth
    for layer, layer_colour in zip(touched, touched_colours):
        d = layer[..., 0]
        near = (
            np.any(np.abs(kept_depth - d[None]) <= (SAME_SURFACE * pixel * d)[None], axis=0)
            if kept_depth.shape[0]
            else np.zeros(d.shape, bool)
        )
        keep = np.isfinite(d) & ~near
        if not keep.any():
            continue
        d = np.where(keep, d, np.nan)
        o, t = np.where(keep, layer[..., 1], -1).astype(np.int64), np.where(keep, layer[..., 2], -1).astype(np.int64)
        depth.append(d[None]), obj.append(o[None]), tri.append(t[None]), kind.append(keep[None])
        shade.append(np.where(keep[..., None], layer_colour, 0).astype(np.uint8)[None])
        positions.append(_touch_positions(camera, d, o, t, objects)[None])
        kept_depth = np.concatenate([kept_depth, d[None]])
    depth = np.concatenate(depth)
    order = np.argsort(depth, axis=0, kind="stable")
    take = lambda a: np.take_along_axis(a, order, axis=0)  # noqa: E731
    depth, obj, tri, kind = (
        take(depth),
        take(np.concatenate(obj)),
        take(np.concatenate(tri)),
        take(np.concatenate(kind)),
    )
    positions = np.take_along_axis(np.concatenate(positions), order[..., None], axis=0)
    colour = np.take_along_axis(np.concatenate(shade), order[..., None], axis=0)
    filled = np.isfinite(depth).any(axis=(1, 2))
    return depth[filled], obj[filled], tri[filled], kind[filled], positions[filled], colour[filled]


def test_the_merge_kernels_keep_the_rule_written_with_arrays():
    from farfield.core.ldi.image import SAME_SURFACE, _merge
    from farfield.core.render.peeling import peel

    camera = _camera(64, 1.0, 10.0)
    ball = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    pixel = 2.0 * math.tan(0.5 * camera.fov) / 64 * 5.0
    objects = [
        SceneObject("ball", np.asarray(ball.vertices) + [0.3, 0.0, 5.0], np.asarray(ball.faces)),
        SceneObject(
            "sliver",
            np.array(
                [[0.6 * pixel, -1.0, 4.0], [0.8 * pixel, -1.0, 4.0], [0.8 * pixel, 1.0, 4.0], [0.6 * pixel, 1.0, 4.0]]
            ),
            np.array([[0, 1, 2], [0, 2, 3]]),
        ),
        _quad("wall", 8.0, half=50.0),
    ]
    hits = peel(objects, camera)
    touched = peel(
        objects,
        camera,
        touching=True,
        centre=hits[0][..., 0],
        same_surface=SAME_SURFACE * 2.0 * math.tan(0.5 * camera.fov) / 64,
    )
    fast = _merge(camera, hits, touched, objects)
    depth, obj, tri, kind, positions, colour = merge_with_arrays(camera, hits, touched, objects)
    assert kind.any() and depth.shape[0] >= 3
    assert (
        np.array_equal(fast.depth, depth, equal_nan=True)
        and np.array_equal(fast.obj, obj)
        and np.array_equal(fast.triangle, tri)
    )
    assert (
        np.array_equal(fast.touched, kind)
        and np.array_equal(fast.positions, positions, equal_nan=True)
        and np.array_equal(fast.colour, colour)
    )
