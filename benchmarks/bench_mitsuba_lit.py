"""Mitsuba 3 second opinion on the lit evaluation (issue 55): a physically based renderer draws what
:mod:`farfield.core.quality.lighting` shades.

Usage: ``.venv/bin/python benchmarks/bench_mitsuba_lit.py [--part sphere|scene|all] [--spp N]
[--resolution R] [--json]``.  Needs the optional extra ``reference`` (``pip install -e '.[reference]'``:
Mitsuba 3); without it the script says so in one line and exits 1.  Mitsuba runs in its
``scalar_rgb`` variant (CPU; the JIT variant ``llvm_ad_rgb`` needs a newer LLVM than the machine's
15), direct lighting only (``path`` with ``max_depth`` 2).

1. **The BRDF.**  A unit sphere (convex: nothing shadows it but itself, which N·L already does),
   lit by each :func:`~farfield.core.quality.lighting.default_lights` light of irradiance
   ``colour * intensity`` (Mitsuba's ``directional`` ``irradiance`` has three.js's meaning) and,
   standing for :data:`~farfield.core.quality.lighting.AMBIENT`, a ``constant`` environment of
   radiance ``AMBIENT / π`` (an unoccluded surface then receives the ambient irradiance), drawn by
   Mitsuba with ``principled`` (Disney), ``roughplastic`` (GGX over Lambert, ior 1.5: F0 0.04) and
   ``diffuse`` (Lambert), against :func:`~farfield.core.quality.lighting.radiance` of the sphere's
   analytic G-buffer (4 × 4 rays per pixel, averaged in linear light) from the same camera.  Errors
   in sRGB levels (0–255, the largest RGB difference) over the pixels the sphere covers whole; a
   second Mitsuba render with another seed gives the noise floor.
2. **A shared scene and one impostor.**  The duck baked as a layered impostor
   (``channels=albedo+normal``) for a cubic cell a fifth of its size three sizes in front of it
   along +z (as ``bench_lit.py``), drawn by Mitsuba three ways beside the source mesh: with its
   normals through Mitsuba's ``normalmap`` BSDF (each quad's page texels converted to the tangent
   frame Mitsuba builds on it, with :func:`farfield.core.impostor.glb.tangent_space_pages`), with
   its normals as per-texel shading normals (no tangent frame, no test against the quad's plane),
   and as flat cards.  Each opaque texel (alpha ≥ 128, glTF's cutoff 0.5) is a quad of its own, so
   the alpha cut is exact and shadow rays see what a camera sees.  From the reference viewpoint
   and a corner of the cell, under each light with the ambient (the environment rendered once per
   view with ``--ambient-spp`` samples and added to each light's render): Mitsuba's error of each
   impostor against the source next to farfield's lit evaluation
   (:func:`~farfield.core.quality.lit.evaluate_lit_at`) for the same view and light; Mitsuba's
   noise (the source rendered again with another seed); how much of the source and of the
   impostor Mitsuba shadows (pixels more than :data:`SHADOW_LEVELS` darker than farfield's
   unshadowed shading of the same G-buffer), and the errors over the pixels neither shadows.

Tables: ``docs/measurements/lit.md`` ("Mitsuba 3 second opinion").
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from farfield.core.colour_space import linear_to_srgb, srgb_to_linear  # noqa: E402
from farfield.core.impostor.glb import quad_frames, tangent_space_pages  # noqa: E402
from farfield.core.impostor.impostor import decode_normals  # noqa: E402
from farfield.core.quality.evaluation import downsample, viewpoints  # noqa: E402
from farfield.core.quality.lighting import AMBIENT, DirectionalLight, default_lights, radiance, shade, view_directions  # noqa: E402
from farfield.core.quality.lit import evaluate_lit_at, impostor_gbuffer  # noqa: E402
from farfield.core.render.raster import Camera, MeshRenderer, depth_bounds  # noqa: E402
from farfield.core.viewcells import BoxCell, box_corners, viewcell_from_dict  # noqa: E402

SCENES = Path(__file__).resolve().parents[2] / "shared" / "scenes"
LIGHT_NAMES = ("overhead", "35° az 0°", "35° az 120°", "35° az 240°", "5° az 60°")
# (roughness, metallic) of the sphere: glTF's default rough dielectric first (farfield's impostors)
MATERIALS = ((1.0, 0.0), (0.5, 0.0), (0.3, 0.0), (1.0, 1.0), (0.5, 1.0), (0.3, 1.0))
SPHERE_ALBEDO = (200, 140, 90)  # sRGB base colour of the sphere
SHADOW_LEVELS = 10  # a source pixel this much darker in Mitsuba than unshadowed shading is "in shadow"


def mitsuba():
    """The ``mitsuba`` module in its ``scalar_rgb`` variant, or exit with one line."""
    try:
        import mitsuba as mi
    except ImportError:
        raise SystemExit(
            "bench_mitsuba_lit: mitsuba is not installed (pip install -e '.[reference]'); nothing measured"
        ) from None
    mi.set_variant("scalar_rgb")
    return mi


# ---------------------------------------------------------------------------------------------
# Mitsuba scene pieces


def sensor(mi, camera: Camera, resolution: int, spp: int) -> dict:
    """A Mitsuba perspective sensor with ``camera``'s eye, orientation and field of view (its
    images are not mirrored: +x of the image is ``camera.right``), box-filtered pixels."""
    eye = np.asarray(camera.eye, dtype=np.float64)
    return {
        "type": "perspective",
        "fov": math.degrees(camera.fov),
        "fov_axis": "x",
        "near_clip": float(camera.near),
        "far_clip": float(camera.far),
        "to_world": mi.ScalarTransform4f().look_at(
            origin=eye.tolist(), target=(eye + camera.forward).tolist(), up=np.asarray(camera.up).tolist()
        ),
        "film": {
            "type": "hdrfilm",
            "width": resolution,
            "height": resolution,
            "rfilter": {"type": "box"},
            "pixel_format": "rgba",
        },
        "sampler": {"type": "independent", "sample_count": spp},
    }


def emitters(light, ambient) -> dict:
    """The directional light, unless None (Mitsuba's ``direction`` is where the light travels) and,
    unless ``ambient`` is None, a constant environment giving that irradiance to an open surface."""
    out = {}
    if light is not None:
        out["sun"] = {
            "type": "directional",
            "direction": (-np.asarray(light.direction, dtype=np.float64)).tolist(),
            "irradiance": {"type": "rgb", "value": (np.asarray(light.colour) * float(light.intensity)).tolist()},
        }
    if ambient is not None:
        out["sky"] = {
            "type": "constant",
            "radiance": {"type": "rgb", "value": (np.asarray(ambient) / math.pi).tolist()},
        }
    return out


def render(mi, shapes: dict, camera: Camera, resolution: int, spp: int, light, ambient, seed: int = 0) -> np.ndarray:
    """(h, w, 4) float32 linear RGB and alpha of ``shapes`` lit by ``light`` (and ``ambient``),
    direct lighting only."""
    scene = mi.load_dict(
        {
            "type": "scene",
            "integrator": {"type": "path", "max_depth": 2},
            "sensor": sensor(mi, camera, resolution, spp),
            **emitters(light, ambient),
            **shapes,
        }
    )
    return np.array(mi.render(scene, spp=spp, seed=seed), dtype=np.float32)


def coverage(mi, shapes: dict, camera: Camera, resolution: int, spp: int = 16) -> np.ndarray:
    """(h, w) float share of each pixel the shapes cover (the environment makes every pixel's
    alpha 1, so this is a render without it: one directional light, whose own alpha is 0)."""
    scene = mi.load_dict(
        {
            "type": "scene",
            "integrator": {"type": "path", "max_depth": 2},
            "sensor": sensor(mi, camera, resolution, spp),
            **emitters(default_lights()[0], None),
            **shapes,
        }
    )
    return np.array(mi.render(scene, spp=spp), dtype=np.float32)[..., 3]


def srgb8(linear: np.ndarray) -> np.ndarray:
    """(..., 3) uint8 sRGB of linear RGB clamped to 0..1 (as :func:`~farfield.core.quality.lighting.shade`)."""
    return np.round(linear_to_srgb(np.clip(linear, 0.0, 1.0)) * 255.0).astype(np.uint8)


def rgb_texture(mi, rgb_linear: np.ndarray, wrap: str = "repeat") -> dict:
    return {
        "type": "bitmap",
        "bitmap": mi.Bitmap(np.ascontiguousarray(rgb_linear, dtype=np.float32)),
        "raw": True,
        "filter_type": "bilinear",
        "wrap_mode": wrap,
    }


def mesh(mi, name: str, positions, faces, uv=None, normals=None, bsdf: dict | None = None):
    """A Mitsuba triangle mesh; ``uv`` in Mitsuba's (and glTF's) convention, (0, 0) the image's top
    left; without ``normals`` each triangle is flat, its normal ``(p1 - p0) × (p2 - p0)``."""
    props = mi.Properties()
    if bsdf is not None:
        props["bsdf"] = mi.load_dict(bsdf)
    out = mi.Mesh(
        name,
        len(positions),
        len(faces),
        has_vertex_normals=normals is not None,
        has_vertex_texcoords=uv is not None,
        props=props,
    )
    params = mi.traverse(out)

    def put(key, array, dtype):
        params[key] = type(params[key])(np.ascontiguousarray(array, dtype=dtype).ravel())

    put("vertex_positions", positions, np.float32)
    put("faces", faces, np.uint32)
    if uv is not None:
        put("vertex_texcoords", uv, np.float32)
    if normals is not None:
        put("vertex_normals", normals, np.float32)
    params.update()
    return out


def error_stats(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> dict:
    """Mean, 95th and 99th percentile of the largest RGB difference of two uint8 images where
    ``mask``, and the mean signed difference ``b - a`` over RGB (``bias``)."""
    signed = b[..., :3].astype(np.int16) - a[..., :3].astype(np.int16)
    d = np.abs(signed).max(axis=-1)[mask]
    if d.size == 0:
        return {"mean": 0.0, "p95": 0.0, "p99": 0.0, "bias": 0.0, "pixels": 0}
    return {
        "mean": float(d.mean()),
        "bias": float(signed[mask].mean()),  # b less a, over RGB
        "p95": float(np.percentile(d, 95)),
        "p99": float(np.percentile(d, 99)),
        "pixels": int(d.size),
    }


# ---------------------------------------------------------------------------------------------
# 1. the BRDF on a sphere


def principled(rough: float, metal: float, colour) -> dict:
    return {"type": "principled", "base_color": {"type": "rgb", "value": list(colour)}, "roughness": rough,
            "metallic": metal}  # fmt: skip


def sphere_bsdfs(rough: float, metal: float, colour) -> dict:
    """The Mitsuba BSDFs compared for glTF's (roughness, metallic): ``principled`` always; for a
    dielectric ``roughplastic`` (GGX, alpha = roughness², ior 1.5) and, at roughness 1, ``diffuse``."""
    out = {"principled": principled(rough, metal, colour)}
    if metal == 0.0:
        out["roughplastic"] = {
            "type": "roughplastic",
            "distribution": "ggx",
            "alpha": max(rough * rough, 1e-3),
            "int_ior": 1.5,
            "diffuse_reflectance": {"type": "rgb", "value": list(colour)},
        }
        if rough == 1.0:
            out["diffuse"] = {"type": "diffuse", "reflectance": {"type": "rgb", "value": list(colour)}}
    return out


def sphere_gbuffer(camera: Camera, supersample: int):
    """The unit sphere at the origin seen by ``camera`` at ``supersample`` rays per pixel side:
    (h, w) bool hit, (h, w, 3) unit normals, (h, w, 3) view directions (toward the eye)."""
    fine = Camera(camera.eye, camera.right, camera.up, camera.forward, camera.fov,
                  camera.resolution * supersample, camera.near, camera.far)  # fmt: skip
    view = view_directions(fine)
    d = -view
    e = np.asarray(camera.eye, dtype=np.float64)
    b = d @ e
    disc = b * b - (e @ e - 1.0)
    hit = disc > 0.0
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    normal = e + t[..., None] * d
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    return hit, normal, view


def block_mean(values: np.ndarray, s: int) -> np.ndarray:
    h, w = values.shape[0] // s, values.shape[1] // s
    return values.reshape(h, s, w, s, *values.shape[2:]).mean(axis=(1, 3))


def _summary(per_light: list[dict]) -> dict:
    means = [r["mean"] for r in per_light]
    return {
        "lights": per_light,
        "mean": float(np.mean(means)),
        "p95": float(np.max([r["p95"] for r in per_light])),
        "bias": float(np.mean([r["bias"] for r in per_light])),
        "worst_mean": float(np.max(means)),
        "worst_light": LIGHT_NAMES[int(np.argmax(means))] if len(per_light) > 1 else "-",
    }


def run_sphere(mi, resolution: int, spp: int, ambient_spp: int) -> list[dict]:
    """Per (roughness, metallic) and Mitsuba BSDF, three lightings: each light alone ("direct"),
    the ambient alone (the constant environment; farfield's ambient term) and both.  Radiance is
    linear in the emitters, so Mitsuba's "both" is its direct render plus its ambient render (the
    environment drawn once, with ``ambient_spp`` samples, the light's with ``spp``)."""
    supersample = 4
    camera = Camera.look_at(np.array([0.0, 0.0, 4.0]), np.zeros(3), math.radians(35.0), resolution, 1.0, 10.0)
    hit, normal, view = sphere_gbuffer(camera, supersample)
    whole = block_mean(hit.astype(np.float64), supersample) == 1.0
    # drop the outermost ring too: a Mitsuba pixel there may see the background through its filter
    whole[1:-1, 1:-1] &= whole[:-2, 1:-1] & whole[2:, 1:-1] & whole[1:-1, :-2] & whole[1:-1, 2:]
    albedo = np.broadcast_to(np.asarray(SPHERE_ALBEDO, np.uint8), hit.shape + (3,))
    colour = srgb_to_linear(np.asarray(SPHERE_ALBEDO, dtype=np.float64) / 255.0).tolist()
    lights = default_lights()
    dark = DirectionalLight(lights[0].direction, np.zeros(3), 0.0)
    rows = []
    for rough, metal in MATERIALS:
        for name, bsdf in sphere_bsdfs(rough, metal, colour).items():
            shapes = {"ball": {"type": "sphere", "center": [0.0, 0.0, 0.0], "radius": 1.0, "bsdf": bsdf}}

            def ours(light, ambient):
                return srgb8(block_mean(radiance(albedo, normal, view, light, ambient, rough, metal), supersample))

            sky = [
                render(mi, shapes, camera, resolution, ambient_spp, None, AMBIENT, seed=seed)[..., :3]
                for seed in (0, 1)
            ]
            suns = [render(mi, shapes, camera, resolution, spp, light, None)[..., :3] for light in lights]
            sun_again = render(mi, shapes, camera, resolution, spp, lights[0], None, seed=1)[..., :3]
            row = {"roughness": rough, "metallic": metal, "bsdf": name}
            row["direct"] = _summary(
                [error_stats(ours(light, np.zeros(3)), srgb8(sun), whole) for light, sun in zip(lights, suns)]
            )
            row["direct"]["noise"] = error_stats(srgb8(sun_again), srgb8(suns[0]), whole)["mean"]
            row["ambient"] = _summary([error_stats(ours(dark, AMBIENT), srgb8(sky[0]), whole)])
            row["ambient"]["noise"] = error_stats(srgb8(sky[1]), srgb8(sky[0]), whole)["mean"]
            row["both"] = _summary(
                [error_stats(ours(light, AMBIENT), srgb8(sun + sky[0]), whole) for light, sun in zip(lights, suns)]
            )
            row["both"]["noise"] = error_stats(srgb8(sun_again + sky[1]), srgb8(suns[0] + sky[0]), whole)["mean"]
            rows.append(row)
            print(
                f"  sphere r={rough} m={metal} {name:<12} "
                + "  ".join(
                    f"{k} {row[k]['mean']:5.2f}/{row[k]['p95']:4.0f} ({row[k]['bias']:+5.2f}, noise {row[k]['noise']:.2f})"
                    for k in ("direct", "ambient", "both")
                ),
                file=sys.stderr,
                flush=True,
            )
    return rows


# ---------------------------------------------------------------------------------------------
# 2. a shared scene and its impostor


def source_shapes(mi, scene) -> dict:
    """The scene's objects as Mitsuba meshes: base colour (texture × factor, linear; vertex colours
    left out) on ``principled`` roughness 1, metallic 0 (farfield's lit evaluation's material),
    two-sided; vertex normals where the file has them."""
    shapes = {}
    for i, obj in enumerate(scene.objects):
        factor = np.asarray(obj.base_color, dtype=np.float64)[:3]
        if obj.texture is not None and obj.uv is not None:
            texel = srgb_to_linear(obj.texture[..., :3].astype(np.float64) / 255.0) * factor
            base = rgb_texture(mi, texel)
            uv = np.stack([obj.uv[:, 0], 1.0 - obj.uv[:, 1]], axis=1)  # farfield's uv is bottom-left
        else:
            base, uv = {"type": "rgb", "value": factor.tolist()}, None
        bsdf = {"type": "twosided", "material": {"type": "principled", "base_color": base, "roughness": 1.0,
                                                 "metallic": 0.0}}  # fmt: skip
        shapes[f"source{i}"] = mesh(mi, f"source{i}", obj.vertices, obj.faces, uv, obj.normals, bsdf)
    return shapes


def texel_quads(impostor, page_index: int, frames: np.ndarray):
    """Every opaque texel (alpha >= 128) of page ``page_index`` as a quad of its own on its tile's
    quad: (n, 3) positions, (m, 3) triangles wound so that ``(p1 - p0) × (p2 - p0)`` is the quad's
    normal toward the reference viewpoint (``frames[:, 2]``), (n, 2) uv, (n, 3) the texel's world
    normal at each corner."""
    payload = impostor.payload
    page = impostor.pages[page_index]
    world = decode_normals(impostor.channels["normal"][page_index])
    h, w = page.shape[:2]
    positions, uvs, normals, triangles = [], [], [], []
    count = 0
    for q in np.flatnonzero(payload.page == page_index):
        c, t = payload.corners[q], payload.uv[q]
        e1, e2 = c[1] - c[0], c[3] - c[0]
        d1, d2 = t[1] - t[0], t[3] - t[0]
        det = d1[0] * d2[1] - d1[1] * d2[0]
        if det == 0.0:
            continue
        dpdu = (d2[1] * e1 - d1[1] * e2) / det
        dpdv = (d1[0] * e2 - d2[0] * e1) / det
        x0, x1 = int(np.floor(t[:, 0].min() * w + 0.5)), int(np.floor(t[:, 0].max() * w + 0.5))
        y0, y1 = int(np.floor(t[:, 1].min() * h + 0.5)), int(np.floor(t[:, 1].max() * h + 0.5))
        ys, xs = np.nonzero(page[max(y0, 0) : y1, max(x0, 0) : x1, 3] >= 128)
        if ys.size == 0:
            continue
        ys, xs = ys + max(y0, 0), xs + max(x0, 0)
        corner_uv = np.stack(
            [
                np.stack([xs, ys], -1),
                np.stack([xs + 1, ys], -1),
                np.stack([xs + 1, ys + 1], -1),
                np.stack([xs, ys + 1], -1),
            ],
            axis=1,
        ) / np.array([w, h], dtype=np.float64)  # (n, 4, 2) TL, TR, BR, BL of each texel
        p = c[0] + (corner_uv[..., 0:1] - t[0, 0]) * dpdu + (corner_uv[..., 1:2] - t[0, 1]) * dpdv
        base = count + 4 * np.arange(ys.size)[:, None]
        tri = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]], axis=0)
        first = p[0]
        if np.dot(np.cross(first[1] - first[0], first[2] - first[0]), frames[q, 2]) < 0.0:
            tri = tri[:, [0, 2, 1]]
        positions.append(p.reshape(-1, 3))
        uvs.append(corner_uv.reshape(-1, 2))
        normals.append(np.repeat(world[ys, xs], 4, axis=0))
        triangles.append(tri)
        count += 4 * ys.size
    if not positions:
        return None
    return np.concatenate(positions), np.concatenate(triangles), np.concatenate(uvs), np.concatenate(normals)


