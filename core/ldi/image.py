"""Layered depth images: every surface a camera's pixel rays meet, as world-space samples.

An LDI (seed 001 §4.2 and §5.1 take three of them for a point-based impostor; seed 004 §4 builds
one from nine construction images) keeps, for each pixel of a perspective camera, all the surfaces
its centre ray crosses, nearest first, not only the visible one.  :func:`record_ldi` peels them on
the GL (:mod:`farfield.core.render.peeling`); a sample is the ray's point at the recorded eye depth, with the
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

import numba
import numpy as np

from farfield.core.render.peeling import peel
from farfield.core.render.raster import Camera
from farfield.core.scene import SceneObject

# A touched-pixel sample within this many pixel widths (at its depth) of another sample of the
# same pixel in depth belongs to the same surface and adds nothing.
SAME_SURFACE = 4.0


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
    normal: np.ndarray | None = None  # (layers, h, w, 3) float64 unit world shading normal (0 where no sample)

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
        if self.positions is not None:
            return self.positions[index[:, 0], index[:, 1], index[:, 2]], index
        # sample_positions() at the samples alone: the same float64 operations, element by element
        depth = self.depth[index[:, 0], index[:, 1], index[:, 2]]
        return self.camera.eye + depth[:, None] * self.directions_at(index[:, 1], index[:, 2]), index

    def directions_at(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(m, 3) :meth:`directions` of the pixels (``rows``, ``cols``) alone, computed as it computes them."""
        c = self.camera
        n = c.resolution
        t = math.tan(0.5 * c.fov)
        x = c.offset[0] + (2.0 * (cols + 0.5) / n - 1.0) * t
        y = c.offset[1] - (2.0 * (rows + 0.5) / n - 1.0) * t
        return x[:, None] * c.right + y[:, None] * c.up + c.forward

    def sample_positions(self) -> np.ndarray:
        """(layers, h, w, 3) float64 world position of every sample (NaN where none)."""
        if self.positions is not None:
            return self.positions
        return self.camera.eye + self.depth[..., None] * self.directions()[None]


def record_ldi(
    objects: list[SceneObject] | tuple[SceneObject, ...],
    camera: Camera,
    max_layers: int = 256,
    conservative: bool = False,
) -> LayeredDepthImage:
    """The layered depth image of ``objects`` from ``camera`` (see :mod:`farfield.core.render.peeling` for the
    rules: back faces count, alpha-cut texels do not; give a tight depth range); ``conservative``
    adds the samples of touched pixels (module docstring)."""  # fmt: skip
    hits, colours = peel(objects, camera, max_layers)
    if not conservative:
        return LayeredDepthImage(
            camera, hits[..., 0], hits[..., 1].astype(np.int64), hits[..., 2].astype(np.int64), colour=colours
        )
    pixel = 2.0 * math.tan(0.5 * camera.fov) / camera.resolution
    touched, touched_colours = peel(
        objects, camera, max_layers, touching=True, centre=hits[..., 0], same_surface=SAME_SURFACE * pixel
    )
    return _merge(camera, (hits, colours), (touched, touched_colours), objects)


