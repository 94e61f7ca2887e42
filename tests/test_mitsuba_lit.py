"""Mitsuba 3 as a second opinion on the lit evaluation (benchmarks/bench_mitsuba_lit.py): runs only
where the optional extra ``reference`` (``mitsuba``) is installed, skipped elsewhere (CI).

What it holds: Mitsuba's physically based renders agree with :func:`farfield.core.quality.lighting.radiance`
where the two models are the same (GGX, Smith and Schlick of a metal's direct light; Lambert under
the ambient, which fixes the units of the environment standing for it), and a layered impostor's
normal page converted to the tangent frame Mitsuba builds on its quads lights the impostor like the
source, where the other handedness does not.
"""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

mi_module = pytest.importorskip("mitsuba")

from scenes import SHARED_SCENES  # noqa: E402

from farfield.core.quality.lighting import AMBIENT, DirectionalLight, default_lights, radiance  # noqa: E402
from farfield.core.render.raster import Camera  # noqa: E402

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_mitsuba_lit.py"


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_mitsuba_lit", BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def mi(bench):
    return bench.mitsuba()


def sphere_error(bench, mi, bsdf, light, ambient, rough, metal, spp) -> dict:
    """Mitsuba's sphere against ``radiance`` of its analytic G-buffer, 32 px."""
    camera = Camera.look_at(np.array([0.0, 0.0, 4.0]), np.zeros(3), math.radians(35.0), 32, 1.0, 10.0)
    hit, normal, view = bench.sphere_gbuffer(camera, 4)
    whole = bench.block_mean(hit.astype(np.float64), 4) == 1.0
    whole[1:-1, 1:-1] &= whole[:-2, 1:-1] & whole[2:, 1:-1] & whole[1:-1, :-2] & whole[1:-1, 2:]  # not the rim
    albedo = np.broadcast_to(np.asarray(bench.SPHERE_ALBEDO, np.uint8), hit.shape + (3,))
    ours = bench.srgb8(bench.block_mean(radiance(albedo, normal, view, light, ambient, rough, metal), 4))
    shapes = {"ball": {"type": "sphere", "center": [0.0, 0.0, 0.0], "radius": 1.0, "bsdf": bsdf}}
    sun = None if light.intensity == 0.0 else light
    sky = None if not np.any(ambient) else ambient
    theirs = bench.render(mi, shapes, camera, 32, spp, sun, sky)
    return bench.error_stats(ours, bench.srgb8(theirs[..., :3]), whole)


def test_metal_direct_light_matches_ggx(bench, mi):
    """A rough metal (no diffuse layer, Schlick F0 = base colour) under a 35° light: Mitsuba's
    principled and farfield's three.js arithmetic are the same model but for the Smith form
    (separable there, height-correlated here) and three.js's multiple-scattering compensation
    (about 5 % at roughness 0.5): 2.8 levels apart at 32 px; alpha = roughness instead of its
    square is 27 apart."""
    colour = bench.srgb_to_linear(np.asarray(bench.SPHERE_ALBEDO) / 255.0).tolist()
    light = default_lights()[3]
    stats = sphere_error(bench, mi, bench.principled(0.5, 1.0, colour), light, np.zeros(3), 0.5, 1.0, 32)
    assert stats["mean"] < 4.0, stats
    # a wrong roughness mapping (alpha = roughness, not its square) is far off
    wrong = sphere_error(bench, mi, bench.principled(math.sqrt(0.5), 1.0, colour), light, np.zeros(3), 0.5, 1.0, 32)
    assert wrong["mean"] > 2.0 * stats["mean"], (stats, wrong)


def test_ambient_is_a_constant_environment_of_ambient_over_pi(bench, mi):
    """Lambert under the environment alone: AMBIENT / π radiance gives farfield's ambient term (less
    its specular share, under 4 %: about one level)."""
    colour = bench.srgb_to_linear(np.asarray(bench.SPHERE_ALBEDO) / 255.0).tolist()
    dark = DirectionalLight(np.array([0.0, 1.0, 0.0]), np.zeros(3), 0.0)
    bsdf = {"type": "diffuse", "reflectance": {"type": "rgb", "value": colour}}
    stats = sphere_error(bench, mi, bsdf, dark, AMBIENT, 1.0, 0.0, 512)
    assert stats["mean"] < 2.5, stats


@pytest.mark.skipif(not (SHARED_SCENES / "duck" / "duck.obj").is_file(), reason="needs the shared duck")
def test_impostor_normal_page_in_mitsuba_tangent_frames(bench, mi):
    """The duck's layered impostor (64 px) under the light in front (35°, azimuth 240°) from its
    reference viewpoint: with its normal page in Mitsuba's tangent frames it is far closer to the
    source than flat cards or the same page read with the other handedness."""
    from farfield.core.exchange import load_scene
    from farfield.core.techniques.layered import BakeOptions, bake_layered
    from farfield.core.viewcells import BoxCell

    scene = load_scene(SHARED_SCENES / "duck" / "duck.obj")
    lo, hi = scene.bounds
    size = float(np.max(hi - lo))
    cell = BoxCell.from_center(0.5 * (lo + hi) + np.array([0.0, 0.0, 3.0 * size]), 0.2 * size)
    impostor = bake_layered(scene, cell, BakeOptions(resolution=64, channels="albedo+normal"))
    target = 0.5 * (lo + hi)
    camera = Camera.look_at(
        impostor.reference_viewpoint, target, math.radians(impostor.fov_deg), 64, 0.1 * size, 10 * size
    )
    light = default_lights()[3]
    frames = bench.mitsuba_frames(impostor)
    mirrored = frames * np.array([1.0, -1.0, 1.0])[None, :, None]
    shapes = {
        "source": bench.source_shapes(mi, scene),
        "normalmap": bench.impostor_shapes(mi, impostor, "normalmap", frames),
        "mirrored": bench.impostor_shapes(mi, impostor, "normalmap", mirrored),
        "flat": bench.impostor_shapes(mi, impostor, "flat"),
    }
    covered = {name: bench.coverage(mi, s, camera, 64, spp=4) > 0.99 for name, s in shapes.items()}
    srgb = {
        name: bench.srgb8(bench.render(mi, s, camera, 64, 16, light, AMBIENT)[..., :3]) for name, s in shapes.items()
    }
    errors = {
        name: bench.error_stats(srgb["source"], srgb[name], covered["source"] & covered[name])["mean"]
        for name in ("normalmap", "mirrored", "flat")
    }
    assert errors["normalmap"] < 8.0, errors
    assert 2.0 * errors["normalmap"] < errors["flat"], errors
    assert 2.0 * errors["normalmap"] < errors["mirrored"], errors
