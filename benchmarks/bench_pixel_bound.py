"""Issue 57 item 4: the planner's per-element pixel estimate, bounding-sphere disc against min(disc, box faces).

Usage: ``.venv/bin/python benchmarks/bench_pixel_bound.py [--scene street,downtown,city] [--views 300] [--drawn 100]``

Pure arithmetic (nothing drawn, independent of load): per scene (``bench_visibility.py``'s), random
eyes in the view space and random directions; over the elements whose bounding sphere meets the
frame's cone (no PVS), the sum of each element's estimated pixels with the disc alone (before
2026-12-07) and with :func:`farfield.core.placement.view_space.element_pixels` (after), in frames,
and how many views reach the 1-frame cap either way.

``--drawn N`` (GL): N more views per scene drawn whole (every element), and per view, each capped
at a frame: the estimate (``element_pixels`` over the elements in the cone), the sum of each box's
projection clipped to the near plane and the frame (:func:`farfield.core.placement.frame_pixels.box_frame_pixels`:
the runtime's per-frame estimate since 2026-12-07, clip30, as it knows the camera; not the
planner's), and the frame's covered pixels.
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

from farfield.core.placement.frame_pixels import box_frame_pixels  # noqa: E402
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


def drawn_rows(name: str, views: int, res: int, rng) -> None:
    from farfield.core.render.raster import Camera, MeshRenderer

    fov, near = math.radians(45.0), 0.05
    frame, half = float(res) ** 2, frame_half_diagonal(fov)
    scene, lo, hi = scene_of(name)
    elements = Elements.of(scene)
    centre = elements.bounds.mean(axis=1)
    radius = 0.5 * np.linalg.norm(elements.bounds[:, 1] - elements.bounds[:, 0], axis=1)
    rows = []
    with MeshRenderer(list(scene.objects)) as gpu:
        for _ in range(views):
            eye = rng.uniform(lo, hi)
            d = rng.normal(size=3)
            d /= np.linalg.norm(d)
            camera = Camera.look_at(eye, eye + d, fov, res, near, 1e4)
            covered = float(np.count_nonzero(gpu.render(camera)[..., 3]))
            v = centre - eye
            dist = np.maximum(np.linalg.norm(v, axis=1), 1e-12)
            angle = np.arccos(np.clip(v @ d / dist, -1.0, 1.0))
            seen = np.flatnonzero((dist <= radius) | (angle - np.arcsin(np.minimum(1.0, radius / dist)) <= half))
            estimate = float(element_pixels(elements, eye, eye, fov, res, seen).sum()) if seen.size else 0.0
            clipped = float(box_frame_pixels(camera, elements.bounds[seen, 0], elements.bounds[seen, 1]).sum())
            rows.append((min(estimate, frame), min(clipped, frame), covered))
    a = np.array(rows)
    cov = np.maximum(a[:, 2], 1.0)
    print(
        f"{name:9s} {np.median(a[:, 0]) / frame:8.2f} {np.median(a[:, 1]) / frame:8.2f} {np.median(a[:, 2]) / frame:8.2f}"
        f" {np.median(a[:, 0] / cov):9.2f} {np.median(a[:, 1] / cov):9.2f} {np.mean(a[:, 1] < a[:, 2] - 2.0):11.0%}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="street,downtown,city")
    parser.add_argument("--views", type=int, default=300)
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--drawn", type=int, default=0, help="views drawn per scene (GL; 0: none)")
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
    if args.drawn:
        print(f"# {args.drawn} drawn views; p50s in frames, each capped at a frame; ratios over the covered pixels")
        print(
            f"{'scene':9s} {'estimate':>8s} {'clipped':>8s} {'covered':>8s} {'est/cov':>9s} {'clip/cov':>9s} {'clip < cov':>11s}"
        )
        for name in args.scene.split(","):
            drawn_rows(name, args.drawn, res, rng)


if __name__ == "__main__":
    main()