def _merge(camera: Camera, centre: tuple, touched: tuple, objects) -> LayeredDepthImage:
    """Centre-ray hits plus the touched-pixel hits that are no other sample's surface, sorted by
    depth per pixel (centre samples before touched ones at equal depth).  A touched sample's
    position is recomputed in float64 from its triangle: the point of the triangle nearest the
    pixel's centre ray.  (Numba kernels, pixel by pixel: which touched samples stay, then the
    merge; the work follows the samples, not layers x layers x pixels.)"""
    (centre, centre_colours), (touched, touched_colours) = centre, touched
    n = camera.resolution
    pixel = 2.0 * math.tan(0.5 * camera.fov) / n
    plain = LayeredDepthImage(camera, centre[..., 0], centre[..., 1].astype(np.int64), centre[..., 2].astype(np.int64))
    c_depth = np.ascontiguousarray(plain.depth, dtype=np.float64)
    t_depth = np.ascontiguousarray(touched[..., 0], dtype=np.float64).reshape((-1,) + c_depth.shape[1:])
    keep = _touched_kept(c_depth, t_depth, SAME_SURFACE * pixel)
    t_obj = np.where(keep, touched[..., 1], -1).astype(np.int64)
    t_tri = np.where(keep, touched[..., 2], -1).astype(np.int64)
    t_pos = np.full(t_depth.shape + (3,), np.nan)
    for layer in np.flatnonzero(keep.any(axis=(1, 2))):
        t_pos[layer] = _touch_positions(
            camera, np.where(keep[layer], t_depth[layer], np.nan), t_obj[layer], t_tri[layer], objects
        )
    depth, obj, tri, kind, positions, colour = _merge_kernel(
        c_depth, plain.obj, plain.triangle, np.ascontiguousarray(plain.sample_positions()), np.ascontiguousarray(centre_colours, dtype=np.uint8),
        t_depth, t_obj, t_tri, t_pos, np.ascontiguousarray(touched_colours, dtype=np.uint8).reshape(t_depth.shape + (4,)), keep,
    )  # fmt: skip
    return LayeredDepthImage(camera, depth, obj, tri, positions, kind, colour)


@numba.njit(cache=True, nogil=True)
def _touched_kept(c_depth, t_depth, same_surface):  # pragma: no cover - compiled
    """(Lt, h, w) bool: the touched samples, nearest layer first, with no kept sample of their
    pixel (centre samples and touched ones kept before) within ``same_surface`` x depth of them."""
    lc, h, w = c_depth.shape
    lt = t_depth.shape[0]
    keep = np.zeros(t_depth.shape, dtype=np.bool_)
    for r in range(h):
        for c in range(w):
            for k in range(lt):
                d = t_depth[k, r, c]
                if not np.isfinite(d):
                    continue
                tolerance = same_surface * d
                near = False
                for m in range(lc):
                    if abs(c_depth[m, r, c] - d) <= tolerance:
                        near = True
                        break
                if not near:
                    for m in range(k):
                        if keep[m, r, c] and abs(t_depth[m, r, c] - d) <= tolerance:
                            near = True
                            break
                keep[k, r, c] = not near
    return keep


@numba.njit(cache=True, nogil=True)
def _merge_kernel(
    c_depth, c_obj, c_tri, c_pos, c_col, t_depth, t_obj, t_tri, t_pos, t_col, keep
):  # pragma: no cover - compiled
    lc, h, w = c_depth.shape
    lt = t_depth.shape[0]
    layers = 0
    for r in range(h):
        for c in range(w):
            count = 0
            for m in range(lc):
                count += np.isfinite(c_depth[m, r, c])
            for k in range(lt):
                count += keep[k, r, c]
            layers = max(layers, count)
    depth = np.full((layers, h, w), np.nan)
    obj = np.full((layers, h, w), -1, np.int64)
    tri = np.full((layers, h, w), -1, np.int64)
    kind = np.zeros((layers, h, w), np.bool_)
    positions = np.full((layers, h, w, 3), np.nan)
    colour = np.zeros((layers, h, w, 4), np.uint8)
    source = np.empty(lc + lt, np.int64)  # per pixel: m (centre) or lc + k (touched), by depth
    value = np.empty(lc + lt)
    for r in range(h):
        for c in range(w):
            count = 0
            for m in range(lc + lt):  # insertion sort, stable: centre layers first, then touched
                if m < lc:
                    d = c_depth[m, r, c]
                    if not np.isfinite(d):
                        continue
                else:
                    if not keep[m - lc, r, c]:
                        continue
                    d = t_depth[m - lc, r, c]
                i = count
                while i > 0 and value[i - 1] > d:
                    value[i], source[i] = value[i - 1], source[i - 1]
                    i -= 1
                value[i], source[i] = d, m
                count += 1
            for i in range(count):
                m = source[i]
                depth[i, r, c] = value[i]
                if m < lc:
                    obj[i, r, c], tri[i, r, c] = c_obj[m, r, c], c_tri[m, r, c]
                    positions[i, r, c] = c_pos[m, r, c]
                    colour[i, r, c] = c_col[m, r, c]
                else:
                    k = m - lc
                    obj[i, r, c], tri[i, r, c] = t_obj[k, r, c], t_tri[k, r, c]
                    positions[i, r, c] = t_pos[k, r, c]
                    colour[i, r, c] = t_col[k, r, c]
                    kind[i, r, c] = True
    return depth, obj, tri, kind, positions, colour