def mitsuba_frames(impostor) -> np.ndarray:
    """(q, 3, 3) rows s, t, n of the shading frame Mitsuba builds on each quad's texel triangles
    (``SurfaceInteraction::initialize_sh_frame``: s along dP/du, t = n × s, n the triangle's
    normal, here toward the reference viewpoint): the frame its ``normalmap`` reads a texel in."""
    frames = quad_frames(impostor.payload, np.asarray(impostor.reference_viewpoint, dtype=np.float64))
    s, n = frames[:, 0], frames[:, 2]
    return np.stack([s, np.cross(n, s), n], axis=1)


def impostor_shapes(mi, impostor, version: str, frames: np.ndarray | None = None) -> dict:
    """The impostor's opaque texels as Mitsuba meshes, one per page: ``normalmap`` (its normal page
    in Mitsuba's tangent frames, or in ``frames`` (q, 3, 3) if given), ``shading`` (per-texel world
    normals as vertex normals) or ``flat``."""
    frames = mitsuba_frames(impostor) if frames is None else frames
    tangent = (
        tangent_space_pages(impostor.payload, frames, impostor.channels["normal"]) if version == "normalmap" else None
    )
    shapes = {}
    for index, page in enumerate(impostor.pages):
        quads = texel_quads(impostor, index, frames)
        if quads is None:
            continue
        positions, triangles, uv, normals = quads
        base = rgb_texture(mi, srgb_to_linear(page[..., :3].astype(np.float64) / 255.0), wrap="clamp")
        bsdf = {"type": "principled", "base_color": base, "roughness": 1.0, "metallic": 0.0}
        if version == "normalmap":
            encoded = tangent[index][..., :3].astype(np.float32) / 255.0
            bsdf = {"type": "normalmap", "normalmap": rgb_texture(mi, encoded, wrap="clamp"), "bsdf": bsdf}
        shapes[f"page{index}"] = mesh(
            mi, f"page{index}", positions, triangles, uv, normals if version == "shading" else None, bsdf
        )
    return shapes


