"""The points of a point-based impostor: the three LDIs' samples, less the redundant ones.

Seed 001 §4.2 and §5.1.  Every surface hit along every ray of the three LDI cameras of
:mod:`core.point_sampling` is a candidate point (:func:`core.ldi.record_ldi`: all depth layers,
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
  :func:`core.point_sampling.corner_perspective_factor`);
- ``s`` is **redundant** when another camera's sample at the same place (``s`` projected into that
  LDI's pixel, the layer within the continuity tolerance of ``s``'s depth there) has a sufficient
  spacing smaller than ``s``'s (ties: the lower camera index keeps its point);
- a sample of a pixel its surface only touches (the conservative LDI's extra samples, for
  geometry thinner than a pixel) is always kept and never stands for another.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from farfield.core.ldi import LayeredDepthImage, record_ldi
from farfield.core.point_sampling import PointSampling, corner_perspective_factor
from farfield.core.scene import SceneObject
from farfield.core.viewcells import BoxCell

# A neighbouring pixel's sample is on the same surface when their depths differ by at most this
# many times the lateral distance between the two rays (tan 76° ≈ 4).
CONTINUITY = 4.0

_NEIGHBOURS = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))


def _shifted(array: np.ndarray, dr: int, dc: int, fill) -> np.ndarray:
    """``array`` (..., h, w) moved so that [..., r, c] holds the value at [..., r + dr, c + dc]."""
    out = np.full_like(array, fill)
    h, w = array.shape[-2:]
    rs, re = max(0, -dr), min(h, h - dr)
    cs, ce = max(0, -dc), min(w, w - dc)
    out[..., rs:re, cs:ce] = array[..., rs + dr : re + dr, cs + dc : ce + dc]
    return out


def ldi_spacing(ldi: LayeredDepthImage, cell: BoxCell) -> np.ndarray:
    """(layers, h, w) float64: the longest edge from each sample to its 8 same-surface neighbours
    as the view cell can see it (module docstring), inf where a neighbour is missing, NaN where
    there is no sample.

    An edge e at p seen from a viewpoint y shows its component across the ray, |e| sin ∠(e, p - y).
    The directions from the cell to p lie within γ = asin(r / |p - c|) of the direction from the
    cell's centre c (r the cell's half diagonal), so that component is at most
    |e| min(1, sin(θ + γ)), θ the angle between e and p - c folded into [0, π/2]: a surface seen
    edge-on from the whole cell needs no dense sampling along its depth."""
    depth = ldi.depth
    centre = cell.center
    radius = 0.5 * float(np.linalg.norm(cell.size))
    positions = ldi.sample_positions()  # (L, h, w, 3)
    pixel = 2.0 * math.tan(0.5 * ldi.camera.fov) / ldi.camera.resolution  # image tangents per pixel
    spacing = np.zeros(depth.shape)
    for dr, dc in _NEIGHBOURS:
        other = _shifted(depth, dr, dc, np.nan)  # (L, h, w): the neighbour pixel's layers
        other = np.where(np.isnan(other), np.inf, other)
        other_pos = _shifted(np.moveaxis(positions, -1, 0), dr, dc, np.nan)  # (3, L, h, w)
        step = pixel * math.hypot(dr, dc)
        for layer in range(depth.shape[0]):  # one layer at a time: (L, h, w), not (L, L, h, w)
            gap = np.abs(other - depth[layer])
            nearest = np.argmin(gap, axis=0)  # (h, w)
            best = np.take_along_axis(gap, nearest[None], axis=0)[0]
            same = best <= CONTINUITY * depth[layer] * step
            q = np.take_along_axis(other_pos, np.broadcast_to(nearest[None, None], (3, 1) + nearest.shape), axis=1)[:, 0]  # (3, h, w)
            e = np.moveaxis(q, 0, -1) - positions[layer]
            length = np.linalg.norm(e, axis=-1)
            seen = positions[layer] - centre
            distance = np.linalg.norm(seen, axis=-1)
            with np.errstate(invalid="ignore", divide="ignore"):
                cos_theta = np.abs(np.einsum("...i,...i->...", e, seen)) / (length * distance)
                gamma = np.arcsin(np.clip(radius / distance, 0.0, 1.0))
            theta = np.arccos(np.clip(cos_theta, 0.0, 1.0))
            across = length * np.minimum(1.0, np.sin(np.minimum(theta + gamma, 0.5 * math.pi)))
            spacing[layer] = np.maximum(spacing[layer], np.where(same, across, np.inf))
    if ldi.touched is not None:  # off their rays: no pattern to judge by, and kept (module docstring)
        spacing = np.where(ldi.touched, np.inf, spacing)
    return np.where(np.isfinite(depth), spacing, np.nan)


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
            "per_camera": [{"candidates": int((self.camera == k).sum()), "kept": int((self.kept & (self.camera == k)).sum()), "layers": ldi.layers} for k, ldi in enumerate(self.ldis)],
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


def gather_point_samples(objects: list[SceneObject] | tuple[SceneObject, ...], sampling: PointSampling, cell: BoxCell,
                         fov_deg: float, resolution: int, max_layers: int = 256) -> PointSamples:
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
    return PointSamples(np.concatenate([p[1] for p in parts]), ldi_of, index, obj, triangle, spacing, sufficient, np.concatenate(kept_parts), colour, ldis)
