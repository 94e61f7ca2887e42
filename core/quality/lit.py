"""The lit evaluation: the impostor against the real geometry under the same lights, as an engine
would light both.

From the evaluation's viewpoints (:func:`farfield.core.quality.evaluation.viewpoints`) the part's
geometry and the impostor are drawn as G-buffers (:meth:`MeshRenderer.render_normals
<farfield.core.render.raster.MeshRenderer.render_normals>`: the sRGB base colour and the world
shading normal of every sample) and each is shaded, sample by sample, under each test light
(:func:`farfield.core.quality.lighting.default_lights`, with the ambient term) by the same BRDF
(:func:`farfield.core.quality.lighting.shade`: glTF's metallic-roughness BRDF as three.js draws it).
A part with a material (:func:`~farfield.core.scene.has_material`: glTF's metallic and roughness
factors and textures, occlusion, emission) is drawn with its material G-buffer
(:meth:`MeshRenderer.render_material <farfield.core.render.raster.MeshRenderer.render_material>`)
and shaded with it; an impostor is shaded with its own material channels where its G-buffer
renderer draws them (one made with ``materials=True``: a payload's ``gbuffer`` of an impostor
that keeps its material channel), else as a rough dielectric (roughness 1, metallic 0, no
occlusion or emission, the matte default), and ``impostor_material`` says which ("kept",
"matte"; ``source_material`` whether the part has one).  The shaded samples are resolved into pixels as the unlit evaluation's
(:func:`~farfield.core.quality.evaluation.downsample`).

The impostor is drawn three ways: with its normal channel (what an engine lights, where it has
one), as flat cards (each quad or triangle lit by its own geometric normal, facing the viewer: what
an engine does with an impostor that has no normals) and unlit.  Per light and viewpoint:

``lit_error_mean``, ``lit_error_p99``, ``lit_ssim``
    the lit impostor against the lit geometry where both cover: the largest difference over RGB
    (0..255), its mean and 99th percentile, and SSIM over both coverages (as the unlit figures,
    :mod:`farfield.core.quality.evaluation`);
``flat_error_mean``, ``flat_error_p99``
    the same for the impostor lit as flat cards;
``unlit_error_mean``, ``unlit_error_p99``
    the unlit colour error of the same pixels (the light changes nothing there; repeated so that
    the ratios below are taken over the same pixels).

Per viewpoint, over the samples both cover: ``normal_error_median`` and ``normal_error_p95``
(degrees between the impostor's normal and the geometry's), the same over ``interior`` samples
(whose 3 x 3 neighbourhood both cover: silhouettes left out) and over ``smooth`` samples, on
surfaces larger than a pixel (interior samples whose geometry normals within one output pixel
turn by less than :data:`SMOOTH_DEGREES`: no edge, crease or sub-pixel detail; ``smooth_share`` of
the samples both cover), and ``flat_normal_error_median`` for the flat cards.  Where the part has a
material, per viewpoint over the samples both cover: ``occlusion_error_mean``,
``roughness_error_mean``, ``metallic_error_mean`` (mean absolute differences of the channels,
0..1) and ``emissive_error_mean`` (of linear emission, the largest over RGB), the impostor's
material against the part's (the matte default's values where the impostor keeps none).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from farfield.core.impostor.impostor import Impostor
from farfield.core.quality.evaluation import downsample, ssim_over_union, viewpoints
from farfield.core.quality.lighting import AMBIENT, DirectionalLight, default_lights, shade, view_directions
from farfield.core.render.raster import Camera, MeshRenderer, depth_bounds
from farfield.core.scene import Scene, has_material
from farfield.core.viewcells import box_corners, viewcell_from_dict

# The figures per light, pooled over viewpoints in the totals (means weighted by pixels both cover).
LIGHT_FIGURES = ("lit_error_mean", "lit_error_p99", "lit_ssim", "flat_error_mean", "flat_error_p99", "unlit_error_mean",
                 "unlit_error_p99")  # fmt: skip


@dataclass
class LitEvaluation:
    """Per viewpoint and light the figures of the module docstring; ``totals`` over the viewpoints
    inside the cell (per light, and the normal errors)."""

    viewpoints: list[dict]
    totals: dict
    lights: list[dict] = field(default_factory=list)  # direction, intensity of each light
    seconds: float = 0.0

    def to_dict(self) -> dict:
        return {"viewpoints": self.viewpoints, "totals": self.totals, "lights": self.lights, "seconds": self.seconds}


def impostor_gbuffer(impostor: Impostor, normals: bool = True) -> MeshRenderer:
    """The G-buffer renderer of ``impostor``: its payload's (:meth:`~farfield.core.impostor.impostor.Payload.gbuffer`),
    with its normal channel when ``normals`` and it keeps one, else lit as flat cards."""
    return impostor.payload.gbuffer(impostor, normals)


# The channels of a material G-buffer (MeshRenderer.render_material) a viewpoint reports errors of.
MATERIAL_FIGURES = ("occlusion_error_mean", "roughness_error_mean", "metallic_error_mean", "emissive_error_mean")
# The material of a pixel drawn without one: no occlusion, roughness 1, metallic 0, no emission.
MATTE = np.array([1.0, 1.0, 0.0, 0.0, 0.0, 0.0], dtype=np.float32)


def gbuffer_of(renderer, camera: Camera) -> tuple:
    """(image, normals, material or None) of ``renderer`` from ``camera``: its material G-buffer
    (:meth:`MeshRenderer.render_material`) where it was made with materials, else its
    ``render_normals`` and None."""
    if getattr(renderer, "materials", False):
        return renderer.render_material(camera)
    return (*renderer.render_normals(camera), None)


def _shading(material: np.ndarray | None) -> dict:
    """The material arguments of :func:`~farfield.core.quality.lighting.shade` of an (h, w, 6)
    material G-buffer (none: the matte default, shade's own defaults)."""
    if material is None:
        return {}
    return {
        "occlusion": material[..., 0],
        "roughness": material[..., 1],
        "metallic": material[..., 2],
        "emissive": material[..., 3:6],
    }


def _material_errors(geometry: np.ndarray, impostor: np.ndarray | None, both: np.ndarray) -> dict:
    """:data:`MATERIAL_FIGURES` over the samples ``both`` cover (the matte default's values where the
    impostor has no material)."""
    g = geometry[both].astype(np.float64)
    i = np.broadcast_to(MATTE, g.shape) if impostor is None else impostor[both].astype(np.float64)
    if not g.size:
        return dict.fromkeys(MATERIAL_FIGURES, None)
    diff = np.abs(g - i)
    return {
        "occlusion_error_mean": float(diff[:, 0].mean()),
        "roughness_error_mean": float(diff[:, 1].mean()),
        "metallic_error_mean": float(diff[:, 2].mean()),
        "emissive_error_mean": float(diff[:, 3:6].max(axis=1).mean()),
    }


def _errors(geometry: np.ndarray, impostor: np.ndarray, both: np.ndarray) -> np.ndarray:
    """The largest absolute difference over RGB of two (h, w, 4) uint8 images where ``both``."""
    return np.abs(geometry[..., :3].astype(np.int16) - impostor[..., :3].astype(np.int16)).max(axis=-1)[both]


def _rgba(rgb: np.ndarray, covered: np.ndarray) -> np.ndarray:
    return np.concatenate([rgb, np.where(covered, 255, 0).astype(np.uint8)[..., None]], axis=-1)


def _angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.einsum("...i,...i->...", a, b), -1.0, 1.0)))


