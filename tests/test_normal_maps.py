"""A source's own normal map (glTF ``normalTexture``): read with its tangents, drawn in the G-buffer
as three.js draws it, and recorded into a lit impostor."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from farfield.core.exchange import load_scene
from farfield.core.quality.lit import evaluate_lit
from farfield.core.render.raster import Camera, MeshRenderer
from farfield.core.scene import Scene
from farfield.core.techniques.layered import BakeOptions, bake_layered
from farfield.core.viewcells import BoxCell

HELMET = Path(__file__).resolve().parents[2] / "shared" / "scenes" / "damaged_helmet" / "DamagedHelmet.glb"
needs_helmet = pytest.mark.skipif(not HELMET.is_file(), reason=f"needs the shared scene {HELMET}")


def angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.einsum("...i,...i->...", a, b), -1.0, 1.0)))


def unmapped(scene: Scene) -> Scene:
    """The scene with its normal maps left out (vertex normals only)."""
    plain = [replace(o, normal_texture=None, normal_uv=None, tangents=None) for o in scene.objects]
    return Scene(tuple(plain), scene.source)


def helmet_cameras(scene: Scene, resolution: int) -> list[Camera]:
    centre = 0.5 * (scene.bounds[0] + scene.bounds[1])
    size = float(np.max(scene.bounds[1] - scene.bounds[0]))
    eyes = [centre + size * np.array(d) for d in ([0.0, 0.3, 1.6], [1.2, 0.5, 1.0], [-1.3, -0.2, 0.9])]
    return [Camera.look_at(eye, centre, math.radians(40.0), resolution, 0.1 * size, 4.0 * size) for eye in eyes]


@needs_helmet
def test_the_helmets_normal_map_is_read_with_tangents_on_the_front_of_its_normals():
    (helmet,) = load_scene(HELMET).objects
    assert helmet.normal_texture is not None and helmet.normal_texture.shape == (2048, 2048, 4)
    assert helmet.tangents.shape == (len(helmet.vertices), 4)
    assert set(np.unique(helmet.tangents[:, 3])) <= {-1.0, 1.0}
    # Derived tangents are unit and orthogonal to the normals.
    assert np.allclose(np.linalg.norm(helmet.tangents[:, :3], axis=1), 1.0)
    assert np.abs(np.einsum("ij,ij->i", helmet.tangents[:, :3], helmet.normals)).max() < 1e-9


@needs_helmet
def test_three_js_draws_the_helmets_mapped_normals_as_farfields_g_buffer(threejs):
    """three.js (GLTFLoader; derivative tangents where the file has no TANGENT) draws the helmet's
    world normals after its normal map; farfield's G-buffer agrees on the pixels inside both
    silhouettes, far better than without the map."""
    from threejs import decode_normals

    scene = load_scene(HELMET)
    cameras = helmet_cameras(scene, 160)
    theirs = threejs.render(HELMET, cameras, output="normal")
    with MeshRenderer(scene.objects, normals=True) as mapped, MeshRenderer(unmapped(scene).objects, normals=True) as plain:
        for camera, three in zip(cameras, theirs, strict=True):
            image, ours = mapped.render_normals(camera)
            _, flat = plain.render_normals(camera)
            both = (image[..., 3] > 0) & (three[..., 3] > 0)
            inner = both.copy()
            inner[1:-1, 1:-1] &= both[:-2, 1:-1] & both[2:, 1:-1] & both[1:-1, :-2] & both[1:-1, 2:]
            expected = decode_normals(three)[inner]
            error, without = angles(ours[inner], expected), angles(flat[inner], expected)
            print("helmet normals", np.median(error), np.percentile(error, 95), "without the map", np.median(without))
            assert inner.sum() > 3000
            assert np.median(error) <= 1.0 and np.percentile(error, 95) <= 3.0
            assert np.median(without) >= 1.5 * np.median(error)


@needs_helmet
def test_a_lit_layered_impostor_of_the_helmet_keeps_its_mapped_normals():
    scene = load_scene(HELMET)
    lo, hi = scene.bounds
    size = float(np.max(hi - lo))
    cell = BoxCell.from_center(0.5 * (lo + hi) + np.array([0.0, 0.0, 3.0 * size]), 0.2 * size)
    impostor = bake_layered(scene, cell, BakeOptions(resolution=192, channels="albedo+normal"))
    t = evaluate_lit(scene, impostor, random_count=0).totals
    print(t)
    assert t["normal_error_interior_median"] <= 5.0
    # The same impostor's normals against the geometry without its map: the map is what it kept.
    plain = evaluate_lit(unmapped(scene), impostor, random_count=0).totals
    assert plain["normal_error_interior_median"] > 1.5 * t["normal_error_interior_median"]
