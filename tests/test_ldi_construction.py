"""The LDI construction's shortcuts (core/ldi/construction.py, core/render/peeling.py) against the
plain computations they replace: the same cameras, vertices, sorted layers and peeled images."""

from __future__ import annotations

import math

import numpy as np
import pytest

from farfield.core import procedural
from farfield.core.ldi.construction import (
    _image_samples,
    _sorted_layers,
    _window,
    construction_cameras,
    construction_cops,
    ldi_camera,
    subset_vertices,
    view_frame,
)
from farfield.core.ldi.image import LayeredDepthImage
from farfield.core.render.peeling import Peeler, peel
from farfield.core.scene import SceneObject


def _plain_cameras(vertices, g, direction, quad, resolution):
    far = float(((vertices - g) @ view_frame(direction)[2]).max()) * (1 + 1e-6)
    camera = ldi_camera(g, direction, quad, float(((quad - g) @ view_frame(direction)[2]).min()), far, resolution)
    cops = construction_cops(g, quad)
    plain = [camera if np.array_equal(c, g) else _window(vertices, c, direction, resolution) for c in cops]
    return camera, cops, plain


def _same(a, b) -> bool:
    return all(
        np.array_equal(getattr(a, k), getattr(b, k))
        for k in ("eye", "right", "up", "forward", "fov", "resolution", "near", "far", "offset")
    )


@pytest.mark.parametrize("yaw", [0.0, 0.5 * np.pi, 0.3])  # axis-aligned views tie whole façades in depth
def test_the_construction_windows_are_those_of_every_vertex(yaw):
    scene = procedural.city(16, seed=2, detail=12)
    vertices = subset_vertices(list(scene.objects))
    centre = 0.5 * (scene.bounds[0] + scene.bounds[1])
    direction = np.array([np.sin(yaw), 0.0, np.cos(yaw)])
    g = centre - 200.0 * direction + np.array([0.0, 10.0, 0.0])
    r, u, _ = view_frame(direction)
    near = float(((vertices - g) @ direction).min())
    quad = np.array([g + near * (direction + a * r + b * u) for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
    camera, cops, plain = _plain_cameras(vertices, g, direction, quad, 64)
    fast = construction_cameras(vertices, cops, camera, direction, 64)
    assert len(fast) == 9 and all(_same(a, b) for a, b in zip(fast, plain))
    assert _same(fast[4], camera)  # the grid point's image is the LDI's own camera


def test_a_vertex_behind_a_construction_eye_is_still_refused():
    vertices = np.array([[0.0, 0.0, 10.0], [1.0, 0.0, 10.0], [0.0, 1.0, -5.0]])
    quad = np.array([[-1.0, -1.0, 5.0], [1.0, -1.0, 5.0], [1.0, 1.0, 5.0], [-1.0, 1.0, 5.0]])
    g = np.zeros(3)
    camera = ldi_camera(g, np.array([0.0, 0.0, 1.0]), quad, 5.0, 20.0, 16)
    with pytest.raises(ValueError, match="behind the centre of projection"):
        construction_cameras(vertices, construction_cops(g, quad), camera, np.array([0.0, 0.0, 1.0]), 16)


def test_subset_vertices_are_the_used_ones_in_order():
    rng = np.random.default_rng(4)
    objects = [SceneObject(f"o{k}", rng.normal(size=(50, 3)), rng.integers(0, 50, (30, 3))) for k in range(3)]
    plain = np.concatenate([o.vertices[np.unique(o.faces)] for o in objects])
    assert np.array_equal(subset_vertices(objects), plain)


def test_with_faces_compacts_as_unique_does():
    rng = np.random.default_rng(5)
    obj = SceneObject("o", rng.normal(size=(400, 3)), rng.integers(0, 400, (900, 3)))
    for chosen in (np.arange(0, 900, 7), rng.random(900) < 0.2, obj.faces[:3]):
        triangles = obj.faces[chosen] if np.asarray(chosen).ndim == 1 else chosen
        used, inverse = np.unique(triangles, return_inverse=True)
        kept = obj.with_faces(chosen)
        assert np.array_equal(kept.faces, inverse.reshape(-1, 3)) and np.array_equal(kept.vertices, obj.vertices[used])


def test_the_layer_sort_is_the_stable_argsort():
    rng = np.random.default_rng(6)
    cap, n = 5, 12
    count = rng.integers(0, cap + 1, (n, n))
    depth = np.full((cap, n, n), np.nan)
    for m in range(cap):
        depth[m] = np.where(m < count, rng.integers(1, 4, (n, n)).astype(float), np.nan)  # many equal depths
    obj = np.where(np.isfinite(depth), rng.integers(0, 9, depth.shape), -1)
    tri = np.where(np.isfinite(depth), np.arange(depth.size).reshape(depth.shape), -1)
    col = np.where(np.isfinite(depth)[..., None], rng.integers(1, 255, depth.shape + (4,)), 0).astype(np.uint8)
    layers = int(count.max())
    order = np.argsort(np.where(np.isfinite(depth[:layers]), depth[:layers], np.inf), axis=0, kind="stable")
    sorted_ = _sorted_layers(depth, obj, tri, col, count, layers)
    for got, a in zip(sorted_, (depth, obj, tri, col)):
        want = np.take_along_axis(a[:layers], order if a.ndim == 3 else order[..., None], axis=0)
        assert np.array_equal(got, want, equal_nan=a.dtype.kind == "f")


def test_one_upload_peels_every_camera_as_a_fresh_one():
    scene = procedural.city(9, seed=3, detail=4)
    objects = list(scene.objects)
    vertices = subset_vertices(objects)
    centre = 0.5 * (scene.bounds[0] + scene.bounds[1])
    direction = np.array([0.2, -0.1, 1.0])
    g = centre - 90.0 * direction / np.linalg.norm(direction)
    cops = construction_cops(g, g + np.array([[-9.0, -9, 40], [9, -9, 40], [9, 9, 40], [-9, 9, 40]]))
    cameras = [_window(vertices, c, direction, 48) for c in cops[:3]]
    with Peeler(objects) as peeler:
        for camera in cameras:
            hits, colours = peeler.peel(camera, max_layers=1, truncate=True)
            fresh_hits, fresh_colours = peel(objects, camera, max_layers=1, truncate=True)
            assert np.isfinite(hits[..., 0]).sum() > 100
            assert np.array_equal(hits, fresh_hits, equal_nan=True) and np.array_equal(colours, fresh_colours)
            # the compiled gather of the image's samples is LayeredDepthImage's, to the bit
            image = LayeredDepthImage(
                camera, hits[..., 0], hits[..., 1].astype(np.int64), hits[..., 2].astype(np.int64)
            )
            index = np.argwhere(np.isfinite(image.depth))
            at = (index[:, 0], index[:, 1], index[:, 2])
            positions, obj, tri, col = _image_samples(hits, colours, camera.eye, camera.right, camera.up, camera.forward,
                                                      *map(float, camera.offset), math.tan(0.5 * camera.fov), camera.resolution)  # fmt: skip
            assert np.array_equal(positions, image.sample_positions()[at])
            assert np.array_equal(obj, image.obj[at]) and np.array_equal(tri, image.triangle[at])
            assert np.array_equal(col, colours[at])
        assert peeler.seconds["draw"] > 0.0