def _interior(mask: np.ndarray) -> np.ndarray:
    """Samples of ``mask`` whose 3 x 3 neighbourhood lies in it."""
    out = mask.copy()
    out[1:] &= mask[:-1]
    out[:-1] &= mask[1:]
    inner = out.copy()
    inner[:, 1:] &= out[:, :-1]
    inner[:, :-1] &= out[:, 1:]
    return inner


# A sample lies on a surface larger than an output pixel where the geometry's normals within one
# pixel around it turn by less than this (degrees): no edge, crease or sub-pixel detail there.
SMOOTH_DEGREES = 10.0


def _smooth(normals: np.ndarray, covered: np.ndarray, samples: int) -> np.ndarray:
    """(h, w) bool: covered samples whose geometry normals within ``samples`` samples (one output
    pixel) each way, all covered, turn by less than :data:`SMOOTH_DEGREES` from theirs."""
    cosine = math.cos(math.radians(SMOOTH_DEGREES))
    out = covered.copy()
    h, w = covered.shape
    for dy in (-samples, 0, samples):
        for dx in (-samples, 0, samples):
            if dy == 0 and dx == 0:
                continue
            ys, yd = slice(max(dy, 0), h + min(dy, 0)), slice(max(-dy, 0), h + min(-dy, 0))
            xs, xd = slice(max(dx, 0), w + min(dx, 0)), slice(max(-dx, 0), w + min(-dx, 0))
            near = np.zeros_like(covered)
            near[yd, xd] = covered[ys, xs] & (np.einsum("ijk,ijk->ij", normals[ys, xs], normals[yd, xd]) > cosine)
            out &= near
    return out


