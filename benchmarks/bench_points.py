"""Point-based impostors (seed 001), the geometry so far: LDIs, candidates, redundant points removed, holes.

Usage: ``.venv/bin/python benchmarks/bench_points.py [--resolution 256] [--json]``

For each test part of issue 27 (the shared Stanford bunny, the shared alpha-cut scrub pine, a
procedural forest of thin trunks, a procedural city block), a cubic view cell in front of it: the
three LDI cameras' resolutions (seed 001 §5.1), the depth layers peeled, the candidate points, the
share removed as redundant (paper: 40-60 %), the kept points per covered output pixel (paper: 2-3),
and the hole pixels of the kept points drawn as one-pixel points from the cell's 8 corners, centre
and 8 random points with a z-buffer, against the part's own depth-peeled first surface (also those
with no point in their 8 neighbours either, and the pixels whose nearest point lies more than 0.5 %
behind the first surface: a see-through), with the seconds of each step: the geometry alone (``bench_point_impostors.py`` bakes the whole technique).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy.ndimage import binary_dilation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from farfield.core.ldi.image import record_ldi  # noqa: E402
from farfield.core.render.context import gl_context, renderer_info  # noqa: E402
from farfield.core.techniques.envmap.runtime import camera_at  # noqa: E402
from farfield.core.techniques.points.samples import gather_point_samples  # noqa: E402
from farfield.core.techniques.points.sampling import plan_point_sampling  # noqa: E402
from farfield.core.viewcells import BoxCell  # noqa: E402
from tests.scenes import city, forest, real_scene  # noqa: E402


def parts():
    """(name, objects, cell): each part with a cubic cell two part-diameters in front of it (-z)."""
    bunny = real_scene("stanford_bunny/bun_zipper.ply")
    pine = real_scene("scrub_pine/scrubPine.obj")
    trunks = forest(60, seed=1).subset([f"tree_{i:03d}" for i in range(60)])
    block = city(16, seed=0)
    for name, scene in (
        ("bunny (shared scan)", bunny),
        ("scrub pine (shared, alpha-cut)", pine),
        ("forest of thin trunks", trunks),
        ("city block", block),
    ):
        lo, hi = scene.bounds
        size = float(np.max(hi - lo))
        centre = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2] - 2.0 * size])
        yield name, list(scene.objects), BoxCell.from_center(centre, 0.25 * size)


def holes(objects, cell: BoxCell, points: np.ndarray, resolution: int) -> tuple[int, int, int, int]:
    """(hole pixels, of those with no point in their 8 neighbours either, pixels whose nearest point
    lies behind the first surface, covered pixels) over the 17 views (module docstring)."""
    lo = np.min([o.bounds[0] for o in objects], axis=0)
    hi = np.max([o.bounds[1] for o in objects], axis=0)
    target = 0.5 * (lo + hi)
    missing = far = wrong = covered_total = 0
    for eye in np.concatenate([cell.corners(), cell.center[None], cell.sample_random(8, 1)]):
        near = float(np.linalg.norm(np.clip(eye, lo, hi) - eye)) * 0.5
        camera = camera_at(
            eye,
            target - eye,
            45.0,
            resolution,
            max(near, 1e-3),
            float(np.max(np.linalg.norm(np.stack([lo, hi]) - eye, axis=1))) * 2.0,
        )
        surface = record_ldi(objects, camera).depth[0]
        first = np.isfinite(surface)
        pixels = np.floor(camera.project(points)).astype(np.int64)
        depth = (points - camera.eye) @ camera.forward
        inside = np.all((pixels >= 0) & (pixels < resolution), axis=1) & (depth > 0.0)
        nearest = np.full((resolution, resolution), np.inf)  # the z-buffer of one-pixel points
        np.minimum.at(nearest, (pixels[inside, 1], pixels[inside, 0]), depth[inside])
        hit = np.isfinite(nearest)
        wrong += int((first & hit & (nearest > surface * 1.005)).sum())
        missing += int((first & ~hit).sum())
        far += int((first & ~binary_dilation(hit, structure=np.ones((3, 3), dtype=bool))).sum())
        covered_total += int(first.sum())
    return missing, far, wrong, covered_total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, default=256, help="output pixels per side (FOV 45°)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    gl_context()
    info = renderer_info()
    print(f"renderer: {info.renderer} ({info.vendor}, {info.version}); output {args.resolution} px, 45°")
    print(
        f"{'part':<32} {'tris':>8} {'LDI px':>16} {'layers':>9} {'candidates':>10} {'removed':>8} {'kept':>9} {'pts/px':>7} {'holes':>6} {'>1 px':>6} {'behind':>6} {'plan s':>7} {'points s':>8}"
    )
    rows = []
    for name, objects, cell in parts():
        lo = np.min([o.bounds[0] for o in objects], axis=0)
        hi = np.max([o.bounds[1] for o in objects], axis=0)
        t = time.perf_counter()
        sampling = plan_point_sampling(cell, np.stack([lo, hi]), 45.0, args.resolution)
        plan_s = time.perf_counter() - t
        t = time.perf_counter()
        points = gather_point_samples(objects, sampling, cell, 45.0, args.resolution)
        points_s = time.perf_counter() - t
        s = points.stats
        kept = points.positions[points.kept]
        missing, beyond, wrong, covered = holes(objects, cell, kept, args.resolution)
        per_pixel = s["kept"] / (covered / 17.0) if covered else float("nan")
        row = {"part": name, "triangles": int(sum(o.faces.shape[0] for o in objects)), "ldi_resolutions": [c.resolution for c in sampling.cameras],
               "layers": [c["layers"] for c in s["per_camera"]], "candidates": s["candidates"], "removed_share": s["removed_share"], "kept": s["kept"],
               "points_per_covered_pixel": per_pixel, "hole_pixels": missing, "holes_beyond_1px": beyond, "wrong_surface_pixels": wrong, "plan_seconds": plan_s, "points_seconds": points_s}  # fmt: skip
        rows.append(row)
        print(
            f"{name:<32} {row['triangles']:>8,} {'/'.join(map(str, row['ldi_resolutions'])):>16} {'/'.join(map(str, row['layers'])):>9} "
            f"{s['candidates']:>10,} {100 * s['removed_share']:>7.1f}% {s['kept']:>9,} {per_pixel:>7.1f} {missing:>6} {beyond:>6} {wrong:>6} {plan_s:>7.2f} {points_s:>8.2f}"
        )
    if args.json:
        print(json.dumps({"renderer": info.renderer, "resolution": args.resolution, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
