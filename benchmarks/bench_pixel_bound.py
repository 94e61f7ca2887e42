"""Issue 57 item 4: the planner's per-element pixel estimate, bounding-sphere disc against min(disc, box faces).

Usage: ``.venv/bin/python benchmarks/bench_pixel_bound.py [--scene street,downtown,city] [--views 300]``

Pure arithmetic (nothing drawn, independent of load): per scene (``bench_visibility.py``'s), random
eyes in the view space and random directions; over the elements whose bounding sphere meets the
frame's cone (no PVS), the sum of each element's estimated pixels with the disc alone (before
2026-12-07) and with :func:`farfield.core.placement.view_space.element_pixels` (after), in frames,
and how many views reach the 1-frame cap either way.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_visibility import scene_of  # noqa: E402

from farfield.core.placement.hierarchy import Elements  # noqa: E402
from farfield.core.placement.view_space import box_gap, element_pixels, frame_half_diagonal  # noqa: E402


def disc_pixels(bounds: np.ndarray, eye: np.ndarray, fov: float, resolution: int) -> np.ndarray:
    """The estimate before: each bounding sphere's disc at the box distance, at most a frame."""
    radius = 0.5 * np.linalg.norm(bounds[:, 1] - bounds[:, 0], axis=1)
    dist = box_gap(bounds[:, 0], bounds[:, 1], eye, eye)
    focal = 0.5 * resolution / math.tan(0.5 * fov)
    frame = float(resolution) ** 2
    with np.errstate(divide="ignore"):
        disc = np.where(dist > 0.0, math.pi * (focal * radius / np.where(dist > 0.0, dist, 1.0)) ** 2, frame)
    return np.minimum(disc, frame)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="street,downtown,city")
    parser.add_argument("--views", type=int, default=300)
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    fov, res = math.radians(45.0), args.resolution
    half, frame = frame_half_diagonal(fov), float(res) ** 2
    print(f"# {args.views} random views, {res} px, 45°; sums in frames")
    print(
        f"{'scene':9s} {'before p50':>10s} {'after p50':>9s} {'after/before p50':>16s} {'p5':>5s} {'capped before':>13s} {'after':>6s}"
    )
    rng = np.random.default_rng(args.seed)
    for name in args.scene.split(","):
        scene, lo, hi = scene_of(name)
        elements = Elements.of(scene)
        centre = elements.bounds.mean(axis=1)
        radius = 0.5 * np.linalg.norm(elements.bounds[:, 1] - elements.bounds[:, 0], axis=1)
        before, after = [], []
        for _ in range(args.views):
            eye = rng.uniform(lo, hi)
            d = rng.normal(size=3)
            d /= np.linalg.norm(d)
            v = centre - eye
            dist = np.maximum(np.linalg.norm(v, axis=1), 1e-12)
            angle = np.arccos(np.clip(v @ d / dist, -1.0, 1.0))
            seen = np.flatnonzero((dist <= radius) | (angle - np.arcsin(np.minimum(1.0, radius / dist)) <= half))
            if seen.size:
                before.append(disc_pixels(elements.bounds[seen], eye, fov, res).sum() / frame)
                after.append(element_pixels(elements, eye, eye, fov, res, seen).sum() / frame)
        b, a = np.array(before), np.array(after)
        print(
            f"{name:9s} {np.median(b):10.2f} {np.median(a):9.2f} {np.median(a / b):16.3f} "
            f"{np.percentile(a / b, 5):5.2f} {np.mean(b >= 1.0):13.0%} {np.mean(a >= 1.0):6.0%}"
        )


if __name__ == "__main__":
    main()