def _touch_positions(camera: Camera, depth: np.ndarray, obj: np.ndarray, tri: np.ndarray, objects) -> np.ndarray:
    """(h, w, 3) world points (NaN where ``depth`` is NaN) of touched-pixel samples: on triangle
    ``tri`` of object ``obj``, the point whose projection is nearest the pixel centre (the same rule
    as ``peel_touch.frag``, in float64): the centre itself when the triangle covers it."""
    out = np.full(depth.shape + (3,), np.nan)
    rows, cols = np.nonzero(np.isfinite(depth))
    if rows.size == 0:
        return out
    n = camera.resolution
    t = math.tan(0.5 * camera.fov)
    centre = np.stack(
        [camera.offset[0] + (2.0 * (cols + 0.5) / n - 1.0) * t, camera.offset[1] - (2.0 * (rows + 0.5) / n - 1.0) * t],
        axis=1,
    )
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
    # A triangle covering the pixel's centre on a cut texel (peel_touch.frag samples it there too):
    # the centre itself.
    a, b, c = proj[:, 0], proj[:, 1], proj[:, 2]
    cross = lambda u, v: u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]  # noqa: E731
    area = cross(b - a, c - a)
    with np.errstate(invalid="ignore", divide="ignore"):
        inside_w = np.stack([cross(b - q, c - q), cross(c - q, a - q), cross(a - q, b - q)], axis=1) / area[:, None]
    inside = (area != 0.0) & np.all(inside_w >= 0.0, axis=1)
    best_w[inside] = inside_w[inside]
    k = best_w / eye[..., 2]
    k /= k.sum(axis=1, keepdims=True)
    out[rows, cols] = np.einsum("mi,mij->mj", k, corners)
    return out


def camera_of(payload) -> Camera:
    """The camera an ``ldi`` payload (:class:`farfield.core.impostor.impostor.LdiPayload`) records."""
    t, ox, oy, near, far = (float(x) for x in payload.window)
    right, up, forward = payload.axes
    return Camera(
        payload.eye.copy(),
        right.copy(),
        up.copy(),
        forward.copy(),
        2.0 * math.atan(t),
        int(payload.size[0]),
        near,
        far,
        (ox, oy),
    )


def ldi_of(impostor) -> LayeredDepthImage:
    """The LDI an ``ldi`` impostor's pages hold (two pages per layer: colour, then float32 depth;
    :mod:`farfield.core.ldi.pages`)."""
    payload = impostor.payload
    layers = int(payload.size[1])
    n = int(payload.size[0])
    depth = np.full((layers, n, n), np.nan)
    colour = np.zeros((layers, n, n, 4), np.uint8)
    for k in range(layers):
        c, d = impostor.pages[2 * k], impostor.pages[2 * k + 1]
        present = c[..., 3] > 0
        values = np.ascontiguousarray(d).view("<f4").reshape(n, n).astype(np.float64)
        depth[k] = np.where(present, values, np.nan)
        colour[k] = c
    missing = np.full(depth.shape, -1, np.int64)
    return LayeredDepthImage(camera_of(payload), depth, missing, missing.copy(), colour=colour)