def _percentiles(values: np.ndarray) -> tuple[float, float]:
    """(median, 95th percentile) of ``values``; None for none (a viewpoint with no such sample),
    which the totals leave out."""
    return (float(np.median(values)), float(np.percentile(values, 95))) if values.size else (None, None)


def _mean_of(rows: list[dict], name: str) -> float:
    """The mean of a per-viewpoint figure over the viewpoints that measured it (0 when none did)."""
    values = [r[name] for r in rows if r[name] is not None]
    return float(np.mean(values)) if values else 0.0


def _max_of(rows: list[dict], name: str) -> float:
    values = [r[name] for r in rows if r[name] is not None]
    return max(values) if values else 0.0


def compare_lit(
    geometry: tuple[np.ndarray, np.ndarray],
    impostor: tuple[np.ndarray, np.ndarray],
    flat: tuple[np.ndarray, np.ndarray],
    camera: Camera,
    lights,
    ambient,
    samples: int,
) -> dict:
    """The figures of one viewpoint (module docstring) from the three G-buffers (image, normals[,
    material]) of the geometry, the impostor with its normals and the impostor as flat cards,
    drawn by ``camera`` at ``samples`` per pixel side; each is shaded with its material where it
    has one (:func:`gbuffer_of`), else as the matte default."""
    materials = {
        name: (buffer[2] if len(buffer) > 2 else None)
        for name, buffer in (("geometry", geometry), ("impostor", impostor), ("flat", flat))
    }
    view = view_directions(camera)
    covered_g, covered_i = geometry[0][..., 3] > 0, impostor[0][..., 3] > 0
    both_samples = covered_g & covered_i
    unlit_g, unlit_i = downsample(geometry[0], samples), downsample(impostor[0], samples)
    both = (unlit_g[..., 3] > 0) & (unlit_i[..., 3] > 0)
    unlit = _errors(unlit_g, unlit_i, both)
    rows = []
    for light in lights:
        lit = {}
        for name, (image, normal, *_) in (("geometry", geometry), ("impostor", impostor), ("flat", flat)):
            covered = image[..., 3] > 0
            shaded = shade(image[..., :3], normal, view, light, ambient, **_shading(materials[name]))
            lit[name] = downsample(_rgba(shaded, covered), samples)
        errors, flat_errors = (
            _errors(lit["geometry"], lit["impostor"], both),
            _errors(lit["geometry"], lit["flat"], both),
        )
        rows.append(
            {
                "lit_error_mean": float(errors.mean()) if errors.size else 0.0,
                "lit_error_p99": float(np.percentile(errors, 99)) if errors.size else 0.0,
                "lit_ssim": ssim_over_union(lit["geometry"], lit["impostor"]),
                "flat_error_mean": float(flat_errors.mean()) if flat_errors.size else 0.0,
                "flat_error_p99": float(np.percentile(flat_errors, 99)) if flat_errors.size else 0.0,
                "unlit_error_mean": float(unlit.mean()) if unlit.size else 0.0,
                "unlit_error_p99": float(np.percentile(unlit, 99)) if unlit.size else 0.0,
            }
        )
    angles = _angles(geometry[1][both_samples], impostor[1][both_samples])
    inner = _interior(covered_g) & _interior(covered_i)
    inner_angles = _angles(geometry[1][inner], impostor[1][inner])
    smooth = inner & _smooth(geometry[1], covered_g, samples)
    smooth_angles = _angles(geometry[1][smooth], impostor[1][smooth])
    flat_angles = _angles(geometry[1][both_samples], flat[1][both_samples])
    median, p95 = _percentiles(angles)
    inner_median, inner_p95 = _percentiles(inner_angles)
    smooth_median, smooth_p95 = _percentiles(smooth_angles)
    material = {}
    if materials["geometry"] is not None:
        material = {"impostor_material": "kept" if materials["impostor"] is not None else "matte"}
        material |= _material_errors(materials["geometry"], materials["impostor"], both_samples)
    return material | {
        "both_pixels": int(both.sum()),
        "lights": rows,
        "normal_error_median": median,
        "normal_error_p95": p95,
        "normal_error_interior_median": inner_median,
        "normal_error_interior_p95": inner_p95,
        "normal_error_smooth_median": smooth_median,
        "normal_error_smooth_p95": smooth_p95,
        "smooth_share": float(smooth.sum() / max(int(both_samples.sum()), 1)),
        "flat_normal_error_median": _percentiles(flat_angles)[0],
    }


