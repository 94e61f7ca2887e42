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
from threadpoolctl import threadpool_limits

from farfield.core.ldi.image import LayeredDepthImage
from farfield.core.placement.yaw_ranges import forward, right
from farfield.core.render.peeling import Peeler
from farfield.core.render.raster import Camera
from farfield.core.scene import SceneObject
from farfield.core.sidedness import seen_from_cell
from farfield.core.stage_clock import StageClock
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
                  images: int = 9, max_layers: int = DEFAULT_MAX_LAYERS, cell: ViewCell | None = None,
                  clock: StageClock | None = None) -> ConstructedLdi:  # fmt: skip
    """The LDI of ``objects`` (the subset's triangles) for the image at ``grid_point`` looking along
    ``direction`` (a yaw, radians, or a 3-vector) through ``quad`` at ``depth`` (module docstring).

    ``cell``: the view cell the LDI serves; a one-sided triangle whose back faces the whole of it is
    not recorded (:func:`farfield.core.sidedness.seen_from_cell`; the samples' object indices are
    then those of the objects it keeps), while the LDI's frame is still that of all ``objects``.

    The objects are uploaded once for the nine images (:class:`~farfield.core.render.peeling.Peeler`).
    ``clock``: the stages' seconds are added to it: ``frame`` (the cameras), ``upload``, ``draw``
    and ``read`` (the GL passes and their read-back), ``merge`` (the samples warped into the LDI)
    and ``sort`` (each pixel's samples by depth)."""
    # OpenBLAS's threads turn the products of (m, 3) arrays here (the vertices' depths, the samples'
    # frame) 10-30x slower on a busy 2-core machine (benchmarks/bench_ldi.py); one thread gives the
    # same values (one kernel per row).
    with threadpool_limits(1, user_api="blas"):
        return _construct(objects, grid_point, direction, quad, depth, resolution, images, max_layers, cell,
                          clock if clock is not None else StageClock())  # fmt: skip


def _construct(
    objects, grid_point, direction, quad, depth, resolution, images, max_layers, cell, clock
) -> ConstructedLdi:
    g = np.asarray(grid_point, dtype=np.float64)
    with clock("frame"):
        vertices = subset_vertices(objects)
        drawn = list(objects) if cell is None else list(seen_from_cell(objects, cell))
        far = float(((vertices - g) @ view_frame(direction)[2]).max()) * (1 + 1e-6)
        camera = ldi_camera(g, direction, quad, depth, far, resolution)
        cops = construction_cops(g, quad, images)
        # (with nothing to draw, the first camera only, as the loop of old stopped there)
        cameras = construction_cameras(vertices, cops if drawn else cops[:1], camera, direction, resolution)
    pixel = 2.0 * math.tan(0.5 * camera.fov) / resolution
    frame = np.stack([camera.right, camera.up, camera.forward])
    with clock("merge"):
        depth_l = np.full((max_layers, resolution, resolution), np.nan)
        obj_l = np.full((max_layers, resolution, resolution), -1, np.int64)
        tri_l = np.full((max_layers, resolution, resolution), -1, np.int64)
        col_l = np.zeros((max_layers, resolution, resolution, 4), np.uint8)
        count = np.zeros((resolution, resolution), np.int64)
    offered = kept = dropped = 0
    if drawn:
        with clock("upload"):
            peeler = Peeler(drawn)
        try:
            for cam in cameras:
                hits, colours = peeler.peel(cam, max_layers=1, truncate=True)
                if hits.shape[0] == 0:
                    continue
                with clock("merge"):
                    positions, obj, tri, col = _image_samples(
                        hits, colours, cam.eye, cam.right, cam.up, cam.forward, float(cam.offset[0]), float(cam.offset[1]),
                        math.tan(0.5 * cam.fov), cam.resolution,
                    )  # fmt: skip
                    offered += obj.size
                    if obj.size == 0:
                        continue
                    rel = (positions - camera.eye) @ frame.T  # (m, 3) in the LDI's frame
                    k, d = _merge_samples(
                        rel, obj, tri, col, float(camera.offset[0]), float(camera.offset[1]), math.tan(0.5 * camera.fov), resolution,
                        float(camera.near), SAME_SURFACE * pixel, depth_l, obj_l, tri_l, col_l, count,
                    )  # fmt: skip
                kept += k
                dropped += d
        finally:
            with clock("upload"):  # and its release
                peeler.release()
        for stage, seconds in peeler.seconds.items():
            clock.seconds[stage] = clock.seconds.get(stage, 0.0) + seconds
    with clock("sort"):
        layers = max(1, int(count.max()))
        d, o, t, c = _sorted_layers(depth_l, obj_l, tri_l, col_l, count, layers)
        ldi = LayeredDepthImage(camera, d, o, t, colour=c)
    return ConstructedLdi(ldi, cops, offered, kept, dropped)


