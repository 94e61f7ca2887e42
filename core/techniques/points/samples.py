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
  LDI's pixel, the layer within the continuity tolerance of ``s``'s depth there) has a finite
  spacing smaller than ``s``'s (ties: the lower camera index keeps its point); with
  ``sufficient_only``, only when that spacing is also sufficient, as §5.1 words it.  Where no
  camera is sufficient (folds finer than an LDI pixel, as a scan's noise makes them) the rule as
  written keeps all three cameras' samples, about 1.3 times the points, and they are no more
  sufficient together (issue 60: the points kept either way leave no hole pixel on a
  327,680-triangle rough sphere from 17 views of the cell; docs/measurements/points.md);
- a sample of a pixel its surface only touches (the conservative LDI's extra samples, for
  geometry thinner than a pixel) is always kept and never stands for another.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numba
import numpy as np

from farfield.core.ldi.image import LayeredDepthImage, record_ldi
from farfield.core.render.raster import Camera
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


# LDIs are recorded in square tiles of at most this many pixels a side (plus a one-pixel border
# for the neighbourhood of the spacing), so a bake holds one tile's (layers, h, w) arrays at a time:
# each tile peels only the layers its own pixels have, and only its samples are kept, compactly.
TILE = 256
TILE_MARGIN = 2  # pixels beyond a tile (and its border) whose triangles it draws: conservative touches


@dataclass(frozen=True, slots=True)
class SampleLookup:
    """One LDI's samples by pixel, for the redundancy test without the LDI's (layers, h, w) arrays:
    ``start`` (h w + 1,) int64 offsets of each pixel's samples (row-major) into ``depth`` and
    ``spacing`` (m,) float64, nearest layer first within a pixel."""

    camera: Camera
    start: np.ndarray
    depth: np.ndarray
    spacing: np.ndarray

    @classmethod
    def of(cls, camera: Camera, pixel: np.ndarray, depth: np.ndarray, spacing: np.ndarray) -> SampleLookup:
        """From samples' flat pixel index (row * n + column) ``pixel``, ``depth`` and ``spacing``
        (m,), in layer order within each pixel."""
        order = np.argsort(pixel, kind="stable")
        counts = np.bincount(pixel, minlength=camera.resolution**2)
        start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        return cls(camera, start, np.ascontiguousarray(depth[order]), np.ascontiguousarray(spacing[order]))

    def spacing_at(self, points: np.ndarray) -> np.ndarray:
        """(m,) float64 the spacing of this LDI's sample at each of ``points`` (m, 3): in the pixel
        the point projects to, the sample whose depth is nearest the point's depth along this
        camera, if within the continuity tolerance of it; inf when there is none."""
        camera = self.camera
        n = camera.resolution
        pixels = camera.project(points)
        column, row = np.floor(pixels[:, 0]).astype(np.int64), np.floor(pixels[:, 1]).astype(np.int64)
        z = (points - camera.eye) @ camera.forward
        inside = (column >= 0) & (column < n) & (row >= 0) & (row < n) & (z > 0.0)
        flat = np.where(inside, row * n + column, -1)
        tolerance = CONTINUITY * z * 2.0 * math.tan(0.5 * camera.fov) / n * math.sqrt(2.0)
        return _lookup_kernel(self.start, self.depth, self.spacing, flat, z, tolerance)


@numba.njit(cache=True, nogil=True)
def _lookup_kernel(start, depth, spacing, pixel, z, tolerance):  # pragma: no cover - compiled
    out = np.full(pixel.size, np.inf)
    for i in range(pixel.size):
        p = pixel[i]
        if p < 0:
            continue
        best, value = np.inf, np.inf
        for m in range(start[p], start[p + 1]):
            g = abs(depth[m] - z[i])
            if g < best:  # the first nearest, as numpy's argmin over layers
                best, value = g, spacing[m]
        if best <= tolerance[i]:
            out[i] = value
    return out


def _lookup(ldi: LayeredDepthImage, spacing: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(m,) float64 the spacing of ``ldi``'s sample at each of ``points`` (m, 3)
    (:meth:`SampleLookup.spacing_at`), from a whole LDI and its (layers, h, w) ``spacing``."""
    index = np.argwhere(np.isfinite(ldi.depth))
    n = ldi.camera.resolution
    at = (index[:, 0], index[:, 1], index[:, 2])
    return SampleLookup.of(ldi.camera, index[:, 1] * n + index[:, 2], ldi.depth[at], spacing[at]).spacing_at(points)


@dataclass(frozen=True, slots=True)
class CameraSamples:
    """The samples of one LDI camera, recorded tile by tile (:data:`TILE`): per sample ``positions``
    (m, 3) float64 world, ``index`` (m, 3) int64 (layer within its tile, row, column), ``obj``,
    ``triangle`` (m,) int64, ``spacing`` (m,) float64, ``touched`` (m,) bool, ``colour`` (m, 4)
    uint8; ``layers`` the most layers of any tile; ``lookup`` the samples by pixel."""

    positions: np.ndarray
    index: np.ndarray
    obj: np.ndarray
    triangle: np.ndarray
    spacing: np.ndarray
    touched: np.ndarray
    colour: np.ndarray
    layers: int
    lookup: SampleLookup


def record_camera_samples(
    objects: list[SceneObject] | tuple[SceneObject, ...],
    camera: Camera,
    cell: BoxCell,
    max_layers: int = 256,
    tile: int = TILE,
) -> CameraSamples:
    """The conservative LDI of ``camera`` and its samples' spacing (:func:`ldi_spacing`), recorded
    in square tiles of ``tile`` pixels with a one-pixel border (:meth:`Camera.window
    <farfield.core.render.raster.Camera.window>` divides the image into the same pixels, so each
    interior pixel sees its 8 neighbours as in the whole LDI); only the samples are kept."""
    n = camera.resolution
    parts: dict[str, list] = {
        k: [] for k in ("positions", "index", "obj", "triangle", "spacing", "touched", "colour", "depth")
    }
    layers = 0
    boxes = [_face_pixel_boxes(o, camera) for o in objects] if n > tile else None
    for y0 in range(0, n, tile):
        for x0 in range(0, n, tile):
            w, h = min(tile, n - x0), min(tile, n - y0)
            side = max(w, h) + 2
            window = (
                x0 - 1 - TILE_MARGIN,
                y0 - 1 - TILE_MARGIN,
                x0 - 1 + side + TILE_MARGIN,
                y0 - 1 + side + TILE_MARGIN,
            )
            tile_objects, object_of, face_of = _tile_objects(objects, boxes, window)
            if not tile_objects:
                continue
            ldi = record_ldi(tile_objects, camera.window(x0 - 1, y0 - 1, side, side), max_layers, conservative=True)
            layers = max(layers, ldi.layers)
            if ldi.layers == 0:
                continue
            spacing = ldi_spacing(ldi, cell)
            interior = np.zeros(ldi.depth.shape, dtype=bool)
            interior[:, 1 : h + 1, 1 : w + 1] = True
            index = np.argwhere(np.isfinite(ldi.depth) & interior)
            at = (index[:, 0], index[:, 1], index[:, 2])
            parts["positions"].append(ldi.sample_positions()[at])
            parts["index"].append(index + np.array([0, y0 - 1, x0 - 1]))
            obj, tri = ldi.obj[at], ldi.triangle[at].copy()
            for k, faces in enumerate(face_of):  # tile faces back to the object's own
                tri[obj == k] = faces[tri[obj == k]]
            parts["obj"].append(object_of[obj])
            parts["triangle"].append(tri)
            parts["spacing"].append(spacing[at])
            parts["touched"].append(ldi.touched[at])
            parts["colour"].append(ldi.colour[at])
            parts["depth"].append(ldi.depth[at])
            del ldi, spacing, interior
    empty = {"positions": (0, 3), "index": (0, 3), "colour": (0, 4)}
    dtypes = {"positions": np.float64, "index": np.int64, "obj": np.int64, "triangle": np.int64, "spacing": np.float64,
              "touched": np.bool_, "colour": np.uint8, "depth": np.float64}  # fmt: skip
    joined = {k: np.concatenate(v) if v else np.zeros(empty.get(k, (0,)), dtype=dtypes[k]) for k, v in parts.items()}
    index = joined["index"]
    lookup = SampleLookup.of(camera, index[:, 1] * n + index[:, 2], joined.pop("depth"), joined["spacing"])
    return CameraSamples(**joined, layers=layers, lookup=lookup)


def _face_pixel_boxes(obj: SceneObject, camera: Camera) -> np.ndarray:
    """(f, 4) float64 each face's pixel bounding box (x lo, y lo, x hi, y hi) in ``camera``'s image;
    a face with a corner at or behind the eye's plane spans every pixel."""
    z = (obj.vertices - camera.eye) @ camera.forward
    pixels = camera.project(obj.vertices)
    corners = pixels[obj.faces]  # (f, 3, 2)
    boxes = np.concatenate([corners.min(axis=1), corners.max(axis=1)], axis=1)
    behind = np.any(z[obj.faces] <= 0.0, axis=1) | ~np.all(np.isfinite(boxes), axis=1)
    boxes[behind] = (-np.inf, -np.inf, np.inf, np.inf)
    return boxes


def _tile_objects(objects, boxes, window) -> tuple[list[SceneObject], np.ndarray, list[np.ndarray]]:
    """(the objects with only their faces whose pixel box meets ``window`` (x lo, y lo, x hi, y hi),
    each tile object's index among ``objects``, each tile object's face indices in its object);
    ``boxes`` None: all of them, unchanged (and an empty face map)."""
    if boxes is None:
        return list(objects), np.arange(len(objects), dtype=np.int64), []
    x0, y0, x1, y1 = window
    out, object_of, face_of = [], [], []
    for k, (obj, box) in enumerate(zip(objects, boxes)):
        faces = np.flatnonzero((box[:, 2] >= x0) & (box[:, 0] <= x1) & (box[:, 3] >= y0) & (box[:, 1] <= y1))
        if faces.size == 0:
            continue
        out.append(obj if faces.size == obj.faces.shape[0] else replace(obj, faces=obj.faces[faces]))
        object_of.append(k)
        face_of.append(faces)
    return out, np.asarray(object_of, dtype=np.int64), face_of


@dataclass(frozen=True, slots=True)
class PointSamples:
    """The candidate points of the three LDIs and which are kept.

    ``positions`` (n, 3) float64 world; ``camera`` (n,) int64 LDI index; ``index`` (n, 3) int64
    (layer within its tile, row, column) in that LDI; ``obj``, ``triangle`` (n,) int64 the surface hit; ``spacing``
    (n,) float64 (module docstring; inf at a discontinuity); ``sufficient`` (n,) bool; ``kept`` (n,)
    bool: not redundant; ``colour`` (n, 4) uint8 sRGB: the surface's colour at the sample, as the
    mesh shader draws it (seed 001 §5.3's one-colour preview, before §5.2's appearance);
    ``layers`` the most depth layers of each LDI (of any of its tiles)."""

    positions: np.ndarray
    camera: np.ndarray
    index: np.ndarray
    obj: np.ndarray
    triangle: np.ndarray
    spacing: np.ndarray
    sufficient: np.ndarray
    kept: np.ndarray
    colour: np.ndarray
    layers: tuple[int, ...]

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
                    "layers": layers,
                }
                for k, layers in enumerate(self.layers)
            ],
        }


