"""Deferred shading (``core/quality/lighting.py``) on its own, and against three.js lighting the same
surface (``tests/threejs.py``'s lit and normal modes).

Unit tests: Lambert's 1/π and cosine at a rough dielectric, ambient only behind the light, the
specular lobe's energy against three.js's DFG table, Fresnel toward grazing, invariance under a
rotation of the whole configuration, and view directions against the camera's own projection.

The independent check draws a smooth UV sphere GLB (written here: a dielectric of one
``baseColorFactor``) in three.js under each default light, and shades farfield's expectation
without farfield's renderer: each pixel centre's ray meets the exact sphere in numpy, whose normal,
view direction and albedo go to :func:`shade`.  Both images are compared where both cover, less a
one-pixel rim (the tessellated silhouette).  ``output="normal"`` is checked against the same
analytic normals.
"""

from __future__ import annotations

import json
import math
import struct

import numpy as np
import pytest

from farfield.core.colour_space import linear_to_srgb, srgb_to_linear
from farfield.core.quality.dfg import TABLE, dfg
from farfield.core.quality.lighting import (
    AMBIENT,
    DirectionalLight,
    default_lights,
    f_schlick,
    geometry_roughness,
    radiance,
    shade,
    view_directions,
)
from farfield.core.render.raster import Camera

Z = np.array([0.0, 0.0, 1.0])
NO_AMBIENT = np.zeros(3)


def pixels(*vectors) -> np.ndarray:
    """(1, n, 3) float64 unit vectors: a one-row G-buffer."""
    v = np.array(vectors, dtype=np.float64)
    return (v / np.linalg.norm(v, axis=-1, keepdims=True))[None]


def toward(theta_deg: float, phi_deg: float = 0.0) -> np.ndarray:
    """(3,) unit vector at ``theta_deg`` from +z, azimuth ``phi_deg`` from +x."""
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def light(direction, intensity: float = math.pi) -> DirectionalLight:
    return DirectionalLight(np.asarray(direction, dtype=np.float64), np.ones(3), intensity)


# ---- the BRDF -----------------------------------------------------------------------------------


def test_lambert_at_normal_incidence_is_albedo_times_irradiance_over_pi():
    """N = V = L, roughness 1: diffuse albedo·E/π·(1 - F0') plus GGX's D = 1/π, V = 1/4, times the
    multi-scattering factor, computed here term by term; the sRGB bytes agree exactly."""
    levels = np.array([0, 30, 64, 128, 200, 255], dtype=np.uint8)
    albedo = np.repeat(levels[:, None], 3, axis=1)[None]
    n = pixels(*[Z] * len(levels))
    intensity = 2.0
    out = radiance(albedo, n, n, light(Z, intensity), NO_AMBIENT)
    f = 0.04 + 0.96 * 2.0**-12.53789  # Epic's Schlick at V·H = 1
    scale, bias = TABLE[-1, -1]  # N·V = 1, roughness 1: the table's corner texel
    specular = f * 0.25 / math.pi * (1.0 + 0.04 * (1.0 / (scale + bias) - 1.0))
    expected = intensity * (srgb_to_linear(levels / 255.0) / math.pi * (1.0 - f) + specular)
    np.testing.assert_allclose(out[0, :, 0], expected, rtol=1e-9)
    encoded = shade(albedo, n, n, light(Z, intensity), NO_AMBIENT)
    assert encoded[0, :, 0].tolist() == np.round(linear_to_srgb(expected) * 255).astype(int).tolist()


@pytest.mark.parametrize("theta", [0.0, 30.0, 60.0, 80.0])
def test_diffuse_follows_the_cosine_of_the_light(theta):
    """Rough white dielectric seen head-on: radiance ≈ E·cos θ/π, the rest within Fresnel and the
    (rough, dim) specular lobe."""
    white = np.full((1, 1, 3), 255, np.uint8)
    n = pixels(Z)
    out = float(radiance(white, n, n, light(toward(theta), math.pi), NO_AMBIENT)[0, 0, 0])
    lambert = math.cos(math.radians(theta))
    assert out == pytest.approx(lambert, rel=0.06)
    assert out < lambert * 1.02 + 1e-3  # never brighter than Lambert by more than the lobe