def subset_vertices(objects: list[SceneObject]) -> np.ndarray:
    """(v, 3) float64: the vertices the objects' faces use, object by object in index order (one
    pass over the faces, no sort)."""
    out = []
    for o in objects:
        used = np.zeros(len(o.vertices), dtype=bool)
        used[o.faces.ravel()] = True
        out.append(o.vertices[used])
    return np.concatenate(out) if out else np.zeros((0, 3))


def construction_cameras(
    vertices: np.ndarray, cops: np.ndarray, camera: Camera, direction, resolution: int
) -> list[Camera]:
    """The construction images' cameras: ``camera`` (the LDI's) at the grid point (the COP equal to
    its eye), elsewhere the square window around ``vertices`` from the COP (:func:`_window`).

    The windows are those of all the vertices, computed on the few that can bound them: a compiled
    pass finds, for every COP at once, the vertices within a tolerance far above rounding of the
    least and greatest depth and image-plane tangents, and :func:`_window` runs on those alone
    (the same float64 operations on the same rows, so the same bounds)."""
    others = [i for i, cop in enumerate(cops) if not np.array_equal(cop, camera.eye)]
    if len(others) == 0 or vertices.shape[0] == 0:
        return [
            camera if i not in others else _window(vertices, cops[i], direction, resolution) for i in range(len(cops))
        ]
    r, u, f = view_frame(direction)
    eyes = np.ascontiguousarray(cops[others])
    candidates = _window_candidates(np.ascontiguousarray(vertices, dtype=np.float64), eyes, r, u, f)
    near = vertices[candidates]
    out = [camera] * len(cops)
    for i in others:
        out[i] = _window(near, cops[i], direction, resolution)
    return out


@numba.njit(cache=True, nogil=True, inline="always")
def _seen_from(points, i, eyes, e, r, u, f, v):  # pragma: no cover - compiled
    """``v`` = point ``i`` seen from eye ``e``: its depth along ``f`` and its tangents along ``r``
    and ``u`` (over the depth)."""
    d0, d1, d2 = points[i, 0] - eyes[e, 0], points[i, 1] - eyes[e, 1], points[i, 2] - eyes[e, 2]
    z = d0 * f[0] + d1 * f[1] + d2 * f[2]
    v[0] = z
    v[1] = (d0 * r[0] + d1 * r[1] + d2 * r[2]) / z
    v[2] = (d0 * u[0] + d1 * u[1] + d2 * u[2]) / z