def lit_totals(rows: list[dict], light_count: int) -> dict:
    """Per light, the figures pooled over ``rows`` (means weighted by the pixels both cover, p99
    the worst viewpoint's, SSIM averaged); the normal errors' worst viewpoint and their mean; and
    the ratios the issue's targets are stated in: the worst ``lit_to_unlit`` (lit error over
    unlit error, per light) and the smallest ``flat_to_lit`` (flat cards' lit error over the
    impostor's)."""
    if not rows:
        return {}
    both = sum(r["both_pixels"] for r in rows)
    lights = []
    for k in range(light_count):
        stats = [r["lights"][k] | {"both_pixels": r["both_pixels"]} for r in rows]
        pooled = {
            name: (sum(s[name] * s["both_pixels"] for s in stats) / both if both else 0.0)
            for name in ("lit_error_mean", "flat_error_mean", "unlit_error_mean")
        }
        lights.append(
            pooled
            | {name: max(s[name] for s in stats) for name in ("lit_error_p99", "flat_error_p99", "unlit_error_p99")}
            | {"lit_ssim": float(np.mean([s["lit_ssim"] for s in stats]))}
        )
    ratio = [
        light["lit_error_mean"] / max(light["unlit_error_mean"], 0.5) for light in lights
    ]  # an unlit error below half a level counts as half a level
    gain = [light["flat_error_mean"] / max(light["lit_error_mean"], 1e-9) for light in lights]
    return {
        "viewpoints": len(rows),
        "both_pixels": both,
        "lights": lights,
        "lit_to_unlit_worst": max(ratio),
        "flat_to_lit_least": min(gain),
        "normal_error_median": _mean_of(rows, "normal_error_median"),
        "normal_error_p95": _max_of(rows, "normal_error_p95"),
        "normal_error_interior_median": _mean_of(rows, "normal_error_interior_median"),
        "normal_error_interior_p95": _max_of(rows, "normal_error_interior_p95"),
        "normal_error_smooth_median": _mean_of(rows, "normal_error_smooth_median"),
        "normal_error_smooth_p95": _max_of(rows, "normal_error_smooth_p95"),
        "smooth_share": float(np.mean([r["smooth_share"] for r in rows])),
        "flat_normal_error_median": _mean_of(rows, "flat_normal_error_median"),
    } | _material_totals(rows)


