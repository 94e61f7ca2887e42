"""Evaluation of an impostor against the real geometry: per-viewpoint pixel counts and colour errors.

From sampled viewpoints (the view cell's corners, the reference viewpoint and seeded random points
inside; optionally points outside) the part's geometry and the impostor are rendered by the same
renderer at the impostor's output resolution and field of view, looking at the part's centre.
Coverage is measured as area: both are rendered with ``samples x samples`` samples per pixel and
a pixel counts as covered when any of its samples is (with one sample per pixel, sub-pixel detail
such as a trunk thinner than a pixel drops in and out of both renders by aliasing alone; the
one-sample hole count is reported too, as ``hole_pixels_1spp``).  Colours are the mean of a
pixel's covered samples.

hole pixels
    covered by the geometry with no impostor coverage within one pixel (the guarantee: zero inside
    the view cell);
bloat pixels
    covered by the impostor only (``bloat_beyond_1px``: farther than one pixel from any geometry);
colour error
    where both cover, the smallest difference (max over RGB, 0..255) between the geometry's pixel
    and the impostor's pixels within one pixel (the one-pixel parallax tolerance).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from farfield.core.impostor import Impostor, MeshPayload, QuadPayload
from farfield.core.render.raster import Camera, MeshRenderer, depth_bounds
from farfield.core.scene import Scene, SceneObject
from farfield.core.viewcells import BoxCell, ShaftCell, ViewCell, box_corners


def impostor_objects(impostor: Impostor) -> list[SceneObject]:
    """The impostor as drawable objects, alpha-cut at 0.5: one per atlas page with geometry.

    A quad payload gives two triangles per quad; a mesh payload its triangles, with the vertices
    they use.  Either way a page's triangles are drawn in payload order.
    """
    payload = impostor.payload
    objects = []
    for page_index, page in enumerate(impostor.pages):
        sel = np.flatnonzero(payload.page == page_index)
        if sel.size == 0:
            continue
        if isinstance(payload, QuadPayload):
            vertices = payload.corners[sel].reshape(-1, 3)
            uv = payload.uv[sel].reshape(-1, 2).copy()
            base = 4 * np.arange(sel.size, dtype=np.int64)[:, None]
            faces = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]], axis=0)
        elif isinstance(payload, MeshPayload):
            used, faces = np.unique(payload.triangles[sel], return_inverse=True)
            faces = faces.reshape(-1, 3)
            vertices = payload.vertices[used]
            uv = payload.uv[used].copy()
        else:
            raise TypeError(f"no renderer for a {payload.kind!r} payload")
        uv[:, 1] = 1.0 - uv[:, 1]  # glTF (top-left origin) -> scene convention (bottom-left)
        objects.append(SceneObject(name=f"page{page_index}", vertices=vertices, faces=faces, uv=uv, texture=page, alpha_cutoff=0.5))
    return objects


def _dilate(mask: np.ndarray) -> np.ndarray:
    """(h, w) bool grown by one pixel in all eight directions."""
    out = mask.copy()
    out[1:] |= mask[:-1]
    out[:-1] |= mask[1:]
    grown = out.copy()
    grown[:, 1:] |= out[:, :-1]
    grown[:, :-1] |= out[:, 1:]
    return grown


def downsample(image: np.ndarray, samples: int) -> np.ndarray:
    """(h, w, 4) uint8 pixels of an (h*s, w*s, 4) render: alpha 255 if any sample is covered, RGB
    the mean of the covered samples."""
    if samples == 1:
        return image
    h, w = image.shape[0] // samples, image.shape[1] // samples
    blocks = image.reshape(h, samples, w, samples, 4).astype(np.float64)
    covered = blocks[..., 3:4] > 0
    count = covered.sum(axis=(1, 3))
    rgb = (blocks[..., :3] * covered).sum(axis=(1, 3)) / np.maximum(count, 1)
    out = np.zeros((h, w, 4), dtype=np.uint8)
    out[..., :3] = np.round(rgb).astype(np.uint8)
    out[..., 3] = np.where(count[..., 0] > 0, 255, 0)
    return out


def _holes(g: np.ndarray, i: np.ndarray) -> np.ndarray:
    """(h, w) bool: covered by the geometry with no impostor coverage within one pixel."""
    return g & ~_dilate(i)


def compare_images(geometry: np.ndarray, impostor: np.ndarray, samples: int = 1) -> dict:
    """Pixel statistics of two (h*s, w*s, 4) uint8 renders (geometry first) with ``samples`` s per
    pixel side; see the module docstring."""
    one = _holes(geometry[samples // 2 :: samples, samples // 2 :: samples, 3] > 0, impostor[samples // 2 :: samples, samples // 2 :: samples, 3] > 0)
    geometry, impostor = downsample(geometry, samples), downsample(impostor, samples)
    g = geometry[..., 3] > 0
    i = impostor[..., 3] > 0
    holes = _holes(g, i)
    bloat = i & ~g
    both = g & i
    gi = geometry[..., :3].astype(np.int16)
    best = np.full(g.shape, 255, dtype=np.int16)
    h, w = g.shape
    padded = np.pad(impostor, ((1, 1), (1, 1), (0, 0)))
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            neighbour = padded[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w]
            diff = np.abs(gi - neighbour[..., :3].astype(np.int16)).max(axis=2)
            diff = np.where(neighbour[..., 3] > 0, diff, 255)
            best = np.minimum(best, diff)
    errors = best[both]
    return {
        "geometry_pixels": int(g.sum()),
        "impostor_pixels": int(i.sum()),
        "hole_pixels": int(holes.sum()),
        "hole_pixels_1spp": int(one.sum()),
        "bloat_pixels": int(bloat.sum()),
        "bloat_beyond_1px": int((i & ~_dilate(g)).sum()),
        "colour_error_mean": float(errors.mean()) if errors.size else 0.0,
        "colour_error_p95": float(np.percentile(errors, 95)) if errors.size else 0.0,
        "colour_error_max": int(errors.max()) if errors.size else 0,
    }


def outside_viewpoints(cell: ViewCell, count: int, seed: int = 0) -> np.ndarray:
    """(count, 3) float64 points just outside ``cell``: its centre pushed 0.6-1.5 cell sizes sideways."""
    rng = np.random.default_rng(seed)
    if isinstance(cell, BoxCell):
        centre, size = cell.center, float(np.max(cell.size))
    else:
        centre, size = cell.center, 2.0 * cell.half_width(cell.min_distance)
    direction = rng.normal(size=(count, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    points = centre + direction * size * rng.uniform(0.9, 1.5, size=(count, 1))
    return points[~cell.contains(points)]


@dataclass(frozen=True, slots=True)
class Evaluation:
    """Per-viewpoint results and totals of one evaluation."""

    viewpoints: list[dict]  # each: position, kind ("corner" | "reference" | "random" | "outside"), inside, stats
    totals: dict  # inside the view cell: sums and maxima; outside: the same under "outside"
    impostor: dict = field(default_factory=dict)  # layers, quads, memory, generation seconds
    seconds: float = 0.0

    def to_dict(self) -> dict:
        return {"viewpoints": self.viewpoints, "totals": self.totals, "impostor": self.impostor, "seconds": self.seconds}


def _totals(rows: list[dict]) -> dict:
    if not rows:
        return {}
    stats = [r["stats"] for r in rows]
    return {
        "viewpoints": len(rows),
        "hole_pixels": sum(s["hole_pixels"] for s in stats),
        "max_hole_pixels": max(s["hole_pixels"] for s in stats),
        "hole_pixels_1spp": sum(s["hole_pixels_1spp"] for s in stats),
        "bloat_pixels": sum(s["bloat_pixels"] for s in stats),
        "bloat_beyond_1px": sum(s["bloat_beyond_1px"] for s in stats),
        "geometry_pixels": sum(s["geometry_pixels"] for s in stats),
        "colour_error_mean": float(np.mean([s["colour_error_mean"] for s in stats])),
        "colour_error_max": max(s["colour_error_max"] for s in stats),
    }


def evaluate(
    part: Scene,
    impostor: Impostor,
    cell: ViewCell,
    random_count: int = 8,
    outside_count: int = 0,
    seed: int = 0,
    depth: float | None = None,
    samples: int = 4,
) -> Evaluation:
    """Render ``part`` and ``impostor`` from viewpoints of ``cell`` and compare them.

    ``depth`` bounds the sampling of an unbounded shaft; ``samples`` per pixel side measure coverage.
    """
    start = time.perf_counter()
    points, kinds = [cell.corners()], ["corner"] * len(cell.corners())
    points.append(np.asarray(impostor.reference_viewpoint)[None, :])
    kinds.append("reference")
    if random_count:
        random = cell.sample_random(random_count, seed, depth) if isinstance(cell, ShaftCell) else cell.sample_random(random_count, seed)
        points.append(random)
        kinds += ["random"] * random_count
    if outside_count:
        out = outside_viewpoints(cell, outside_count, seed)
        points.append(out)
        kinds += ["outside"] * len(out)
    points = np.concatenate(points)
    target = 0.5 * (part.bounds[0] + part.bounds[1])
    extent = np.concatenate([box_corners(part.bounds), impostor.payload.world_points()])
    fov = math.radians(impostor.fov_deg)
    rows = []
    with MeshRenderer(part.objects) as geometry, MeshRenderer(impostor_objects(impostor)) as stand_in:
        for position, kind in zip(points, kinds):
            forward = (target - position) / np.linalg.norm(target - position)
            near, far = depth_bounds(position, forward, extent)
            camera = Camera.look_at(position, target, fov, impostor.resolution * samples, near, far)
            stats = compare_images(geometry.render(camera), stand_in.render(camera), samples)
            rows.append({"position": position.tolist(), "kind": kind, "inside": kind != "outside", "stats": stats})
    totals = _totals([r for r in rows if r["inside"]])
    outside = _totals([r for r in rows if not r["inside"]])
    if outside:
        totals["outside"] = outside
    summary = {k: impostor.stats.get(k) for k in ("layers", "quads", "texture_bytes", "geometry_bytes", "seconds")}
    return Evaluation(rows, totals, summary, time.perf_counter() - start)
