"""The layered depth image of a primitive-budget image (seed 004 §4, §4.1, Fig. 11), built from nine
construction images.

The LDI's camera is the image's own: centre of projection at the grid point, looking along the
image's view direction.  Its window is the square around the quad, and its near plane is the
quad's plane ("the projection and near plane", §3).  Nine construction images are drawn of the
subset's triangles only:
- the central one from the grid point (``a_0``);
- four from halfway between the grid point and the midpoints of the quad's edges (``a_1..a_4``);
- four as far behind the grid point (``a_5..a_8``).
All nine look the same way, each through the square window around the subset as seen from it, at
the LDI's resolution.

Each construction image is one layer (the nearest surface along each pixel's centre ray, with its
colour and its object and triangle ids: :func:`farfield.core.render.peeling.peel` truncated to one layer).

**Merge.**  The samples are warped into the LDI, "the nearest construction image first" (§4.1):
``a_1..a_4`` (half way to the quad), then ``a_0``, then ``a_5..a_8``.  A sample lands in the LDI
pixel its position projects into, at its own depth (so it moves onto that pixel's centre ray, up to
half a pixel sideways, as in any LDI).  It is dropped when a sample already in that pixel is the
same surface: the same triangle, or a depth within :data:`SAME_SURFACE` pixel widths at that
depth.  It is also dropped when the pixel already holds ``max_layers`` samples; those are counted.
Layers are then sorted by depth, nearest first.  The paper gives no rule for either case.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from farfield.core.ldi.image import LayeredDepthImage
from farfield.core.placement.yaw_ranges import forward, right
from farfield.core.render.peeling import peel
from farfield.core.render.raster import Camera
from farfield.core.scene import SceneObject
from farfield.core.sidedness import seen_from_cell
from farfield.core.viewcells import ViewCell

SAME_SURFACE = 2.0  # pixel widths (at the sample's depth) within which two samples of a pixel are one surface
DEFAULT_MAX_LAYERS = 8
UP = np.array([0.0, 1.0, 0.0])


@dataclass(frozen=True)
class ConstructedLdi:
    """An LDI and how it was made: the construction COPs in merge order, and the samples offered,
    kept and dropped for a full pixel."""

    ldi: LayeredDepthImage
    cops: np.ndarray  # (k, 3)
    offered: int
    kept: int
    dropped_full: int


def construction_cops(grid_point: np.ndarray, quad: np.ndarray, images: int = 9) -> np.ndarray:
    """(images, 3) construction COPs in merge order (Fig. 11): ``a_1..a_4`` halfway to the quad's
    edge midpoints, the grid point ``a_0``, then ``a_5..a_8`` as far behind it; ``images=1``: ``a_0`` only."""
    g = np.asarray(grid_point, dtype=np.float64)
    if images == 1:
        return g[None].copy()
    if images != 9:
        raise ValueError(f"an LDI is built from 1 or 9 construction images, not {images}")
    q = np.asarray(quad, dtype=np.float64)
    mids = 0.5 * (q + np.roll(q, -1, axis=0))  # (4, 3) edge midpoints
    half = 0.5 * (mids - g)
    return np.concatenate([g + half, g[None], g - half])


def view_frame(direction) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(right, up, forward) of a camera looking along ``direction`` (a yaw in radians, or a 3-vector):
    up is +y unless the view is within ~8° of vertical, then +z."""
    if np.ndim(direction) == 0:
        return right(float(direction)), UP.copy(), forward(float(direction))
    f = np.asarray(direction, dtype=np.float64)
    f = f / np.linalg.norm(f)
    hint = UP if abs(f[1]) < 0.99 else np.array([0.0, 0.0, 1.0])
    r = np.cross(f, hint)
    r /= np.linalg.norm(r)
    return r, np.cross(r, f), f


def _window(points: np.ndarray, eye: np.ndarray, direction, resolution: int, near: float | None = None) -> Camera:
    """The square camera at ``eye`` looking along ``direction`` whose window just holds ``points``."""
    r, u, f = view_frame(direction)
    d = points - eye
    z = d @ f
    if np.any(z <= 0):
        raise ValueError("construction camera: the subset reaches behind the centre of projection")
    x, y = (d @ r) / z, (d @ u) / z
    cx, cy = 0.5 * (x.min() + x.max()), 0.5 * (y.min() + y.max())
    # A hair wider than the points so none falls on the window's outer edge.
    h = 0.5 * max(x.max() - x.min(), y.max() - y.min(), 1e-9) * (1.0 + 2.0 / resolution)
    lo = z.min() if near is None else near
    return Camera(eye.copy(), r, u, f, 2.0 * math.atan(h), int(resolution), float(lo) * (1 - 1e-6), float(z.max()) * (1 + 1e-6) + 1e-9,
                  (float(cx), float(cy)))  # fmt: skip


def ldi_camera(
    grid_point: np.ndarray, direction, quad: np.ndarray, depth: float, far: float, resolution: int
) -> Camera:
    """The LDI's camera: at the grid point along ``direction`` (yaw or vector), the square window around ``quad``, near plane the quad's."""
    cam = _window(np.asarray(quad, dtype=np.float64), np.asarray(grid_point, dtype=np.float64), direction, resolution)
    return Camera(
        cam.eye,
        cam.right,
        cam.up,
        cam.forward,
        cam.fov,
        cam.resolution,
        float(depth) * (1 - 1e-6),
        float(far),
        cam.offset,
    )


