"""Issue 57 item 4: how far a CPV's enclosing-frustum estimate lies over its worst view, by the test
that decides which elements the frustum holds.

Usage: ``.venv/bin/python benchmarks/bench_cpv_cone.py [--scene street,downtown,city] [--cpvs 150]
[--views 16] [--seed 0]``

Per scene (``bench_visibility.py``'s), ``--cpvs`` random (region, interval) pairs at the planner's
defaults (regions of side / 8, 11.25° intervals, 45°, 128 px, builtin model, 1-frame pixel cap; no
PVS), and per pair ``--views`` views sampled in it (eye uniform in the region, direction uniform
in the interval's face square): the model over each view's frustum (discs from the eye, as
``bench_estimate_split.py``'s views in no CPV).  For each test, the elements the CPV's frustum
holds (mean) and its estimate over its worst sampled view (p50, p95):

* ``sphere``: the bounding sphere of ``element - region`` against the cone (before 2026-12-07);
* ``exact``: that, refined by the exact cone-against-box test (:mod:`farfield.core.placement.cone_box`);
* ``sub N``: the largest of the exact estimates of the region's N x N (x N) sub-boxes along its
  axes longer than a fifth of its longest: a bound the greedy could use only by tracking each
  sub-box's time (each view lies in one sub-box), for what it would win.

Model arithmetic only (nothing is drawn or timed); the worst of a few sampled views is below the
CPV's true worst, so the ratios are upper bounds of the slack.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_visibility import scene_of  # noqa: E402

from farfield.core.placement.cost_model import LLVMPIPE_MODEL  # noqa: E402
from farfield.core.placement.hierarchy import Elements  # noqa: E402
from farfield.core.placement.runtime import boxes_in_frustum, plain_estimate  # noqa: E402
from farfield.core.placement.view_space import VDI, RegionSight, element_pixels, frame_half_diagonal  # noqa: E402
from farfield.core.techniques.envmap.runtime import camera_at  # noqa: E402

FOV_DEG, RESOLUTION = 45.0, 128


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="street,downtown,city")
    parser.add_argument("--cpvs", type=int, default=150)
    parser.add_argument("--views", type=int, default=16)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    model, fov = LLVMPIPE_MODEL, math.radians(FOV_DEG)
    widen, frame = frame_half_diagonal(fov), float(RESOLUTION * RESOLUTION)
    print(f"{'scene':<9} {'test':<7} {'elements':>8} {'CPV/worst p50':>13} {'p95':>6} {'CPU s':>6}")
    for name in args.scene.split(","):
        rng = np.random.default_rng(args.seed)
        scene, lo, hi = scene_of(name)
        el = Elements.of(scene)
        b = el.bounds
        n = np.maximum(1, np.ceil((hi - lo) / (float(np.max(hi - lo)) / 8.0) - 1e-9)).astype(int)
        cost = model.geometry_time(el.draw_calls, el.triangles, 0.0)

        def estimate(mask, pixels):
            return model.frame_time + cost[mask].sum() + model.geometry[2] * min(pixels[mask].sum(), frame)

        rows: dict[str, list] = {}
        cpu: dict[str, float] = {}
        for _ in range(args.cpvs):
            cell = rng.integers(0, n)
            r_lo, r_hi = lo + cell * (hi - lo) / n, lo + (cell + 1) * (hi - lo) / n
            vdi = VDI(int(rng.integers(6)), 3, int(rng.integers(8)), int(rng.integers(8)))
            axis, half = vdi.cone()
            h = np.array([half + widen])
            x0, x1, y0, y1 = vdi.ranges()
            worst = 0.0
            for _ in range(args.views):
                eye = rng.uniform(r_lo, r_hi)
                forward = vdi.directions([rng.uniform(x0, x1)], [rng.uniform(y0, y1)])[0]
                ids = np.flatnonzero(
                    boxes_in_frustum(camera_at(eye, forward, FOV_DEG, RESOLUTION, 0.1, 1e4), b[:, 0], b[:, 1])
                )
                worst = max(worst, plain_estimate(model, el, ids, eye, fov, RESOLUTION, 1.0))
            pixels = element_pixels(el, r_lo, r_hi, fov, RESOLUTION)
            for test in ("sphere", "exact"):
                started = time.process_time()
                sight = RegionSight.of(b[:, 0], b[:, 1], r_lo, r_hi)
                mask = (sight.seen_by_sphere if test == "sphere" else sight.seen)(axis[None, :], h)[0]
                cpu[test] = cpu.get(test, 0.0) + time.process_time() - started
                rows.setdefault(test, []).append((mask.sum(), estimate(mask, pixels) / worst))
            for div in (2, 4):
                ext = r_hi - r_lo
                parts = np.where(ext > 0.2 * ext.max(), div, 1)
                best = (0.0, 0)
                for idx in np.ndindex(*parts):
                    s_lo = r_lo + np.array(idx) * ext / parts
                    s_hi = r_lo + (np.array(idx) + 1) * ext / parts
                    mask = RegionSight.of(b[:, 0], b[:, 1], s_lo, s_hi).seen(axis[None, :], h)[0]
                    best = max(best, (estimate(mask, element_pixels(el, s_lo, s_hi, fov, RESOLUTION)), int(mask.sum())))
                rows.setdefault(f"sub {div}", []).append((best[1], best[0] / worst))
        for test, r in rows.items():
            r = np.array(r)
            print(f"{name:<9} {test:<7} {r[:, 0].mean():8.1f} {np.median(r[:, 1]):13.2f} {np.percentile(r[:, 1], 95):6.2f} "
                  f"{cpu.get(test, math.nan):6.2f}", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
