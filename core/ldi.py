"""Layered depth images: every surface a camera's pixel rays meet, as world-space samples.

An LDI (seed 001 §4.2 and §5.1 take three of them for a point-based impostor; seed 004 §4 builds
one from nine construction images) keeps, for each pixel of a perspective camera, all the surfaces
its centre ray crosses, nearest first, not only the visible one.  :func:`record_ldi` peels them on
the GL (:mod:`core.render.peeling`); a sample is the ray's point at the recorded eye depth, with the
object and triangle it lies on.

A *conservative* LDI also has a sample wherever a surface touches a pixel without covering its
centre and no centre sample of that pixel lies within :data:`SAME_SURFACE` pixel widths of it in
depth: geometry thinner than a pixel (a trunk, a wire, a needle) then leaves a sample in every
pixel it crosses.  Such a sample is the surface's point whose projection is nearest the pixel
centre, so it lies within the pixel's square but not always on its centre ray.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from farfield.core.render.peeling import peel

# A touched-pixel sample within this many pixel widths (at its depth) of another sample of the
# same pixel in depth belongs to the same surface and adds nothing.
SAME_SURFACE = 4.0
from farfield.core.render.raster import Camera
from farfield.core.scene import SceneObject


@dataclass(frozen=True, slots=True)
class LayeredDepthImage:
    """The surfaces along each pixel-centre ray of ``camera``: ``depth`` (layers, h, w) eye depth
    along the camera's forward axis (NaN past a ray's last surface), ``obj`` and ``triangle``
    (layers, h, w) int64 object index and face index (-1 there); rows top first."""

    camera: Camera
    depth: np.ndarray
    obj: np.ndarray
    triangle: np.ndarray
    positions: np.ndarray | None = None  # (layers, h, w, 3) world, where samples leave their centre ray
    touched: np.ndarray | None = None  # (layers, h, w) bool: a touched-pixel sample (conservative LDIs)
    colour: np.ndarray | None = None  # (layers, h, w, 4) uint8 sRGB: the surface's colour at the sample

    @property
    def layers(self) -> int:
        return int(self.depth.shape[0])

    @property
    def count(self) -> int:
        """Number of samples (surface hits) over all rays."""
        return int(np.count_nonzero(np.isfinite(self.depth)))

    def directions(self) -> np.ndarray:
        """(h, w, 3) float64 world vectors of the pixel-centre rays, scaled to eye depth 1
        (``eye + depth * direction`` is the sample)."""
        c = self.camera
        n = c.resolution
        t = math.tan(0.5 * c.fov)
        tangent = (2.0 * (np.arange(n) + 0.5) / n - 1.0) * t
        x = c.offset[0] + tangent[None, :]  # columns: left to right
        y = c.offset[1] - tangent[:, None]  # rows: top to bottom
        return x[..., None] * c.right + y[..., None] * c.up + c.forward

    def samples(self) -> tuple[np.ndarray, np.ndarray]:
        """((m, 3) float64 world positions, (m, 3) int64 (layer, row, column)) of every sample,
        ordered by layer, then row, then column."""
        index = np.argwhere(np.isfinite(self.depth))
        return self.sample_positions()[index[:, 0], index[:, 1], index[:, 2]], index

    def sample_positions(self) -> np.ndarray:
        """(layers, h, w, 3) float64 world position of every sample (NaN where none)."""
        if self.positions is not None:
            return self.positions
        return self.camera.eye + self.depth[..., None] * self.directions()[None]


def record_ldi(objects: list[SceneObject] | tuple[SceneObject, ...], camera: Camera, max_layers: int = 256,
               conservative: bool = False) -> LayeredDepthImage:
    """The layered depth image of ``objects`` from ``camera`` (see :mod:`core.render.peeling` for the
    rules: back faces count, alpha-cut texels do not; give a tight depth range); ``conservative``
    adds the samples of touched pixels (module docstring)."""  # fmt: skip
    hits, colours = peel(objects, camera, max_layers)
    if not conservative:
        return LayeredDepthImage(camera, hits[..., 0], hits[..., 1].astype(np.int64), hits[..., 2].astype(np.int64), colour=colours)
    pixel = 2.0 * math.tan(0.5 * camera.fov) / camera.resolution
    touched, touched_colours = peel(objects, camera, max_layers, touching=True, centre=hits[..., 0], same_surface=SAME_SURFACE * pixel)
    return _merge(camera, (hits, colours), (touched, touched_colours), objects)


def _merge(camera: Camera, centre: tuple, touched: tuple, objects) -> LayeredDepthImage:
    """Centre-ray hits plus the touched-pixel hits that are no other sample's surface, sorted by
    depth per pixel.  A touched sample's position is recomputed in float64 from its triangle: the
    point of the triangle nearest the pixel's centre ray."""
    (centre, centre_colours), (touched, touched_colours) = centre, touched
    n = camera.resolution
    pixel = 2.0 * math.tan(0.5 * camera.fov) / n
    plain = LayeredDepthImage(camera, centre[..., 0], centre[..., 1].astype(np.int64), centre[..., 2].astype(np.int64))
    positions = [plain.sample_positions()]
    depth, obj, tri, kind = [plain.depth], [plain.obj], [plain.triangle], [np.zeros(plain.depth.shape, dtype=bool)]
    shade = [centre_colours]
    kept_depth = plain.depth
    for layer, layer_colour in zip(touched, touched_colours):  # nearest first: kept if no kept sample is near it in depth
        d = layer[..., 0]
        tolerance = SAME_SURFACE * pixel * d
        if kept_depth.shape[0]:
            near = np.any(np.abs(kept_depth - d[None]) <= tolerance[None], axis=0)
        else:
            near = np.zeros(d.shape, dtype=bool)
        keep = np.isfinite(d) & ~near
        if not keep.any():
            continue
        d = np.where(keep, d, np.nan)
        o = np.where(keep, layer[..., 1], -1).astype(np.int64)
        t = np.where(keep, layer[..., 2], -1).astype(np.int64)
        depth.append(d[None])
        obj.append(o[None])
        tri.append(t[None])
        kind.append(keep[None])
        shade.append(np.where(keep[..., None], layer_colour, 0).astype(np.uint8)[None])
        positions.append(_touch_positions(camera, d, o, t, objects)[None])
        kept_depth = np.concatenate([kept_depth, d[None]])
    depth = np.concatenate(depth)
    positions = np.concatenate(positions)
    order = np.argsort(depth, axis=0, kind="stable")  # NaN last
    take = lambda a: np.take_along_axis(a, order, axis=0)  # noqa: E731
    depth, obj, tri, kind = take(depth), take(np.concatenate(obj)), take(np.concatenate(tri)), take(np.concatenate(kind))
    positions = np.take_along_axis(positions, order[..., None], axis=0)
    colour = np.take_along_axis(np.concatenate(shade), order[..., None], axis=0)
    filled = np.isfinite(depth).any(axis=(1, 2))
    return LayeredDepthImage(camera, depth[filled], obj[filled], tri[filled], positions[filled], kind[filled], colour[filled])