@numba.njit(cache=True, nogil=True)
def _window_candidates(points, eyes, r, u, f):  # pragma: no cover - compiled
    """Indices of the ``points`` that may hold, for some eye, the least or greatest depth along
    ``f`` or tangent along ``r`` / ``u``: those within a tolerance (below) of an extreme."""
    n, k = points.shape[0], eyes.shape[0]
    lo = np.full((k, 3), np.inf)
    hi = np.full((k, 3), -np.inf)
    v = np.empty(3)
    for i in range(n):
        for e in range(k):
            _seen_from(points, i, eyes, e, r, u, f, v)
            for a in range(3):
                lo[e, a] = min(lo[e, a], v[a])
                hi[e, a] = max(hi[e, a], v[a])
    # Rounding moves a value by ~1e-16 of the eye-relative position's length, at most depth x
    # (1 + |x| + |y|): the tolerances are 1e-9 of that, far above it and far below any window.
    tol = np.empty((k, 3))
    for e in range(k):
        spread = 1.0 + max(abs(lo[e, 1]), abs(hi[e, 1])) + max(abs(lo[e, 2]), abs(hi[e, 2]))
        tol[e, 0] = 1e-9 * spread * max(abs(lo[e, 0]), abs(hi[e, 0]))
        tol[e, 1] = tol[e, 2] = 1e-9 * spread
        for a in range(3):
            if not np.isfinite(tol[e, a]):
                tol[e, a] = np.inf  # a vertex at or behind an eye: every vertex is a candidate
    keep = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        for e in range(k):
            _seen_from(points, i, eyes, e, r, u, f, v)
            for a in range(3):
                if not (v[a] > lo[e, a] + tol[e, a] and v[a] < hi[e, a] - tol[e, a]):
                    keep[i] = True
            if keep[i]:
                break
    return np.flatnonzero(keep)


@numba.njit(cache=True, nogil=True)
def _image_samples(hits, colours, eye, right, up, forward, ox, oy, t, n):  # pragma: no cover - compiled
    """The samples of a one-layer image (peel's ``hits`` (1, h, w, 3) and ``colours``), row by row:
    (m, 3) world positions, object and triangle indices, (m, 4) colours.  The positions are
    :meth:`LayeredDepthImage.samples`' (eye + depth x the pixel-centre direction), by the same float64
    operations in the same order."""
    h, w = hits.shape[1], hits.shape[2]
    m = 0
    for r in range(h):
        for c in range(w):
            if np.isfinite(hits[0, r, c, 0]):
                m += 1
    positions = np.empty((m, 3))
    obj = np.empty(m, np.int64)
    tri = np.empty(m, np.int64)
    col = np.empty((m, 4), np.uint8)
    i = 0
    for r in range(h):
        y = oy - (2.0 * (r + 0.5) / n - 1.0) * t
        for c in range(w):
            d = hits[0, r, c, 0]
            if not np.isfinite(d):
                continue
            x = ox + (2.0 * (c + 0.5) / n - 1.0) * t
            for k in range(3):
                positions[i, k] = eye[k] + d * (x * right[k] + y * up[k] + forward[k])
            obj[i] = np.int64(hits[0, r, c, 1])
            tri[i] = np.int64(hits[0, r, c, 2])
            for k in range(4):
                col[i, k] = colours[0, r, c, k]
            i += 1
    return positions, obj, tri, col


@numba.njit(cache=True, nogil=True)
def _sorted_layers(depth_l, obj_l, tri_l, col_l, count, layers):  # pragma: no cover - compiled
    """The first ``layers`` of the merged LDI with each pixel's ``count`` samples sorted by depth,
    nearest first (stable: of equal depths, the one merged first stays first; NaN slots after)."""
    _, h, w = depth_l.shape
    depth = np.full((layers, h, w), np.nan)
    obj = np.full((layers, h, w), -1, np.int64)
    tri = np.full((layers, h, w), -1, np.int64)
    col = np.zeros((layers, h, w, 4), np.uint8)
    order = np.empty(depth_l.shape[0], np.int64)
    for r in range(h):
        for c in range(w):
            m = count[r, c]
            for i in range(m):  # insertion sort of the slots by depth, stable
                j = i
                while j > 0 and depth_l[order[j - 1], r, c] > depth_l[i, r, c]:
                    order[j] = order[j - 1]
                    j -= 1
                order[j] = i
            for i in range(m):
                s = order[i]
                depth[i, r, c] = depth_l[s, r, c]
                obj[i, r, c] = obj_l[s, r, c]
                tri[i, r, c] = tri_l[s, r, c]
                for k in range(4):
                    col[i, r, c, k] = col_l[s, r, c, k]
    return depth, obj, tri, col


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
