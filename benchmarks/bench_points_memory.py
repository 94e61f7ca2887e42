"""Point-based impostors at scale (issue 60, item 3): peak memory, points per pixel, time.

Usage: ``.venv/bin/python benchmarks/bench_points_memory.py [--scenes dense,bunny] [--resolutions 256,512]
[--subdivisions 7] [--before REV] [--json]``

Each bake runs in a fresh process (its peak resident memory is that process's ``ru_maxrss``), the
``points`` technique with its defaults, output at 45°:

- **dense**: ``tests/scenes.py::dense_mesh`` (a bumpy icosphere of radius 1, 327,680 triangles at
  7 subdivisions, the size of the 346k-triangle scan the issue measured; its ±2 % noise per vertex
  folds the surface like a scan's noise, 30-40 depth layers per LDI);
- **bunny**: the shared Stanford bunny (69,451 triangles).

The cell is a cube whose side is 10 % of its centre's distance to the part's centre (5 radii for
the sphere, 5 part sizes for the bunny), in front of the part along -z.  Per bake: the kept points;
**points per bounding-box pixel** (seed 001 Table 1's measure: the pixels of the screen bounding box
of the part drawn from the cell's centre at the output resolution) and per covered pixel there; points
per source vertex; the LDI candidates, the redundant ones and those no view of the cell shows; the
peak resident memory; the seconds per stage and the wall time; and the **hole pixels** of the
kept points drawn as one-pixel points with a numpy z-buffer from the cell's 8 corners, its centre
and 8 random points, against each view's first surface (depth peeled, one layer), and the same
from ``--unseen`` more random points of the cell (seed 7), views the points' selection never used.

``--before REV`` also bakes with ``core/techniques/points/`` as it was at git revision REV (loaded
from ``git archive`` in the child process, the rest of the package as it is now), side by side.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import importlib.util, json, math, resource, sys, time
sys.path.insert(0, sys.argv[1] + "/tests")
import numpy as np
scene_name, resolution, subdivisions, old, UNSEEN = sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), sys.argv[5], int(sys.argv[6])
import farfield.core.techniques  # registers the current techniques first
if old:  # the points package as it was, in place of the current one
    for name in [m for m in sys.modules if m.startswith("farfield.core.techniques.points")]:
        del sys.modules[name]
    spec = importlib.util.spec_from_file_location("farfield.core.techniques.points", old + "/__init__.py", submodule_search_locations=[old])
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
from farfield.core.techniques.points.technique import PointOptions, bake_points, warm_kernels
from farfield.core.render.context import gl_context, renderer_info
from farfield.core.render.peeling import peel
from farfield.core.techniques.envmap.runtime import camera_at
from farfield.core.viewcells import BoxCell
from scenes import dense_mesh, real_scene

gl_context()
warm_kernels()
if scene_name == "dense":
    scene = dense_mesh(subdivisions)
else:
    scene = real_scene("stanford_bunny/bun_zipper.ply")
lo, hi = scene.bounds
centre = 0.5 * (lo + hi)
distance = 5.0 * float(np.max(hi - lo)) / (2.0 if scene_name == "dense" else 1.0)
cell = BoxCell.from_center(centre - np.array([0.0, 0.0, distance]), 0.1 * distance)
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
start = time.perf_counter()
impostor = bake_points(scene, cell, PointOptions(resolution=resolution))
wall = time.perf_counter() - start
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
points = impostor.payload.world_points()
objects = list(scene.objects)

def first_surface(eye):
    near = max(float(np.linalg.norm(np.clip(eye, lo, hi) - eye)) * 0.5, 1e-3)
    far = float(np.max(np.linalg.norm(np.stack([lo, hi]) - eye, axis=1))) * 2.0
    camera = camera_at(eye, centre - eye, 45.0, resolution, near, far)
    return camera, peel(objects, camera, 1, truncate=True)[0][0, ..., 0]

camera, depth = first_surface(cell.center)
ys, xs = np.nonzero(np.isfinite(depth))
box = int((np.ptp(ys) + 1) * (np.ptp(xs) + 1))
holes = covered = 0
unseen = []  # hole pixels from random points of the cell that no selection view used
eyes = np.concatenate([cell.corners(), cell.center[None], cell.sample_random(8, 1), cell.sample_random(UNSEEN, 7)])
for k, eye in enumerate(eyes):
    camera, depth = first_surface(eye)
    pixels = np.floor(camera.project(points)).astype(np.int64)
    z = (points - camera.eye) @ camera.forward
    inside = np.all((pixels >= 0) & (pixels < resolution), axis=1) & (z > 0.0)
    hit = np.zeros((resolution, resolution), bool)
    hit[pixels[inside, 1], pixels[inside, 0]] = True
    first = np.isfinite(depth)
    if k >= 17:
        unseen.append(int((first & ~hit).sum()))
        continue
    holes += int((first & ~hit).sum())
    covered += int(first.sum())
s = impostor.stats
print(json.dumps({
    "renderer": renderer_info().renderer, "triangles": scene.triangle_count, "vertices": int(sum(o.vertices.shape[0] for o in objects)),
    "points": s["points"], "candidates": s["candidates"], "redundant_share": s["removed_share"], "unseen_dropped": s["unseen_dropped"],
    "ldi_resolution": s["ldi_resolution"], "ldi_layers": s["ldi_layers"], "box_pixels": box, "covered_pixels": len(ys),
    "peak_rss_gb": peak / 1e6, "before_bake_rss_gb": base / 1e6, "seconds": s["seconds"], "wall_seconds": wall,
    "hole_pixels": holes, "hole_views_covered": covered, "unseen_hole_pixels": sum(unseen), "unseen_views": len(unseen),
}))
"""