def _touch_positions(camera: Camera, depth: np.ndarray, obj: np.ndarray, tri: np.ndarray, objects) -> np.ndarray:
    """(h, w, 3) world points (NaN where ``depth`` is NaN) of touched-pixel samples: on triangle
    ``tri`` of object ``obj``, the point whose projection is nearest the pixel centre (the same rule
    as ``peel_touch.frag``, in float64)."""
    out = np.full(depth.shape + (3,), np.nan)
    rows, cols = np.nonzero(np.isfinite(depth))
    if rows.size == 0:
        return out
    n = camera.resolution
    t = math.tan(0.5 * camera.fov)
    centre = np.stack([camera.offset[0] + (2.0 * (cols + 0.5) / n - 1.0) * t, camera.offset[1] - (2.0 * (rows + 0.5) / n - 1.0) * t], axis=1)
    frame = np.stack([camera.right, camera.up, camera.forward])
    corners = np.empty((rows.size, 3, 3))
    for index in np.unique(obj[rows, cols]):
        sel = obj[rows, cols] == index
        o = objects[int(index)]
        corners[sel] = o.vertices[o.faces[tri[rows, cols][sel]]]
    eye = (corners - camera.eye) @ frame.T  # (m, 3 corners, 3) in the camera frame
    proj = eye[..., :2] / eye[..., 2:3] - np.asarray(camera.offset)  # image tangents, window-centred
    q = centre - np.asarray(camera.offset)
    best_w, best_d = np.zeros((rows.size, 3)), np.full(rows.size, np.inf)
    for i, j in ((0, 1), (1, 2), (2, 0)):  # nearest point on each projected edge
        a, b = proj[:, i], proj[:, j]
        d = b - a
        length2 = np.einsum("ij,ij->i", d, d)
        s = np.clip(np.einsum("ij,ij->i", q - a, d) / np.where(length2 > 0.0, length2, 1.0), 0.0, 1.0)
        point = a + s[:, None] * d
        dist = np.linalg.norm(point - q, axis=1)
        better = dist < best_d
        w = np.zeros((rows.size, 3))
        w[:, i], w[:, j] = 1.0 - s, s
        best_w[better], best_d[better] = w[better], dist[better]
    k = best_w / eye[..., 2]
    k /= k.sum(axis=1, keepdims=True)
    out[rows, cols] = np.einsum("mi,mij->mj", k, corners)
    return out