def _material_totals(rows: list[dict]) -> dict:
    """``source_material`` (whether the part was shaded with its material), and where it was,
    ``impostor_material`` ("kept" where every viewpoint shaded the impostor with its own, else
    "matte") and the channel errors' means over the viewpoints."""
    if not any("impostor_material" in r for r in rows):
        return {"source_material": False}
    kept = all(r.get("impostor_material") == "kept" for r in rows)
    return {"source_material": True, "impostor_material": "kept" if kept else "matte"} | {
        name: _mean_of(rows, name) for name in MATERIAL_FIGURES
    }


def evaluate_lit_at(
    part: Scene,
    impostor: Impostor,
    points: np.ndarray,
    kinds: list[str],
    samples: int = 2,
    lights: tuple[DirectionalLight, ...] | None = None,
    ambient=AMBIENT,
) -> LitEvaluation:
    """The lit figures (module docstring) of ``impostor`` against ``part`` from ``points`` (n, 3)
    (of ``kinds``; "outside" ones are left out of the totals) at the impostor's resolution and
    field of view, towards the part's centre, ``samples`` per pixel side; ``lights`` default to
    :func:`~farfield.core.quality.lighting.default_lights` (+y up, glTF's)."""
    start = time.perf_counter()
    lights = default_lights() if lights is None else tuple(lights)
    target = 0.5 * (part.bounds[0] + part.bounds[1])
    extent = np.concatenate([box_corners(part.bounds), impostor.payload.world_points()])
    fov = math.radians(impostor.fov_deg)
    with (
        MeshRenderer(part.objects, normals=True, materials=any(has_material(o) for o in part.objects)) as geometry,
        impostor_gbuffer(impostor) as stand_in,
        impostor_gbuffer(impostor, normals=False) as cards,
    ):

        def views():
            for position, kind in zip(np.asarray(points, dtype=np.float64), kinds):
                forward = (target - position) / np.linalg.norm(target - position)
                near, far = depth_bounds(position, forward, extent)
                camera = Camera.look_at(position, target, fov, impostor.resolution * samples, near, far)
                yield camera, {"position": position.tolist(), "kind": kind}

        result = evaluate_lit_views(geometry, stand_in, cards, views(), samples, lights, ambient)
    result.seconds = time.perf_counter() - start
    return result


def evaluate_lit_views(
    geometry, stand_in, cards, views, samples: int = 2, lights=None, ambient=AMBIENT
) -> LitEvaluation:
    """The lit figures (module docstring) from ``views``: (camera, row) pairs, each camera drawing
    ``samples`` per output pixel side and ``row`` a dict of what to report of the view (its
    ``kind`` at least; "outside" ones are left out of the totals).  ``geometry``, ``stand_in`` and
    ``cards`` are G-buffer renderers (``render_normals(camera)``, as :class:`MeshRenderer` made with
    ``normals=True`` and :func:`impostor_gbuffer`; shaded with their material where made with
    ``materials=True``, :func:`gbuffer_of`) of the geometry, the impostor with its normals
    and the impostor as flat cards.  A technique whose impostor stands in for part of what a view
    shows (an environment map's far field) gives renderers that leave the rest uncovered."""
    start = time.perf_counter()
    lights = default_lights() if lights is None else tuple(lights)
    rows = []
    for camera, row in views:
        stats = compare_lit(
            gbuffer_of(geometry, camera),
            gbuffer_of(stand_in, camera),
            gbuffer_of(cards, camera),
            camera,
            lights,
            ambient,
            samples,
        )
        rows.append(row | {"inside": row["kind"] != "outside", "stats": stats})
    totals = lit_totals([r["stats"] for r in rows if r["inside"]], len(lights))
    described = [{"direction": light.direction.tolist(), "intensity": float(light.intensity)} for light in lights]
    return LitEvaluation(rows, totals, described, time.perf_counter() - start)