def construct_ldi(objects: list[SceneObject], grid_point, direction, quad, depth: float, resolution: int = 256,
                  images: int = 9, max_layers: int = DEFAULT_MAX_LAYERS, cell: ViewCell | None = None) -> ConstructedLdi:  # fmt: skip
    """The LDI of ``objects`` (the subset's triangles) for the image at ``grid_point`` looking along
    ``direction`` (a yaw, radians, or a 3-vector) through ``quad`` at ``depth`` (module docstring).

    ``cell``: the view cell the LDI serves; a one-sided triangle whose back faces the whole of it is
    not recorded (:func:`farfield.core.sidedness.seen_from_cell`; the samples' object indices are
    then those of the objects it keeps), while the LDI's frame is still that of all ``objects``."""
    g = np.asarray(grid_point, dtype=np.float64)
    vertices = np.concatenate([o.vertices[np.unique(o.faces)] for o in objects])
    drawn = list(objects) if cell is None else list(seen_from_cell(objects, cell))
    far = float(((vertices - g) @ view_frame(direction)[2]).max()) * (1 + 1e-6)
    camera = ldi_camera(g, direction, quad, depth, far, resolution)
    cops = construction_cops(g, quad, images)
    pixel = 2.0 * math.tan(0.5 * camera.fov) / resolution
    frame = np.stack([camera.right, camera.up, camera.forward])
    depth_l = np.full((max_layers, resolution, resolution), np.nan)
    obj_l = np.full((max_layers, resolution, resolution), -1, np.int64)
    tri_l = np.full((max_layers, resolution, resolution), -1, np.int64)
    col_l = np.zeros((max_layers, resolution, resolution, 4), np.uint8)
    count = np.zeros((resolution, resolution), np.int64)
    offered = kept = dropped = 0
    for cop in cops:
        cam = camera if np.array_equal(cop, g) else _window(vertices, cop, direction, resolution)
        if not drawn:
            break
        hits, colours = peel(drawn, cam, max_layers=1, truncate=True)
        if hits.shape[0] == 0:
            continue
        image = LayeredDepthImage(
            cam, hits[..., 0], hits[..., 1].astype(np.int64), hits[..., 2].astype(np.int64), colour=colours
        )
        positions, index = image.samples()
        offered += positions.shape[0]
        if positions.shape[0] == 0:
            continue
        rel = (positions - camera.eye) @ frame.T  # (m, 3) in the LDI's frame
        k, d = _merge_samples(
            rel, image.obj[index[:, 0], index[:, 1], index[:, 2]], image.triangle[index[:, 0], index[:, 1], index[:, 2]],
            np.ascontiguousarray(colours[index[:, 0], index[:, 1], index[:, 2]]), float(camera.offset[0]), float(camera.offset[1]),
            math.tan(0.5 * camera.fov), resolution, float(camera.near), SAME_SURFACE * pixel, depth_l, obj_l, tri_l, col_l, count,
        )  # fmt: skip
        kept += k
        dropped += d
    layers = max(1, int(count.max()))
    order = np.argsort(np.where(np.isfinite(depth_l[:layers]), depth_l[:layers], np.inf), axis=0, kind="stable")
    take = lambda a: np.take_along_axis(a[:layers], order if a.ndim == 3 else order[..., None], axis=0)  # noqa: E731
    ldi = LayeredDepthImage(camera, take(depth_l), take(obj_l), take(tri_l), colour=take(col_l))
    return ConstructedLdi(ldi, cops, offered, kept, dropped)


@numba.njit(cache=True, nogil=True)
def _merge_samples(
    rel, obj, tri, col, ox, oy, half, n, near, same, depth_l, obj_l, tri_l, col_l, count
):  # pragma: no cover - compiled
    """Insert samples (LDI-frame positions) into the LDI's pixels unless one there is the same
    surface; (kept, dropped because the pixel was full)."""
    kept = 0
    dropped = 0
    cap = depth_l.shape[0]
    for i in range(rel.shape[0]):
        z = rel[i, 2]
        if not (z >= near):
            continue
        x = rel[i, 0] / z - ox
        y = rel[i, 1] / z - oy
        c = int(math.floor((x + half) / (2.0 * half) * n))
        r = int(math.floor((half - y) / (2.0 * half) * n))
        if c < 0 or c >= n or r < 0 or r >= n:
            continue
        duplicate = False
        for m in range(count[r, c]):
            if (obj_l[m, r, c] == obj[i] and tri_l[m, r, c] == tri[i]) or abs(depth_l[m, r, c] - z) <= same * z:
                duplicate = True
                break
        if duplicate:
            continue
        m = count[r, c]
        if m >= cap:
            dropped += 1
            continue
        depth_l[m, r, c] = z
        obj_l[m, r, c] = obj[i]
        tri_l[m, r, c] = tri[i]
        for k in range(4):
            col_l[m, r, c, k] = col[i, k]
        count[r, c] = m + 1
        kept += 1
    return kept, dropped
