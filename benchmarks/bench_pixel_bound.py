"""Issue 57 item 4: the planner's per-element pixel estimate, bounding-sphere disc against min(disc, box faces).

Usage: ``.venv/bin/python benchmarks/bench_pixel_bound.py [--scene street,downtown,city] [--views 300] [--drawn 100]``

Pure arithmetic (nothing drawn, independent of load): per scene (``bench_visibility.py``'s), random
eyes in the view space and random directions; over the elements whose bounding sphere meets the
frame's cone (no PVS), the sum of each element's estimated pixels with the disc alone (before
2026-12-07) and with :func:`farfield.core.placement.view_space.element_pixels` (after), in frames,
and how many views reach the 1-frame cap either way.

``--drawn N`` (GL): N more views per scene drawn whole (every element), and per view, each capped
at a frame: the estimate (``element_pixels`` over the elements in the cone), the sum of each box's
projection clipped to the near plane and the frame (a per-view estimate the runtime could make,
as it knows the camera; not the planner's), and the frame's covered pixels.
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

CORNERS = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
EDGES = [(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1]


def disc_pixels(bounds: np.ndarray, eye: np.ndarray, fov: float, resolution: int) -> np.ndarray:
    """The estimate before: each bounding sphere's disc at the box distance, at most a frame."""
    radius = 0.5 * np.linalg.norm(bounds[:, 1] - bounds[:, 0], axis=1)
    dist = box_gap(bounds[:, 0], bounds[:, 1], eye, eye)
    focal = 0.5 * resolution / math.tan(0.5 * fov)
    frame = float(resolution) ** 2
    with np.errstate(divide="ignore"):
        disc = np.where(dist > 0.0, math.pi * (focal * radius / np.where(dist > 0.0, dist, 1.0)) ** 2, frame)
    return np.minimum(disc, frame)


def _clip_area(polygon: np.ndarray, limit: float) -> float:
    """Area of a convex polygon (k, 2) clipped to the square ``[-limit, limit]²`` (Sutherland-Hodgman)."""
    poly = list(polygon)
    for axis in (0, 1):
        for sign in (1.0, -1.0):
            out = []
            for i in range(len(poly)):
                a, b = poly[i], poly[(i + 1) % len(poly)]
                in_a, in_b = sign * a[axis] <= limit, sign * b[axis] <= limit
                if in_a:
                    out.append(a)
                if in_a != in_b:
                    out.append(a + (limit - sign * a[axis]) / (sign * (b[axis] - a[axis])) * (b - a))
            poly = out
            if len(poly) < 3:
                return 0.0
    p = np.array(poly)
    return 0.5 * abs(float(np.dot(p[:, 0], np.roll(p[:, 1], -1)) - np.dot(p[:, 1], np.roll(p[:, 0], -1))))


def projected_pixels(bounds: np.ndarray, eye, forward, right, up, focal: float, resolution: int, near: float) -> float:
    """Pixels of a box's projection clipped to the near plane and the frame (its convex hull's area)."""
    from scipy.spatial import ConvexHull

    q = bounds[0] + CORNERS * (bounds[1] - bounds[0]) - eye
    z = q @ forward
    points = [q[z >= near]]
    for a, b in EDGES:
        if (z[a] - near) * (z[b] - near) < 0.0:
            points.append((q[a] + (near - z[a]) / (z[b] - z[a]) * (q[b] - q[a]))[None, :])
    p = np.concatenate(points)
    if len(p) < 3:
        return 0.0
    uv = focal * np.stack([p @ right, p @ up], axis=1) / (p @ forward)[:, None]
    if np.ptp(uv[:, 0]) < 1e-9 or np.ptp(uv[:, 1]) < 1e-9:
        return 0.0
    return _clip_area(uv[ConvexHull(uv).vertices], 0.5 * resolution)


def drawn_rows(name: str, views: int, res: int, rng) -> None:
    from farfield.core.render.raster import Camera, MeshRenderer

    fov, near = math.radians(45.0), 0.05
    focal, frame, half = 0.5 * res / math.tan(0.5 * fov), float(res) ** 2, frame_half_diagonal(fov)
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
            hint = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.99 else np.array([0.0, 1.0, 0.0])  # as Camera.look_at
            right = np.cross(d, hint)
            right /= np.linalg.norm(right)
            up = np.cross(right, d)
            v = centre - eye
            dist = np.maximum(np.linalg.norm(v, axis=1), 1e-12)
            angle = np.arccos(np.clip(v @ d / dist, -1.0, 1.0))
            seen = np.flatnonzero((dist <= radius) | (angle - np.arcsin(np.minimum(1.0, radius / dist)) <= half))
            estimate = float(element_pixels(elements, eye, eye, fov, res, seen).sum()) if seen.size else 0.0
            clipped = sum(projected_pixels(elements.bounds[e], eye, d, right, up, focal, res, near) for e in seen)
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