def evaluate_lit(
    part: Scene, impostor: Impostor, random_count: int = 8, seed: int = 0, samples: int = 2, lights=None
) -> LitEvaluation:
    """:func:`evaluate_lit_at` from the viewpoints of the impostor's cell (its corners, the reference
    viewpoint and ``random_count`` seeded points inside)."""
    cell = viewcell_from_dict(impostor.viewcell)
    points, kinds = viewpoints(cell, impostor.reference_viewpoint, random_count, 0, seed)
    return evaluate_lit_at(part, impostor, points, kinds, samples, lights)


def lit_figures(result: LitEvaluation) -> dict:
    """The figures a benchmark's row shows of a lit evaluation, flat: the worst light's unlit, lit
    and flat-card mean errors, the two ratios, the normal errors (all, interior, smooth), the flat
    cards' normal error, the per-light totals and the seconds."""
    t = result.totals
    worst = max(t["lights"], key=lambda row: row["lit_error_mean"])
    return {
        "unlit_mean": worst["unlit_error_mean"],
        "lit_mean_worst": worst["lit_error_mean"],
        "flat_mean_worst": max(row["flat_error_mean"] for row in t["lights"]),
        "lit_to_unlit_worst": t["lit_to_unlit_worst"],
        "flat_to_lit_least": t["flat_to_lit_least"],
        "normal_median": t["normal_error_median"],
        "normal_p95": t["normal_error_p95"],
        "normal_interior_median": t["normal_error_interior_median"],
        "normal_interior_p95": t["normal_error_interior_p95"],
        "normal_smooth_median": t["normal_error_smooth_median"],
        "normal_smooth_p95": t["normal_error_smooth_p95"],
        "smooth_share": t["smooth_share"],
        "flat_normal_median": t["flat_normal_error_median"],
        "lights": t["lights"],
        "eval_s": result.seconds,
    } | {name: t[name] for name in ("source_material", "impostor_material", *MATERIAL_FIGURES) if name in t}


def lit_text(result: LitEvaluation) -> str:
    """The lit evaluation's totals as a table, a line per light."""
    t = result.totals
    lines = [
        f"lit, {t['viewpoints']} viewpoints inside the view cell; colour error where both cover (max over RGB, 0-255)",
        f"{'light (direction)':<26} {'lit mean':>9} {'lit p99':>8} {'ssim':>6} {'flat mean':>10} {'unlit mean':>11}",
    ]
    for light, row in zip(result.lights, t["lights"]):
        direction = "(" + ", ".join(f"{x:+.2f}" for x in light["direction"]) + ")"
        lines.append(
            f"{direction:<26} {row['lit_error_mean']:>9.2f} {row['lit_error_p99']:>8.1f} {row['lit_ssim']:>6.3f} "
            f"{row['flat_error_mean']:>10.2f} {row['unlit_error_mean']:>11.2f}"
        )
    lines.append(
        f"normal error: median {t['normal_error_median']:.1f}°, 95th percentile {t['normal_error_p95']:.1f}° "
        f"(away from silhouettes: {t['normal_error_interior_median']:.1f}°, {t['normal_error_interior_p95']:.1f}°; "
        f"on surfaces larger than a pixel, {100 * t['smooth_share']:.0f} % of them: "
        f"{t['normal_error_smooth_median']:.1f}°, {t['normal_error_smooth_p95']:.1f}°; "
        f"flat cards: median {t['flat_normal_error_median']:.1f}°)"
    )
    if t.get("source_material"):
        lines.append(
            f"material: the part's shaded with its material, the impostor's {t['impostor_material']} "
            f"(mean abs error: occlusion {t['occlusion_error_mean']:.3f}, roughness {t['roughness_error_mean']:.3f}, "
            f"metallic {t['metallic_error_mean']:.3f}, emission {t['emissive_error_mean']:.3f})"
        )
    lines.append(
        f"lit error / unlit error, worst light: {t['lit_to_unlit_worst']:.2f}; "
        f"flat cards' lit error / the impostor's, least: {t['flat_to_lit_least']:.2f}"
    )
    return "\n".join(lines)
