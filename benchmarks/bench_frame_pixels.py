"""Issue 57 item 4: what a frame's clipped-box pixel estimate costs per frame, beside the direction-free bound.

Usage: ``.venv/bin/python benchmarks/bench_frame_pixels.py [--scene street,downtown,city] [--views 200] [--repeats 20]``

Pure arithmetic, nothing drawn: per scene (``bench_visibility.py``'s), random eyes in the view space
and random directions; per frame the CPU microseconds (``time.process_time``, each view repeated
``--repeats`` times, the median view reported) of

* ``free``: :func:`~farfield.core.placement.runtime.plain_estimate` without a camera (each element's
  disc or faces from the eye: the estimate before 2026-12-07, clip30);
* ``clipped``: the same with the frame's camera (each box projected and clipped to the near plane and
  the frame, :func:`~farfield.core.placement.frame_pixels.box_frame_pixels`: the runtime's now);

over every element of the scene (an upper end: the runtime passes only the elements it draws, after
frustum culling and the PVS) and over those the frustum keeps (:func:`~farfield.core.placement.runtime.boxes_in_frustum`).
The first call compiles the numba kernel (cached on disk); it is made before timing.
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
from farfield.core.techniques.envmap.runtime import camera_at  # noqa: E402


def per_frame_us(call, repeats: int) -> float:
    start = time.process_time()
    for _ in range(repeats):
        call()
    return 1e6 * (time.process_time() - start) / repeats


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="street,downtown,city")
    parser.add_argument("--views", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    fov, res = math.radians(45.0), args.resolution
    print(f"# {args.views} random views x {args.repeats} repeats, {res} px, 45°; CPU µs per frame, median view")
    print(f"{'scene':9s} {'elements':>8s} {'in frustum p50':>14s} {'all: free':>10s} {'clipped':>8s} "
          f"{'frustum: free':>14s} {'clipped':>8s}")  # fmt: skip
    rng = np.random.default_rng(args.seed)
    for name in args.scene.split(","):
        scene, lo, hi = scene_of(name)
        elements = Elements.of(scene)
        everything = np.arange(elements.count)
        b = elements.bounds
        rows = []
        for k in range(args.views + 1):
            eye = rng.uniform(lo, hi)
            d = rng.normal(size=3)
            camera = camera_at(eye, d, 45.0, res, 0.1, 1e4)
            seen = everything[boxes_in_frustum(camera, b[:, 0], b[:, 1])]
            if k == 0:  # compile (or load) the kernel, untimed
                plain_estimate(LLVMPIPE_MODEL, elements, everything, eye, fov, res, 1.0, camera)
                continue
            rows.append((
                seen.size,
                per_frame_us(lambda: plain_estimate(LLVMPIPE_MODEL, elements, everything, eye, fov, res, 1.0), args.repeats),
                per_frame_us(lambda: plain_estimate(LLVMPIPE_MODEL, elements, everything, eye, fov, res, 1.0, camera), args.repeats),
                per_frame_us(lambda: plain_estimate(LLVMPIPE_MODEL, elements, seen, eye, fov, res, 1.0), args.repeats),
                per_frame_us(lambda: plain_estimate(LLVMPIPE_MODEL, elements, seen, eye, fov, res, 1.0, camera), args.repeats),
            ))  # fmt: skip
        a = np.median(np.array(rows, dtype=float), axis=0)
        print(
            f"{name:9s} {elements.count:8d} {a[0]:14.0f} {a[1]:10.1f} {a[2]:8.1f} {a[3]:14.1f} {a[4]:8.1f}", flush=True
        )


if __name__ == "__main__":
    main()
