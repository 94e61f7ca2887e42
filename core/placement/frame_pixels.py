"""A box's pixels in a known frame: the exact area of its silhouette clipped by the near plane and the frustum.

Where the camera is known (a frame the runtime or the walkthrough draws, not a problem view of the
planner, which may look anywhere in its interval), an element's covered pixels are bounded by its
bounding box's projection *clipped to the frame*: the box cut by the near plane (a convex
polytope in front of the eye), its vertices projected, their convex hull (the silhouette, exact
for a convex body), clipped to the image square (the four side planes of the frustum pass through
the eye), its area in pixels.  Elements behind the eye or outside the frame count 0; an eye inside
a box sees it fill the frame (its near-plane section is around the view axis).

How conservative: the element's triangles lie in its box, so their covered pixels (a pixel is
covered where its centre is) are within the box's silhouette up to the raster's edge pixels; the
area is of the box, not of the triangles (a tree's crown or a slanted roof covers less), and
overlaps between elements are not subtracted (no occlusion): the per-frame sum is at least the
frame's covered pixels, the estimate caps it at ``depth_complexity`` frames as before.

The kernel (numba, one loop over boxes) is exact arithmetic on at most 14 points a box: no sampling.  The frame's
sides clip the hull's points in the eye frame, before the division (a near plane's points
project to box size / near tangents: clipped after it, a tiny near lost the frame's digits).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from farfield.core.render.raster import Camera

# The 12 edges of a box whose corner ``i`` is (i & 1, i >> 1 & 1, i >> 2 & 1) of (lo, hi).
_EDGES = np.array([(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1], dtype=np.int64)
_PICK = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], dtype=bool)


def box_frame_pixels(camera: Camera, lo, hi) -> np.ndarray:
    """(k,) float64 pixels of each box ``lo``..``hi`` ((k, 3) each, world) inside ``camera``'s frame:
    the area of its projection after clipping by the near plane and the frame's four sides.

    >>> cam = Camera.look_at(np.zeros(3), [0.0, 0.0, 1.0], math.radians(90.0), 8, 0.1, 100.0)
    >>> lo = np.array([[-1.0, -1, 2], [-1, -1, -6], [-9, -9, -9], [0, 0, 4]])
    >>> box_frame_pixels(cam, lo, lo + [[2.0, 2, 2], [2, 2, 2], [18, 18, 18], [8, 8, 1]]).round(3).tolist()
    [16.0, 0.0, 64.0, 16.0]
    """
    lo = np.asarray(lo, dtype=np.float64).reshape(-1, 3)
    hi = np.asarray(hi, dtype=np.float64).reshape(-1, 3)
    if lo.shape[0] == 0:
        return np.zeros(0)
    corners = np.where(_PICK[None, :, :], hi[:, None, :], lo[:, None, :])  # (k, 8, 3)
    e = (corners - camera.eye) @ np.stack([camera.right, camera.up, camera.forward]).T
    t = math.tan(0.5 * camera.fov)
    area = _clipped_areas(
        np.ascontiguousarray(e), _EDGES, float(camera.near), float(camera.offset[0]), float(camera.offset[1]), t
    )
    scale = 0.5 * camera.resolution / t  # pixels per unit of tangent
    return area * (scale * scale)


@njit(cache=True, nogil=True)
def _clipped_areas(e, edges, near, ox, oy, t):
    """(k,) area, in tangent units², of each box (eye-frame corners ``e`` (k, 8, 3)) cut by ``z >=
    near``, projected to ``(x / z - ox, y / z - oy)`` and clipped to ``[-t, t]²``."""
    k = e.shape[0]
    out = np.zeros(k)
    u = np.empty(16)
    v = np.empty(16)
    w = np.empty((16, 3))  # each point in the eye frame, sorted with (u, v)
    hull = np.empty(34, np.int64)
    p = np.empty((24, 3))
    q = np.empty((24, 3))
    for b in range(k):
        n = 0
        for c in range(8):
            z = e[b, c, 2]
            if z >= near:
                u[n] = e[b, c, 0] / z - ox
                v[n] = e[b, c, 1] / z - oy
                w[n, 0], w[n, 1], w[n, 2] = e[b, c, 0], e[b, c, 1], z
                n += 1
        if n == 0:
            continue  # wholly behind the near plane (a box cut by it keeps a corner in front)
        for m in range(edges.shape[0]):
            i, j = edges[m, 0], edges[m, 1]
            zi, zj = e[b, i, 2], e[b, j, 2]
            if (zi < near) != (zj < near):
                s = (near - zi) / (zj - zi)
                w[n, 0] = e[b, i, 0] + s * (e[b, j, 0] - e[b, i, 0])
                w[n, 1] = e[b, i, 1] + s * (e[b, j, 1] - e[b, i, 1])
                w[n, 2] = near
                u[n] = w[n, 0] / near - ox
                v[n] = w[n, 1] / near - oy
                n += 1
        if n < 3:
            continue
        # Sort the points by (u, v) (insertion sort: at most 14), then Andrew's monotone chain.
        for i in range(1, n):
            a, c = u[i], v[i]
            x, y, z = w[i, 0], w[i, 1], w[i, 2]
            j = i - 1
            while j >= 0 and (u[j] > a or (u[j] == a and v[j] > c)):
                u[j + 1] = u[j]
                v[j + 1] = v[j]
                w[j + 1, 0], w[j + 1, 1], w[j + 1, 2] = w[j, 0], w[j, 1], w[j, 2]
                j -= 1
            u[j + 1] = a
            v[j + 1] = c
            w[j + 1, 0], w[j + 1, 1], w[j + 1, 2] = x, y, z
        h = 0
        for i in range(n):  # lower chain
            while h >= 2 and _cross(u, v, hull[h - 2], hull[h - 1], i) <= 0.0:
                h -= 1
            hull[h] = i
            h += 1
        low = h + 1
        for i in range(n - 2, -1, -1):  # upper chain
            while h >= low and _cross(u, v, hull[h - 2], hull[h - 1], i) <= 0.0:
                h -= 1
            hull[h] = i
            h += 1
        h -= 1  # the last point repeats the first
        if h < 3:
            continue
        for i in range(h):
            p[i, 0], p[i, 1], p[i, 2] = w[hull[i], 0], w[hull[i], 1], w[hull[i], 2]
        # Sutherland-Hodgman against u <= t, -u <= t, v <= t, -v <= t, in the eye frame (the
        # planes through the eye ``sign (x - o z) - t z <= 0``): the hull's points at the near
        # plane project up to (box size / near) tangents, whose differences lose the frame's
        # digits; the eye-frame points keep them, each projected once clipped.
        m = h
        for side in range(4):
            axis = 0 if side < 2 else 1
            sign = 1.0 if side % 2 == 0 else -1.0
            o = ox if axis == 0 else oy
            r = 0
            for i in range(m):
                i2 = i + 1 if i + 1 < m else 0
                a = sign * (p[i, axis] - o * p[i, 2]) - t * p[i, 2]
                c = sign * (p[i2, axis] - o * p[i2, 2]) - t * p[i2, 2]
                if a <= 0.0:
                    q[r, 0], q[r, 1], q[r, 2] = p[i, 0], p[i, 1], p[i, 2]
                    r += 1
                if (a <= 0.0) != (c <= 0.0):
                    s = a / (a - c)
                    for d in range(3):
                        q[r, d] = p[i, d] + s * (p[i2, d] - p[i, d])
                    r += 1
            m = r
            for i in range(m):
                p[i, 0], p[i, 1], p[i, 2] = q[i, 0], q[i, 1], q[i, 2]
            if m < 3:
                break
        if m < 3:
            continue
        area = 0.0
        for i in range(m):
            i2 = i + 1 if i + 1 < m else 0
            area += (p[i, 0] / p[i, 2] - ox) * (p[i2, 1] / p[i2, 2] - oy)
            area -= (p[i2, 0] / p[i2, 2] - ox) * (p[i, 1] / p[i, 2] - oy)
        out[b] = 0.5 * abs(area)
    return out


@njit(cache=True, inline="always")
def _cross(u, v, o, a, b):
    return (u[a] - u[o]) * (v[b] - v[o]) - (v[a] - v[o]) * (u[b] - u[o])