def before_package(rev: str, folder: str) -> str:
    """``core/techniques/points/`` at git revision ``rev``, unpacked under ``folder``; its path."""
    archive = Path(folder) / "points.tar"
    subprocess.run(["git", "archive", "-o", str(archive), rev, "core/techniques/points"], cwd=ROOT, check=True)
    with tarfile.open(archive) as tar:
        tar.extractall(folder, filter="data")
    return str(Path(folder) / "core" / "techniques" / "points")


def bake(scene: str, resolution: int, subdivisions: int, old: str, unseen: int) -> dict:
    run = subprocess.run(
        [sys.executable, "-c", CHILD, str(ROOT), scene, str(resolution), str(subdivisions), old, str(unseen)],
        capture_output=True, text=True, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)},
    )  # fmt: skip
    if run.returncode != 0:
        return {"error": (run.stderr.strip().splitlines() or ["failed"])[-1]}
    return json.loads(run.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default="dense,bunny", help="comma-separated: dense, bunny")
    parser.add_argument("--resolutions", default="256,512", help="comma-separated output pixels per side")
    parser.add_argument("--subdivisions", type=int, default=7, help="dense mesh: 20 * 4**n triangles")
    parser.add_argument("--before", default=None, help="git revision of core/techniques/points/ to bake beside")
    parser.add_argument(
        "--unseen",
        type=int,
        default=32,
        help="random viewpoints of the cell (seed 7) for the hole pixels of views no selection used",
    )
    parser.add_argument("--before-only", action="store_true", help="with --before: bake only the old code")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        versions = [("after", "")] + (
            [("before " + args.before, before_package(args.before, folder))] if args.before else []
        )
        versions = versions[1:] if args.before and args.before_only else versions
        print(
            f"{'scene':<7} {'px':>4} {'code':<14} {'tris':>8} {'points':>9} {'/box px':>7} {'/cov px':>7} {'/vertex':>7} "
            f"{'candidates':>10} {'redund.':>7} {'unseen':>9} {'LDI px':>5} {'layers':>9} {'peak GB':>7} {'holes':>5} {'new-view holes':>14} "
            f"{'points s':>8} {'vis s':>6} {'app s':>6} {'wall s':>7}",
            flush=True,
        )
        for scene in args.scenes.split(","):
            for resolution in map(int, args.resolutions.split(",")):
                for label, old in versions:
                    r = bake(scene, resolution, args.subdivisions, old, args.unseen)
                    r.update(scene=scene, resolution=resolution, code=label)
                    rows.append(r)
                    if "error" in r:
                        print(f"{scene:<7} {resolution:>4} {label:<14} failed: {r['error']}", flush=True)
                        continue
                    sec = r["seconds"]
                    print(
                        f"{scene:<7} {resolution:>4} {label:<14} {r['triangles']:>8,} {r['points']:>9,} {r['points'] / r['box_pixels']:>7.2f} "
                        f"{r['points'] / r['covered_pixels']:>7.2f} {r['points'] / r['vertices']:>7.2f} {r['candidates']:>10,} "
                        f"{100 * r['redundant_share']:>6.1f}% {r['unseen_dropped']:>9,} {r['ldi_resolution'][0]:>5} "
                        f"{'/'.join(map(str, r['ldi_layers'])):>9} {r['peak_rss_gb']:>7.2f} {r['hole_pixels']:>5} {r['unseen_hole_pixels']:>14} "
                        f"{sec['points']:>8.1f} {sec.get('visibility', 0.0):>6.1f} {sec['appearance']:>6.1f} {r['wall_seconds']:>7.1f}",
                        flush=True,
                    )
        if rows and "renderer" in rows[0]:
            print(f"renderer: {rows[0]['renderer']}")
    if args.json:
        print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
