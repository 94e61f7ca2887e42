"""The points of a point-based impostor: the three LDIs' samples, less the redundant ones.

Seed 001 §4.2 and §5.1.  Every surface hit along every ray of the three LDI cameras of
:mod:`farfield.core.techniques.points.sampling` is a candidate point (:func:`farfield.core.ldi.image.record_ldi`: all depth layers,
back faces kept, alpha-cut texels skipped; conservative, so geometry thinner than an LDI pixel
leaves a sample in every pixel it touches).  Three cameras sample most surfaces two or three times,
so §5.1 removes a point "if [it] lies in a region which is sampled better and sufficiently by
another camera", where a camera samples a region sufficiently when "a triangulation of the
sampling pattern from this camera in a small neighbourhood contains no edge which projects to more
than a pixel in any view".  Here, for a sample ``s`` of one LDI:

- its **neighbourhood** is the samples of the 8 neighbouring pixels that lie on the same surface:
  the one whose depth is nearest ``s``'s, if within :data:`CONTINUITY` times the lateral distance
  between the two rays at that depth (a surface at most ~76° from facing the camera); a missing
  neighbour is a depth discontinuity or a surface border;
- its **spacing** is the longest edge to those 8 neighbours (diagonals included, the pixel
  diagonal of §5.1's "sampling pattern orientation") as seen across the rays from the view cell
  (:func:`ldi_spacing`), infinite when a neighbour is missing: a point is never judged redundant
  by a pattern that crosses a discontinuity;
- the spacing is **sufficient** when, seen from the point of the view cell nearest ``s``, it spans
  at most the smallest angle of an output pixel (the radial angle of a corner pixel,
  :func:`farfield.core.techniques.points.sampling.corner_perspective_factor`);
- ``s`` is **redundant** when another camera's sample at the same place (``s`` projected into that
  LDI's pixel, the layer within the continuity tolerance of ``s``'s depth there) has a sufficient
  spacing smaller than ``s``'s (ties: the lower camera index keeps its point);
- a sample of a pixel its surface only touches (the conservative LDI's extra samples, for
  geometry thinner than a pixel) is always kept and never stands for another.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np

from farfield.core.ldi.image import LayeredDepthImage, record_ldi
from farfield.core.scene import SceneObject
from farfield.core.techniques.points.sampling import PointSampling, corner_perspective_factor
from farfield.core.viewcells import BoxCell

# A neighbouring pixel's sample is on the same surface when their depths differ by at most this
# many times the lateral distance between the two rays (tan 76° ≈ 4).
CONTINUITY = 4.0


def ldi_spacing(ldi: LayeredDepthImage, cell: BoxCell) -> np.ndarray:
    """(layers, h, w) float64: the longest edge from each sample to its 8 same-surface neighbours
    as the view cell can see it (module docstring), inf where a neighbour is missing, NaN where
    there is no sample.

    An edge e at p seen from a viewpoint y shows its component across the ray, |e| sin ∠(e, p - y).
    The directions from the cell to p lie within γ = asin(r / |p - c|) of the direction from the
    cell's centre c (r the cell's half diagonal), so that component is at most
    |e| min(1, sin(θ + γ)), θ the angle between e and p - c folded into [0, π/2]: a surface seen
    edge-on from the whole cell needs no dense sampling along its depth.  (A numba kernel, one
    sample at a time; ``tests/test_point_samples.py`` holds the rule written with numpy arrays.)"""
    depth = np.ascontiguousarray(ldi.depth, dtype=np.float64)
    positions = np.ascontiguousarray(ldi.sample_positions(), dtype=np.float64)  # (L, h, w, 3)
    pixel = 2.0 * math.tan(0.5 * ldi.camera.fov) / ldi.camera.resolution  # image tangents per pixel
    touched = (
        np.zeros(depth.shape, dtype=np.bool_)
        if ldi.touched is None
        else np.ascontiguousarray(ldi.touched, dtype=np.bool_)
    )
    return _spacing_kernel(
        depth,
        positions,
        touched,
        np.asarray(cell.center, dtype=np.float64),
        0.5 * float(np.linalg.norm(cell.size)),
        pixel,
        CONTINUITY,
    )


@numba.njit(cache=True, nogil=True)
def _spacing_kernel(depth, positions, touched, centre, radius, pixel, continuity):  # pragma: no cover - compiled
    layers, h, w = depth.shape
    out = np.full(depth.shape, np.nan)
    half_pi = 0.5 * math.pi
    for layer in range(layers):
        for r in range(h):
            for c in range(w):
                d = depth[layer, r, c]
                if not np.isfinite(d):
                    continue
                if touched[layer, r, c]:  # off their rays: no pattern to judge by, and kept
                    out[layer, r, c] = np.inf
                    continue
                px, py, pz = positions[layer, r, c, 0], positions[layer, r, c, 1], positions[layer, r, c, 2]
                sx, sy, sz = px - centre[0], py - centre[1], pz - centre[2]
                distance = math.sqrt(sx * sx + sy * sy + sz * sz)
                gamma = math.asin(min(max(radius / distance, 0.0), 1.0)) if distance > 0.0 else half_pi
                spacing = 0.0
                for dr in range(-1, 2):
                    for dc in range(-1, 2):
                        if dr == 0 and dc == 0:
                            continue
                        rr, cc = r + dr, c + dc
                        best, nearest = np.inf, 0
                        if 0 <= rr < h and 0 <= cc < w:
                            for m in range(layers):
                                g = abs(depth[m, rr, cc] - d)
                                if g < best:  # NaN compares false: a missing layer is never nearest
                                    best, nearest = g, m
                        if not best <= continuity * d * pixel * math.sqrt(dr * dr + dc * dc):
                            across = np.inf  # a discontinuity or a border
                        else:
                            ex = positions[nearest, rr, cc, 0] - px
                            ey = positions[nearest, rr, cc, 1] - py
                            ez = positions[nearest, rr, cc, 2] - pz
                            length = math.sqrt(ex * ex + ey * ey + ez * ez)
                            cos_theta = (
                                abs(ex * sx + ey * sy + ez * sz) / (length * distance)
                                if length * distance > 0.0
                                else np.nan
                            )
                            theta = math.acos(min(max(cos_theta, 0.0), 1.0)) if cos_theta == cos_theta else np.nan
                            angle = theta + gamma
                            across = length * min(1.0, math.sin(min(angle, half_pi))) if angle == angle else np.nan
                        if across != across or spacing != spacing:
                            spacing = np.nan  # NaN stays, as numpy's maximum keeps it
                        elif across > spacing:
                            spacing = across
                out[layer, r, c] = spacing
    return out


@dataclass(frozen=True, slots=True)
class PointSamples:
    """The candidate points of the three LDIs and which are kept.

    ``positions`` (n, 3) float64 world; ``camera`` (n,) int64 LDI index; ``index`` (n, 3) int64
    (layer, row, column) in that LDI; ``obj``, ``triangle`` (n,) int64 the surface hit; ``spacing``
    (n,) float64 (module docstring; inf at a discontinuity); ``sufficient`` (n,) bool; ``kept`` (n,)
    bool: not redundant; ``colour`` (n, 4) uint8 sRGB: the surface's colour at the sample, as the
    mesh shader draws it (seed 001 §5.3's one-colour preview, before §5.2's appearance)."""

    positions: np.ndarray
    camera: np.ndarray
    index: np.ndarray
    obj: np.ndarray
    triangle: np.ndarray
    spacing: np.ndarray
    sufficient: np.ndarray
    kept: np.ndarray
    colour: np.ndarray
    ldis: tuple[LayeredDepthImage, ...] = field(repr=False)

    @property
    def stats(self) -> dict:
        n = int(self.positions.shape[0])
        kept = int(self.kept.sum())
        return {
            "candidates": n,
            "kept": kept,
            "removed_share": (n - kept) / n if n else 0.0,
            "sufficient_share": float(self.sufficient.mean()) if n else 0.0,
            "per_camera": [
                {
                    "candidates": int((self.camera == k).sum()),
                    "kept": int((self.kept & (self.camera == k)).sum()),
                    "layers": ldi.layers,
                }
                for k, ldi in enumerate(self.ldis)
            ],
        }


def _lookup(ldi: LayeredDepthImage, spacing: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(m,) float64 the spacing of ``ldi``'s sample at each of ``points`` (m, 3): in the pixel the
    point projects to, the layer whose depth is within the continuity tolerance of the point's
    depth along that camera (nearest one); inf when there is none."""
    camera = ldi.camera
    n = camera.resolution
    pixels = camera.project(points)
    column, row = np.floor(pixels[:, 0]).astype(np.int64), np.floor(pixels[:, 1]).astype(np.int64)
    z = (points - camera.eye) @ camera.forward
    inside = (column >= 0) & (column < n) & (row >= 0) & (row < n) & (z > 0.0)
    out = np.full(points.shape[0], np.inf)
    if not inside.any() or ldi.layers == 0:
        return out
    r, c, zi = row[inside], column[inside], z[inside]
    depths = ldi.depth[:, r, c]  # (L, m')
    gap = np.abs(depths - zi[None, :])
    gap = np.where(np.isnan(gap), np.inf, gap)
    layer = np.argmin(gap, axis=0)
    tolerance = CONTINUITY * zi * 2.0 * math.tan(0.5 * camera.fov) / n * math.sqrt(2.0)
    found = gap[layer, np.arange(layer.size)] <= tolerance
    values = spacing[layer, r, c]
    out[np.flatnonzero(inside)] = np.where(found, values, np.inf)
    return out