@pytest.mark.parametrize("direction", [-Z, toward(95.0), toward(135.0, 70.0), toward(179.0, 200.0)])
def test_a_light_behind_the_surface_gives_ambient_only(direction):
    albedo = np.array([[[200, 120, 60], [30, 90, 250]]], dtype=np.uint8)
    n, v = pixels(Z, Z), pixels(toward(20.0), toward(50.0, 90.0))
    lit = shade(albedo, n, v, light(direction, 5.0), AMBIENT, roughness=0.3)
    dark = shade(albedo, n, v, light(direction, 0.0), AMBIENT, roughness=0.3)
    assert lit.tolist() == dark.tolist()
    # and ambient alone is albedo·E/π less the specular layer's share (a few per cent at these angles)
    only = radiance(albedo, n, v, light(direction, 5.0), AMBIENT, roughness=0.3)
    lambert = srgb_to_linear(albedo / 255.0) * AMBIENT / math.pi
    assert np.all(only <= lambert * 0.97) and np.all(only >= lambert * 0.8)


def _rotations_taking(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(k, 3, 3) rotations taking each unit row of ``a`` (k, 3) to unit ``b`` (3,) (Rodrigues)."""
    v = np.cross(a, b)
    c = a @ b
    vx = np.zeros((len(a), 3, 3))
    vx[:, 0, 1], vx[:, 0, 2], vx[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    vx -= np.transpose(vx, (0, 2, 1))
    return np.eye(3) + vx + vx @ vx / (1.0 + c)[:, None, None]


def _reflected_fraction(
    albedo, roughness: float, view: np.ndarray, metallic: float = 0.0, n_theta: int = 192, n_phi: int = 256
) -> np.ndarray:
    """(3,) ∫ f(l, v) (n·l) dl over the hemisphere of n = +z: the fraction of a unit irradiance's
    light (one light per direction of a midpoint grid in cos θ, φ) reflected toward ``view``.
    Each light direction is one pixel: the whole configuration is turned so that the light is the
    same for all of them, which leaves every dot product as it was."""
    mu = (np.arange(n_theta) + 0.5) / n_theta  # cos θ
    phi = (np.arange(n_phi) + 0.5) / n_phi * 2.0 * math.pi
    mu, phi = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1.0 - mu**2)
    directions = np.stack([s * np.cos(phi), s * np.sin(phi), mu], axis=-1).reshape(-1, 3)
    fixed = np.array([1.0, 0.0, 0.0])
    rot = _rotations_taking(directions, fixed)
    n = (rot @ Z)[None]
    v = (rot @ view)[None]
    albedo_px = np.broadcast_to(np.asarray(albedo, np.uint8), n.shape).copy()
    out = radiance(albedo_px, n, v, light(fixed, 1.0), NO_AMBIENT, roughness=roughness, metallic=metallic)
    # E = 1 per light, radiance = f·cos θ; dω = dμ dφ: the grid's cell is (1/n_theta)(2π/n_phi)
    return out[0].sum(axis=0) * (1.0 / n_theta) * (2.0 * math.pi / n_phi)


@pytest.mark.parametrize("roughness", [0.3, 0.5, 0.75])
@pytest.mark.parametrize("view_theta", [0.0, 45.0, 75.0])
def test_the_specular_lobe_holds_the_energy_of_three_js_dfg_table(roughness, view_theta):
    """The specular lobe's directional albedo is the split sum F0·scale + bias of three.js's table
    (it integrates the same GGX and Smith, with the textbook Schlick), times the multi-scattering
    compensation: for F0 = 1 (white metal; within 3.5%, the grid's error on the sharpest lobe) and
    for the dielectric's 0.04 (black albedo, within 6%: there the Fresnel fits differ most in
    relative terms).  A white dielectric's diffuse layer reflects no more than it receives (with
    its specular lobe on top it may: glTF's fresnel_mix weights diffuse by 1 - F(V·H), not by what
    the lobe took, 1.15 at a grazing view and roughness 0.3; three.js follows glTF there).

    Not at roughness 1: the table's last texel centre is roughness 31/32 and a clamped lookup
    reads it there (as three.js's does), 10% more energy than roughness 1's own lobe."""
    view = toward(view_theta)
    scale, bias = dfg(roughness, view @ Z)
    metal = _reflected_fraction([255, 255, 255], roughness, view, metallic=1.0)
    assert metal[0] == pytest.approx(1.0, rel=0.035)  # the compensation's white furnace: E_ss / E_ss
    black = _reflected_fraction([0, 0, 0], roughness, view)
    expected = (0.04 * scale + bias) * (1.0 + 0.04 * (1.0 / (scale + bias) - 1.0))
    assert black[0] == pytest.approx(expected, rel=0.06)
    white = _reflected_fraction([255, 255, 255], roughness, view)
    assert 0.85 < white[0] - black[0] < 1.0


def test_fresnel_rises_to_one_toward_grazing():
    """F reaches F90 = 1 at V·H = 0; a smooth black dielectric's mirror highlight brightens from
    head-on to grazing."""
    f = f_schlick(0.04, 1.0, np.linspace(1.0, 0.0, 11))[:, 0]
    assert np.all(np.diff(f) > 0) and f[-1] == pytest.approx(1.0)
    black = np.zeros((1, 3, 3), np.uint8)
    angles = (0.0, 60.0, 85.0)
    n = pixels(Z, Z, Z)
    v = pixels(*[toward(a, 0.0) for a in angles])
    values = [
        radiance(black, n[:, i : i + 1], v[:, i : i + 1], light(toward(a, 180.0), 1.0), NO_AMBIENT, roughness=0.3)
        for i, a in enumerate(angles)
    ]
    per_cos = [float(x[0, 0, 0]) / math.cos(math.radians(a)) for x, a in zip(values, angles, strict=True)]
    assert per_cos[0] < per_cos[1] < per_cos[2]


def test_shading_is_invariant_under_a_rotation_of_everything():
    rng = np.random.default_rng(7)
    h, w = 8, 9
    n = rng.normal(size=(h, w, 3))
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    v = n + rng.normal(scale=0.7, size=(h, w, 3))
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    albedo = rng.integers(0, 256, size=(h, w, 3), dtype=np.uint8)
    rough = rng.uniform(0.0, 1.0, size=(h, w))
    metal = rng.uniform(0.0, 1.0, size=(h, w))
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.linalg.det(q))  # a proper rotation
    for lamp in default_lights():
        a = radiance(albedo, n, v, lamp, AMBIENT, rough, metal)
        turned = DirectionalLight(q @ lamp.direction, lamp.colour, lamp.intensity)
        b = radiance(albedo, n @ q.T, v @ q.T, turned, AMBIENT, rough, metal)
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12)
        # and each pixel is shaded on its own: a pixel moved elsewhere shades the same
        np.testing.assert_allclose(
            radiance(albedo[::-1], n[::-1], v[::-1], lamp, AMBIENT, rough[::-1], metal[::-1]), a[::-1], rtol=1e-12
        )


def test_default_lights_are_unit_and_lie_above_the_horizon():
    for up in ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0), (1.0, 2.0, -0.5)):
        u = np.asarray(up) / np.linalg.norm(up)
        lights = default_lights(up)
        elevations = [math.degrees(math.asin(float(lamp.direction @ u))) for lamp in lights]
        assert np.allclose([np.linalg.norm(lamp.direction) for lamp in lights], 1.0)
        np.testing.assert_allclose(elevations, [90.0, 35.0, 35.0, 35.0, 5.0], atol=1e-9)


def test_view_directions_point_back_along_each_pixels_ray():
    camera = Camera.look_at(np.array([1.0, -4.0, 2.0]), np.zeros(3), math.radians(50.0), 7, 0.1, 20.0)
    v = view_directions(camera)
    np.testing.assert_allclose(v[3, 3], -camera.forward, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(v, axis=-1), 1.0)
    for cam in (camera, camera.window(1.0, 4.0, 2.0, 5)):  # off-axis too
        d = view_directions(cam)
        points = cam.eye - 3.0 * d.reshape(-1, 3)
        ys, xs = np.mgrid[0 : cam.resolution, 0 : cam.resolution] + 0.5
        np.testing.assert_allclose(cam.project(points), np.stack([xs.ravel(), ys.ravel()], axis=1), atol=1e-9)


# ---- against three.js ---------------------------------------------------------------------------

RESOLUTION = 96
ALBEDO = (200, 120, 60)  # sRGB bytes of the sphere's colour (written as the linear factor they decode to)
SEGMENTS, RINGS = 256, 128  # 65 k triangles: the normals' interpolation error is ~1e-5 rad


def sphere_glb(path, roughness: float, metallic: float = 0.0, segments: int = SEGMENTS, rings: int = RINGS) -> None:
    """A unit UV sphere at the origin with smooth NORMALs (the positions themselves), counter-
    clockwise seen from outside, no seam (no texture coordinates), one single-sided material:
    ``baseColorFactor`` the linear value of :data:`ALBEDO`, ``roughnessFactor`` ``roughness``,
    ``metallicFactor`` ``metallic``.  Written by hand so the test depends on no exporter."""
    theta = np.arange(1, rings) / rings * math.pi  # ring latitudes from the +y pole, poles apart
    phi = np.arange(segments) / segments * 2.0 * math.pi
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ring_points = np.stack([np.sin(t) * np.sin(p), np.cos(t), np.sin(t) * np.cos(p)], axis=-1).reshape(-1, 3)
    positions = np.concatenate([[[0.0, 1.0, 0.0]], ring_points, [[0.0, -1.0, 0.0]]]).astype("<f4")
    normals = (positions / np.linalg.norm(positions, axis=1, keepdims=True)).astype("<f4")
    top, bottom = 0, len(positions) - 1

    def at(ring, seg):
        return 1 + ring * segments + seg % segments

    s = np.arange(segments)
    faces = [np.stack([np.full(segments, top), at(0, s), at(0, s + 1)], axis=1)]
    for r in range(rings - 2):
        a, b, c, d = at(r, s), at(r + 1, s), at(r + 1, s + 1), at(r, s + 1)
        faces += [np.stack([a, b, c], axis=1), np.stack([a, c, d], axis=1)]
    faces.append(np.stack([at(rings - 2, s), np.full(segments, bottom), at(rings - 2, s + 1)], axis=1))
    indices = np.concatenate(faces).astype("<u4").ravel()

    blob = positions.tobytes() + normals.tobytes() + indices.tobytes()
    n_pos, n_idx = len(positions), len(indices)
    factor = [float(x) for x in srgb_to_linear(np.array(ALBEDO) / 255.0)] + [1.0]
    gltf = {
        "asset": {"version": "2.0", "generator": "farfield tests/test_lighting.py"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1}, "indices": 2, "material": 0}]}],
        "materials": [
            {
                "pbrMetallicRoughness": {
                    "baseColorFactor": factor,
                    "metallicFactor": metallic,
                    "roughnessFactor": roughness,
                }
            }
        ],
        "buffers": [{"byteLength": len(blob)}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": n_pos * 12, "target": 34962},
            {"buffer": 0, "byteOffset": n_pos * 12, "byteLength": n_pos * 12, "target": 34962},
            {"buffer": 0, "byteOffset": n_pos * 24, "byteLength": n_idx * 4, "target": 34963},
        ],
        "accessors": [
            {
                "bufferView": 0,
                "componentType": 5126,
                "count": n_pos,
                "type": "VEC3",
                "min": positions.min(axis=0).tolist(),
                "max": positions.max(axis=0).tolist(),
            },
            {"bufferView": 1, "componentType": 5126, "count": n_pos, "type": "VEC3"},
            {"bufferView": 2, "componentType": 5125, "count": n_idx, "type": "SCALAR"},
        ],
    }
    text = json.dumps(gltf, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    blob += b"\0" * (-len(blob) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(blob), 0x004E4942) + blob
    path.write_bytes(struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body)


def sphere_gbuffer(camera: Camera):
    """(mask (h, w) bool, normal (h, w, 3), view (h, w, 3)) of the exact unit sphere at the origin
    seen by ``camera``: each pixel centre's ray meets it (nearest root) or not."""
    v = view_directions(camera)
    d = -v
    e = np.asarray(camera.eye, dtype=np.float64)
    b = d @ e
    disc = b * b - (e @ e - 1.0)
    mask = disc > 0.0
    t = -b - np.sqrt(np.where(mask, disc, 0.0))
    hit = e + t[..., None] * d
    normal = hit / np.linalg.norm(hit, axis=-1, keepdims=True)
    return mask, normal, v


def erode(mask: np.ndarray) -> np.ndarray:
    """(h, w) bool less its one-pixel rim (all eight neighbours must be set)."""
    padded = np.pad(mask, 1)
    h, w = mask.shape
    return np.logical_and.reduce(
        [padded[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w] for dy in (-1, 0, 1) for dx in (-1, 0, 1)]
    )


def sphere_camera() -> Camera:
    # about 80 pixels across, seen from above the horizon and off every light's azimuth
    eye = np.array([1.3, 1.1, 2.6])
    return Camera.look_at(eye, np.zeros(3), math.radians(45.0), RESOLUTION, 1.0, 6.0)


MATERIALS = ((1.0, 0.0), (0.5, 0.0), (0.5, 1.0))  # (roughness, metallic): rough and glossy dielectrics, a metal


@pytest.fixture(scope="module")
def sphere_files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("lit_sphere")
    files = {}
    for roughness, metallic in MATERIALS:
        files[roughness, metallic] = folder / f"sphere_r{roughness}_m{metallic}.glb"
        sphere_glb(files[roughness, metallic], roughness, metallic)
    return files


# Bounds on |three.js - farfield| in sRGB levels over the interior of the sphere, per channel:
# (mean, 99th percentile, |signed mean|) per (roughness, metallic).  Measured (SwiftShader, three.js
# 0.187.0, 4,556 pixels, every default light): roughness 1 dielectric mean <= 0.022, p99 <= 1;
# roughness 0.5 dielectric mean <= 0.051, p99 <= 1; roughness 0.5 metal mean <= 0.21, p99 <= 3,
# signed mean within 0.03 (no bias: the metal is all specular, so the emulated geometryRoughness,
# least exact near the rim where the normal turns fastest per pixel, shows most there).  The largest
# single differences, 7 to 16 levels, are a few highlight pixels next to the rim.  Without
# three.js's geometryRoughness the roughness 0.5 means are 0.2 to 0.6 (dielectric) and 3 to 4
# (metal), signed: the mean bounds sit between, so they catch a missing term as well as a wrong
# formula.
BOUNDS = {(1.0, 0.0): (0.1, 1.0, 0.05), (0.5, 0.0): (0.15, 2.0, 0.05), (0.5, 1.0): (0.4, 4.0, 0.1)}


@pytest.mark.parametrize(("roughness", "metallic"), MATERIALS)
def test_three_js_lights_a_sphere_as_shade_does(roughness, metallic, sphere_files, threejs):
    camera = sphere_camera()
    mask, normal, view = sphere_gbuffer(camera)
    albedo = np.broadcast_to(np.array(ALBEDO, np.uint8), normal.shape)
    extra = geometry_roughness(np.where(mask[..., None], normal, 0.0), camera)
    for index, lamp in enumerate(default_lights()):
        (theirs,) = threejs.render(sphere_files[roughness, metallic], camera, lights=[lamp], ambient=AMBIENT)
        ours = shade(albedo, normal, view, lamp, AMBIENT, roughness, metallic, geometry_roughness=extra)
        both = erode(mask) & erode(theirs[..., 3] > 0)
        assert both.sum() > 0.6 * mask.sum()
        signed = (theirs[..., :3].astype(np.int16) - ours.astype(np.int16))[both]
        diff = np.abs(signed)
        mean, p99, bias = diff.mean(axis=0), np.percentile(diff, 99, axis=0), signed.mean(axis=0)
        print(
            f"roughness {roughness} metallic {metallic} light {index}: mean {mean.round(3).tolist()} "
            f"p99 {p99.tolist()} signed {bias.round(3).tolist()} max {diff.max(axis=0).tolist()}"
        )
        mean_bound, p99_bound, bias_bound = BOUNDS[roughness, metallic]
        assert np.all(mean <= mean_bound) and np.all(p99 <= p99_bound), (index, mean, p99)
        assert np.all(np.abs(bias) <= bias_bound), (index, bias)


def test_three_js_draws_the_spheres_world_normals(sphere_files, threejs):
    camera = sphere_camera()
    mask, normal, _ = sphere_gbuffer(camera)
    (theirs,) = threejs.render(sphere_files[1.0, 0.0], camera, output="normal")
    from threejs import decode_normals

    both = erode(mask) & erode(theirs[..., 3] > 0)
    assert both.sum() > 0.6 * mask.sum()
    cos = np.clip(np.einsum("...i,...i->...", decode_normals(theirs), normal)[both], -1.0, 1.0)
    angle = np.degrees(np.arccos(cos))
    median, p95 = float(np.median(angle)), float(np.percentile(angle, 95))
    print(f"normal angle error: median {median:.3f} deg, p95 {p95:.3f} deg, max {angle.max():.3f} deg")
    # 8-bit components quantise a direction to about 0.2 degrees
    assert median < 0.3 and p95 < 0.5