def gather_point_samples(
    objects: list[SceneObject] | tuple[SceneObject, ...],
    sampling: PointSampling,
    cell: BoxCell,
    fov_deg: float,
    resolution: int,
    max_layers: int = 256,
    tile: int = TILE,
    sufficient_only: bool = False,
) -> PointSamples:
    """Record the three LDIs of ``sampling`` (in tiles of ``tile`` pixels) and mark the redundant
    samples (module docstring; ``sufficient_only``: seed 001 §5.1's rule as written, only where
    the better camera also samples sufficiently); ``fov_deg`` and ``resolution`` are the output
    camera's, as planned."""  # fmt: skip
    fov = math.radians(float(fov_deg))
    beta = 2.0 * math.tan(0.5 * fov) / int(resolution) / corner_perspective_factor(fov)  # smallest pixel angle
    cameras = [record_camera_samples(objects, camera.camera(), cell, max_layers, tile) for camera in sampling.cameras]
    kept_parts = []
    for k, mine in enumerate(cameras):
        s = mine.spacing
        nearest = np.linalg.norm(mine.positions - np.clip(mine.positions, cell.lo, cell.hi), axis=1)  # to the cell
        allowed = beta * nearest
        redundant = np.zeros(s.shape[0], dtype=bool)
        for j, other_camera in enumerate(cameras):
            if j == k:
                continue
            other = other_camera.lookup.spacing_at(mine.positions)
            better = (other < s) | ((other == s) & (j < k))
            redundant |= ((other <= allowed) if sufficient_only else np.isfinite(other)) & better
        redundant &= ~mine.touched  # a touched-pixel sample stays (module docstring)
        kept_parts.append((~redundant, s <= allowed))
    return PointSamples(
        np.concatenate([c.positions for c in cameras]),
        np.concatenate([np.full(c.spacing.shape[0], k, dtype=np.int64) for k, c in enumerate(cameras)]),
        np.concatenate([c.index for c in cameras]),
        np.concatenate([c.obj for c in cameras]),
        np.concatenate([c.triangle for c in cameras]),
        np.concatenate([c.spacing for c in cameras]),
        np.concatenate([p[1] for p in kept_parts]),
        np.concatenate([p[0] for p in kept_parts]),
        np.concatenate([c.colour for c in cameras]),
        tuple(c.layers for c in cameras),
    )