def gather_point_samples(
    objects: list[SceneObject] | tuple[SceneObject, ...],
    sampling: PointSampling,
    cell: BoxCell,
    fov_deg: float,
    resolution: int,
    max_layers: int = 256,
) -> PointSamples:
    """Record the three LDIs of ``sampling`` and mark the redundant samples (module docstring);
    ``fov_deg`` and ``resolution`` are the output camera's, as planned."""  # fmt: skip
    fov = math.radians(float(fov_deg))
    beta = 2.0 * math.tan(0.5 * fov) / int(resolution) / corner_perspective_factor(fov)  # smallest pixel angle
    ldis = tuple(record_ldi(objects, camera.camera(), max_layers, conservative=True) for camera in sampling.cameras)
    spacings = [ldi_spacing(ldi, cell) for ldi in ldis]
    parts = []
    for k, (ldi, spacing) in enumerate(zip(ldis, spacings)):
        positions, index = ldi.samples()
        s = spacing[index[:, 0], index[:, 1], index[:, 2]]
        nearest = np.linalg.norm(positions - np.clip(positions, cell.lo, cell.hi), axis=1)  # distance to the cell
        allowed = beta * nearest
        parts.append((k, positions, index, s, allowed))
    kept_parts = []
    for k, positions, index, s, allowed in parts:
        redundant = np.zeros(positions.shape[0], dtype=bool)
        for j, (ldi, spacing) in enumerate(zip(ldis, spacings)):
            if j == k:
                continue
            other = _lookup(ldi, spacing, positions)
            better = (other < s) | ((other == s) & (j < k))
            redundant |= (other <= allowed) & better
        touched = ldis[k].touched
        if touched is not None:  # a touched-pixel sample stays (module docstring)
            redundant &= ~touched[index[:, 0], index[:, 1], index[:, 2]]
        kept_parts.append(~redundant)
    ldi_of = np.concatenate([np.full(p[1].shape[0], p[0], dtype=np.int64) for p in parts])
    index = np.concatenate([p[2] for p in parts])
    obj = np.concatenate([ldis[k].obj[i[:, 0], i[:, 1], i[:, 2]] for k, _, i, _, _ in parts])
    triangle = np.concatenate([ldis[k].triangle[i[:, 0], i[:, 1], i[:, 2]] for k, _, i, _, _ in parts])
    spacing = np.concatenate([p[3] for p in parts])
    sufficient = np.concatenate([p[3] <= p[4] for p in parts])
    colour = np.concatenate([ldis[k].colour[i[:, 0], i[:, 1], i[:, 2]] for k, _, i, _, _ in parts])
    return PointSamples(
        np.concatenate([p[1] for p in parts]),
        ldi_of,
        index,
        obj,
        triangle,
        spacing,
        sufficient,
        np.concatenate(kept_parts),
        colour,
        ldis,
    )
