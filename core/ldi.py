"""Layered depth images: every surface a camera's pixel rays meet, as world-space samples.

An LDI (seed 001 §4.2 and §5.1 take three of them for a point-based impostor; seed 004 §4 builds
one from nine construction images) keeps, for each pixel of a perspective camera, all the surfaces
its centre ray crosses, nearest first, not only the visible one.  :func:`record_ldi` peels them on
the GL (:mod:`core.render.peeling`); a sample is the ray's point at the recorded eye depth, with the
object and triangle it lies on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from farfield.core.render.peeling import peel
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
        rays = self.directions()[index[:, 1], index[:, 2]]
        depth = self.depth[index[:, 0], index[:, 1], index[:, 2]]
        return self.camera.eye + depth[:, None] * rays, index


def record_ldi(objects: list[SceneObject] | tuple[SceneObject, ...], camera: Camera, max_layers: int = 256) -> LayeredDepthImage:
    """The layered depth image of ``objects`` from ``camera`` (see :mod:`core.render.peeling` for the
    rules: back faces count, alpha-cut texels do not; give a tight depth range)."""
    hits = peel(objects, camera, max_layers)
    return LayeredDepthImage(camera, hits[..., 0], hits[..., 1].astype(np.int64), hits[..., 2].astype(np.int64))
