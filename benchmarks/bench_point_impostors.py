"""Point-based impostors (seed 001) baked by the ``points`` technique: size, bake time, holes,
colour, and aliasing and flicker against plain geometry.

Usage: ``.venv/bin/python benchmarks/bench_point_impostors.py [--resolution 256] [--parts bunny,pine,forest,city] [--json]``

The parts and cells are ``bench_points.py``'s (issue 27's list: the shared bunny, the shared
alpha-cut scrub pine, a procedural forest of thin trunks, a procedural city block; a cubic cell a
quarter of the part's size two part-diameters in front of it), output at 45°.  Per part:

- **size**: the points, the LDI candidates and the shares removed (redundant, §5.1; never shown by
  any appearance view), the points per covered output pixel (covered: the part's pixels seen from
  the cell's centre at 4 x 4 samples) and per pixel of the part's screen bounding box there (seed
  001's Table 1 measure), the share of one-colour points (§5.3) and the bytes per point;
- **bake seconds** per stage (plan, points, appearance, pack) and the appearance's views;
- **the evaluation** (:func:`farfield.core.quality.evaluation.evaluate`, as ``farfield evaluate`` runs it): the cell's
  corners, reference viewpoint (its centre) and 16 random points, hole pixels, pixels bloated
  beyond one pixel, colour error mean;
- **aliasing error** (the paper's reason to exist, Figs. 6-8): from the cell's centre and 8
  random points, the mean over the pixels either image covers of the difference (max over RGB,
  0-255) to a **reference**: the part drawn with 8 x 8 samples per pixel, each pixel the mean of
  its samples composited over mid grey in linear light.  The candidates are the point impostor and
  plain geometry at one sample per pixel, both over the same grey;
- **flicker**: along a slow camera path (32 frames from the cell's centre towards a corner, each
  step moving the nearest point of the part by ¼ pixel of parallax), the mean over consecutive
  frames of the mean difference between them over the pixels either covers (0-255): the
  reference's own change is what the image should do, the excess over it is flicker.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_points import parts  # noqa: E402

from farfield.core.colour_space import linear_to_srgb, srgb_to_linear  # noqa: E402
from farfield.core.quality.evaluation import evaluate, impostor_renderer  # noqa: E402
from farfield.core.render.context import gl_context, renderer_info  # noqa: E402
from farfield.core.render.raster import Camera, MeshRenderer, depth_bounds  # noqa: E402
from farfield.core.scene import Scene  # noqa: E402
from farfield.core.techniques import get_technique  # noqa: E402
from farfield.core.viewcells import box_corners  # noqa: E402

GREY = srgb_to_linear(128 / 255.0)
REFERENCE_SAMPLES = 8
FRAMES = 32


def over_grey(image: np.ndarray, samples: int) -> np.ndarray:
    """(h, w, 4) float: an (h s, w s, 4) uint8 render's pixels, each the mean of its samples over
    mid grey in linear light (a sample's alpha its coverage), sRGB 0-255; alpha the covered share."""
    h, w = image.shape[0] // samples, image.shape[1] // samples
    alpha = image[..., 3] / 255.0  # a point's coverage; 0 or 1 for geometry
    linear = alpha[..., None] * srgb_to_linear(image[..., :3] / 255.0) + (1.0 - alpha[..., None]) * GREY
    rgb = linear.reshape(h, samples, w, samples, 3).mean(axis=(1, 3))
    cover = alpha.reshape(h, samples, w, samples).mean(axis=(1, 3))
    return np.concatenate([linear_to_srgb(rgb) * 255.0, cover[..., None]], axis=2)


def difference(a: np.ndarray, b: np.ndarray) -> float:
    """Mean over the pixels either covers of the largest RGB difference."""
    either = (a[..., 3] > 0) | (b[..., 3] > 0)
    return float(np.abs(a[..., :3] - b[..., :3]).max(axis=2)[either].mean()) if either.any() else 0.0


def views(cell, lo, hi, resolution):
    """(aliasing viewpoints, flicker path) for the part in [lo, hi] seen from ``cell``."""
    still = np.concatenate([cell.center[None], cell.sample_random(8, 7)])
    nearest = max(float(np.linalg.norm(np.clip(cell.center, lo, hi) - cell.center)), 1e-6)
    step = 0.25 * 2.0 * math.tan(math.radians(22.5)) / resolution * nearest  # ¼ pixel of parallax at the nearest point
    direction = (cell.hi - cell.center) / np.linalg.norm(cell.hi - cell.center)
    path = cell.center + np.arange(FRAMES)[:, None] * step * direction
    return still, path


def camera(eye, target, extent, resolution):
    forward = (target - eye) / np.linalg.norm(target - eye)
    near, far = depth_bounds(eye, forward, extent)
    return Camera.look_at(eye, target, math.radians(45.0), resolution, near, far)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, default=256, help="output pixels per side (FOV 45°)")
    parser.add_argument("--parts", default="bunny,pine,forest,city", help="comma-separated: bunny, pine, forest, city")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    wanted = args.parts.split(",")
    gl_context()
    info = renderer_info()
    print(f"renderer: {info.renderer} ({info.vendor}, {info.version}); output {args.resolution} px, 45°")
    technique = get_technique("points")
    rows = []
    for (name, objects, cell), key in zip(parts(), ("bunny", "pine", "forest", "city")):
        if key not in wanted:
            continue
        scene = Scene.from_objects(objects, source=name)
        lo, hi = scene.bounds
        start = time.perf_counter()
        impostor = technique.bake(scene, cell, technique.options({}, args.resolution), None, None)
        bake_s = time.perf_counter() - start
        s = impostor.stats
        evaluation = evaluate(scene, impostor, cell, random_count=16, outside_count=0, seed=0)
        t = evaluation.totals
        target = 0.5 * (lo + hi)
        extent = np.concatenate([box_corners(scene.bounds), impostor.payload.world_points()])
        still, path = views(cell, lo, hi, args.resolution)
        alias = {"points": [], "geometry": []}
        flicker = {"reference": [], "points": [], "geometry": []}
        with MeshRenderer(scene.objects) as geometry, impostor_renderer(impostor) as points:
            centre_view = (
                over_grey(geometry.render(camera(cell.center, target, extent, 4 * args.resolution)), 4)[..., 3] > 0
            )
            covered = int(centre_view.sum())
            ys, xs = np.nonzero(centre_view)
            box = int((np.ptp(ys) + 1) * (np.ptp(xs) + 1)) if ys.size else 0  # the paper's measure

            def frames(eye):
                c = camera(eye, target, extent, args.resolution)
                fine = camera(eye, target, extent, REFERENCE_SAMPLES * args.resolution)
                return {
                    "reference": over_grey(geometry.render(fine), REFERENCE_SAMPLES),
                    "points": over_grey(points.render(c), 1),
                    "geometry": over_grey(geometry.render(c), 1),
                }

            for eye in still:
                f = frames(eye)
                for k in alias:
                    alias[k].append(difference(f[k], f["reference"]))
            previous = None
            for eye in path:
                f = frames(eye)
                if previous is not None:
                    for k in flicker:
                        flicker[k].append(difference(f[k], previous[k]))
                previous = f
        row = {
            "part": name, "triangles": scene.triangle_count, "points": s["points"], "candidates": s["candidates"],
            "redundant_share": s["removed_share"], "unseen_dropped": s["unseen_dropped"], "points_per_covered_pixel": s["points"] / covered, "points_per_box_pixel": s["points"] / box,
            "single_colour_share": s["single_colour_share"], "bytes_per_point": s["bytes_per_point"], "views": s["appearance"]["views"],
            "standard_error_p95": s["appearance"]["standard_error_p95"], "seconds": s["seconds"], "bake_seconds": bake_s,
            "hole_pixels": t["hole_pixels"], "bloat_beyond_1px": t["bloat_beyond_1px"], "colour_error_mean": t["colour_error_mean"], "viewpoints": t["viewpoints"],
            "aliasing_points": float(np.mean(alias["points"])), "aliasing_geometry": float(np.mean(alias["geometry"])),
            "flicker_reference": float(np.mean(flicker["reference"])), "flicker_points": float(np.mean(flicker["points"])), "flicker_geometry": float(np.mean(flicker["geometry"])),
        }  # fmt: skip
        rows.append(row)
        sec = s["seconds"]
        print(
            f"{name}: {row['points']:,} points of {row['candidates']:,} candidates (redundant {100 * row['redundant_share']:.1f} %, never shown {row['unseen_dropped']:,}), "
            f"{row['points_per_covered_pixel']:.1f} per covered pixel ({row['points_per_box_pixel']:.1f} per pixel of its screen bounding box), one colour {100 * row['single_colour_share']:.1f} %, {row['bytes_per_point']:.1f} B/point; "
            f"{row['views']} views (SE p95 {row['standard_error_p95']}); seconds plan {sec['plan']:.1f} points {sec['points']:.1f} appearance {sec['appearance']:.1f} pack {sec['pack']:.1f} total {sec['total']:.1f}\n"
            f"    evaluation over {row['viewpoints']} viewpoints: {row['hole_pixels']} hole pixels, {row['bloat_beyond_1px']} bloated beyond 1 px, colour error mean {row['colour_error_mean']:.2f}; "
            f"aliasing error points {row['aliasing_points']:.2f} vs geometry 1 spp {row['aliasing_geometry']:.2f} (ratio {row['aliasing_geometry'] / max(row['aliasing_points'], 1e-9):.2f}); "
            f"flicker reference {row['flicker_reference']:.2f}, points {row['flicker_points']:.2f}, geometry {row['flicker_geometry']:.2f}",
            flush=True,
        )
    if args.json:
        print(json.dumps({"renderer": info.renderer, "resolution": args.resolution, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