def run_scene(mi, resolution: int, spp: int, ambient_spp: int) -> dict:
    from farfield.core.exchange import load_scene
    from farfield.core.techniques.layered import BakeOptions, bake_layered

    path = SCENES / "duck" / "duck.obj"
    scene = load_scene(path)
    lo, hi = scene.bounds
    size = float(np.max(hi - lo))
    centre = 0.5 * (lo + hi)
    cell = BoxCell.from_center(centre + np.array([0.0, 0.0, 3.0 * size]), 0.2 * size)
    impostor = bake_layered(scene, cell, BakeOptions(resolution=resolution, channels="albedo+normal"))
    points, kinds = viewpoints(viewcell_from_dict(impostor.viewcell), impostor.reference_viewpoint, 0, 0, 0)
    chosen = [kinds.index("reference"), kinds.index("corner")]
    points, kinds = points[chosen], [kinds[i] for i in chosen]
    lights = default_lights()
    samples = 2
    start = time.perf_counter()
    ours = evaluate_lit_at(scene, impostor, points, kinds, samples=samples, lights=lights)
    ours_s = time.perf_counter() - start

    shapes = {
        "source": source_shapes(mi, scene),
        "normalmap": impostor_shapes(mi, impostor, "normalmap"),
        "shading": impostor_shapes(mi, impostor, "shading"),
        "flat": impostor_shapes(mi, impostor, "flat"),
    }
    texels = int(sum(m.face_count() // 2 for m in shapes["flat"].values()))
    target = 0.5 * (scene.bounds[0] + scene.bounds[1])
    extent = np.concatenate([box_corners(scene.bounds), impostor.payload.world_points()])
    fov = math.radians(impostor.fov_deg)
    views = []
    mitsuba_s = 0.0
    with MeshRenderer(scene.objects, normals=True) as geometry, impostor_gbuffer(impostor) as stand_in:
        for v, (position, kind) in enumerate(zip(points, kinds)):
            forward = (target - position) / np.linalg.norm(target - position)
            near, far = depth_bounds(position, forward, extent)
            camera = Camera.look_at(position, target, fov, resolution, near, far)
            fine = Camera.look_at(position, target, fov, resolution * samples, near, far)
            image, normal = geometry.render_normals(fine)
            image_i, normal_i = stand_in.render_normals(fine)
            covered = {name: coverage(mi, s, camera, resolution) for name, s in shapes.items()}
            # the environment once per view, with more samples (radiance is linear in the emitters)
            start = time.perf_counter()
            sky = {name: render(mi, s, camera, resolution, ambient_spp, None, AMBIENT) for name, s in shapes.items()}
            sky_again = render(mi, shapes["source"], camera, resolution, ambient_spp, None, AMBIENT, seed=1)
            mitsuba_s += time.perf_counter() - start
            rows = []
            for k, light in enumerate(lights):
                start = time.perf_counter()
                drawn = {
                    name: render(mi, s, camera, resolution, spp, light, None) + sky[name] for name, s in shapes.items()
                }
                again = render(mi, shapes["source"], camera, resolution, spp, light, None, seed=1) + sky_again
                mitsuba_s += time.perf_counter() - start
                srgb = {name: srgb8(img[..., :3]) for name, img in drawn.items()}
                src = covered["source"] > 0.99
                row = {"light": LIGHT_NAMES[k]}
                row["mitsuba_noise"] = error_stats(srgb["source"], srgb8(again[..., :3]), src)
                for name in ("normalmap", "shading", "flat"):
                    row[f"mitsuba_{name}"] = error_stats(srgb["source"], srgb[name], src & (covered[name] > 0.99))
                stats = ours.viewpoints[v]["stats"]["lights"][k]
                row["farfield_lit"] = stats["lit_error_mean"]
                row["farfield_flat"] = stats["flat_error_mean"]
                row["farfield_unlit"] = stats["unlit_error_mean"]
                # Mitsuba's shadows: pixels more than SHADOW_LEVELS darker than farfield's unshadowed
                # shading of the same G-buffer (the source's; the impostor's, against its per-texel
                # normals in Mitsuba)
                view = view_directions(fine)
                lit = downsample(
                    np.concatenate([shade(image[..., :3], normal, view, light, AMBIENT), image[..., 3:]], -1), samples
                )
                lit_i = downsample(
                    np.concatenate([shade(image_i[..., :3], normal_i, view, light, AMBIENT), image_i[..., 3:]], -1),
                    samples,
                )
                mask = src & (lit[..., 3] > 0)
                darker = lit[..., :3].astype(np.int16).max(-1) - srgb["source"].astype(np.int16).max(-1)
                shadowed = darker > SHADOW_LEVELS
                row["shadowed_share"] = float(shadowed[mask].mean()) if mask.any() else 0.0
                row["source_vs_farfield"] = error_stats(lit, srgb["source"], mask)
                row["source_vs_farfield_unshadowed"] = error_stats(lit, srgb["source"], mask & ~shadowed)
                mask_i = (covered["shading"] > 0.99) & (lit_i[..., 3] > 0)
                darker_i = lit_i[..., :3].astype(np.int16).max(-1) - srgb["shading"].astype(np.int16).max(-1)
                row["impostor_shadowed_share"] = (
                    float((darker_i[mask_i] > SHADOW_LEVELS).mean()) if mask_i.any() else 0.0
                )
                both = src & (covered["shading"] > 0.99)
                clear = both & ~shadowed & ~(darker_i > SHADOW_LEVELS)
                row["mitsuba_shading_unshadowed"] = error_stats(srgb["source"], srgb["shading"], clear)
                row["mitsuba_flat_unshadowed"] = error_stats(
                    srgb["source"], srgb["flat"], clear & (covered["flat"] > 0.99)
                )
                rows.append(row)
                print(
                    f"  {kind:<9} {LIGHT_NAMES[k]:<12} mitsuba normalmap {row['mitsuba_normalmap']['mean']:5.2f} "
                    f"shading {row['mitsuba_shading']['mean']:5.2f} flat {row['mitsuba_flat']['mean']:5.2f} | "
                    f"farfield lit {row['farfield_lit']:5.2f} flat {row['farfield_flat']:5.2f} | noise {row['mitsuba_noise']['mean']:4.2f} "
                    f"shadowed {100 * row['shadowed_share']:4.1f}% impostor {100 * row['impostor_shadowed_share']:4.1f}% "
                    f"unshadowed shading {row['mitsuba_shading_unshadowed']['mean']:5.2f}",
                    file=sys.stderr,
                    flush=True,
                )
            views.append({"kind": kind, "position": np.asarray(position).tolist(), "lights": rows})
    return {
        "scene": "duck",
        "triangles": scene.triangle_count,
        "resolution": resolution,
        "spp": spp,
        "ambient_spp": ambient_spp,
        "quads": impostor.payload.count,
        "opaque_texels": texels,
        "views": views,
        "farfield_seconds": ours_s,
        "mitsuba_seconds": mitsuba_s,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", choices=("sphere", "scene", "all"), default="all")
    parser.add_argument("--resolution", type=int, default=128, help="the impostor's and the scene renders' pixels")
    parser.add_argument("--spp", type=int, default=64, help="samples per pixel (the sphere's light, the scene)")
    parser.add_argument("--ambient-spp", type=int, default=1024, help="samples per pixel of the environment")
    parser.add_argument("--sphere-resolution", type=int, default=64)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    mi = mitsuba()
    out = {"mitsuba": mi.__version__, "variant": mi.variant()}
    start = time.perf_counter()
    if args.part in ("sphere", "all"):
        out["sphere"] = run_sphere(mi, args.sphere_resolution, args.spp, args.ambient_spp)
    if args.part in ("scene", "all"):
        out["scene"] = run_scene(mi, args.resolution, args.spp, args.ambient_spp)
    out["seconds"] = time.perf_counter() - start
    if args.json:
        print(json.dumps(out, indent=1))
        return
    print(f"mitsuba {out['mitsuba']} ({out['variant']}), {out['seconds']:.0f} s")
    for r in out.get("sphere", []):
        print(
            f"sphere roughness {r['roughness']} metallic {r['metallic']} {r['bsdf']:<12} "
            + "  ".join(
                f"{k}: mean {r[k]['mean']:5.2f} p95 {r[k]['p95']:4.0f} bias {r[k]['bias']:+5.2f} noise {r[k]['noise']:.2f}"
                for k in ("direct", "ambient", "both")
            )
        )
    if "scene" in out:
        s = out["scene"]
        print(
            f"{s['scene']}: {s['quads']} quads, {s['opaque_texels']} opaque texels, {s['resolution']} px, {s['spp']} spp"
        )
        for view in s["views"]:
            for r in view["lights"]:
                print(
                    f"{view['kind']:<9} {r['light']:<12} mitsuba: normalmap {r['mitsuba_normalmap']['mean']:5.2f} "
                    f"shading {r['mitsuba_shading']['mean']:5.2f} flat {r['mitsuba_flat']['mean']:5.2f}  "
                    f"farfield: lit {r['farfield_lit']:5.2f} flat {r['farfield_flat']:5.2f} unlit {r['farfield_unlit']:5.2f}  "
                    f"noise {r['mitsuba_noise']['mean']:4.2f}  shadowed {100 * r['shadowed_share']:4.1f}%  "
                    f"mitsuba-vs-farfield source {r['source_vs_farfield']['mean']:5.2f}"
                )


if __name__ == "__main__":
    main()
