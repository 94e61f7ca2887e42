"""Warping a layered depth image to a new view (seed 004 §4; McMillan & Bishop 1995; Shade et al. 1998):
the reference CPU warp in occlusion-compatible order, the splat sizes both warpers use, and the
3x3 pass that fills a warped image's pin holes.

**Occlusion-compatible order.**  The eye is projected into the LDI's image: that is the *epipole*.
Two LDI samples that land on one output pixel lie on one epipolar line, and the one farther from
the eye projects farther from the epipole when the eye is in front of the LDI's centre of
projection (``w > 0``), nearer when it is behind (``w < 0``).  So the image is cut at the epipole's
row and column into up to four *sheets*.  Each sheet is walked row by row and column by column:
toward the epipole when ``w > 0``, away from it when ``w < 0``.  Each pixel's layers go back to
front, and a later sample simply paints over an earlier one: no depth buffer.  When ``w`` is near
zero the epipole lies at infinity in the direction ``(x, y)``.  ``w`` is then clamped to a tiny
value of its own sign, which walks every sheet along that direction, the limit of both rules.

**Splats.**  A sample covers its LDI pixel's footprint: ``pixel_ref * depth_ref`` wide in the
world, ``pixel_ref * depth_ref / (depth_out * pixel_out)`` output pixels wide.  It is drawn as a
square of that width rounded up (1 to :data:`MAX_SPLAT` pixels), rasterised as the GL draws
points: an odd width is centred on the pixel the sample falls in, an even one on the pixel corner
nearest it.  The GPU drawer (:mod:`farfield.core.render.splats`) draws the same squares with a depth
test; the two agree except where splats of equal depth order differently.

**3x3 pass** (§5: "we use a 3x3 convolution-kernel to smooth the warped image").  An output pixel
no splat reached, with at least :data:`FILL_NEIGHBOURS` of its 8 neighbours reached, takes their
mean.  This fills the pin holes between splats without growing the image's silhouette by more
than that.  Reached pixels are left as they are.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from farfield.core.ldi.image import LayeredDepthImage
from farfield.core.render.raster import Camera

MAX_SPLAT = 8  # pixels: a sample drawn wider than this is a sample seen far too close
FILL_NEIGHBOURS = 4  # of 8: a pin hole, not the image's edge


def _frame(camera: Camera) -> tuple[np.ndarray, float, float, float]:
    return (
        np.stack([camera.right, camera.up, camera.forward]),
        float(camera.offset[0]),
        float(camera.offset[1]),
        math.tan(0.5 * camera.fov),
    )


def epipole(ldi_camera: Camera, eye) -> tuple[float, float, float]:
    """(column, row, w) of ``eye`` in the LDI's image: pixel coordinates (0 at the top-left corner)
    and the eye's depth ``w`` along the LDI's forward axis, clamped away from 0 (module docstring)."""
    frame, ox, oy, half = _frame(ldi_camera)
    e = frame @ (np.asarray(eye, dtype=np.float64) - ldi_camera.eye)
    w = float(e[2])
    tiny = 1e-12 * max(float(np.linalg.norm(e)), 1e-300)
    if abs(w) < tiny:
        w = tiny if w >= 0 else -tiny
    n = ldi_camera.resolution
    return (e[0] / w - ox + half) / (2 * half) * n, (half - (e[1] / w - oy)) / (2 * half) * n, w


def warp_cpu(ldi: LayeredDepthImage, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """((h, w, 4) uint8 image, (h, w) float64 eye depth, NaN where nothing) of ``ldi`` warped to
    ``camera`` in occlusion-compatible order, splatted, before the 3x3 pass; top row first."""
    col_e, row_e, w = epipole(ldi.camera, camera.eye)
    ref_frame, rox, roy, rhalf = _frame(ldi.camera)
    out_frame, oox, ooy, ohalf = _frame(camera)
    colour = ldi.colour if ldi.colour is not None else np.full(ldi.depth.shape + (4,), 255, np.uint8)
    image = np.zeros((camera.resolution, camera.resolution, 4), np.uint8)
    depth = np.full((camera.resolution, camera.resolution), np.nan)
    _warp_kernel(
        np.ascontiguousarray(ldi.depth), np.ascontiguousarray(colour), ldi.camera.eye, ref_frame, rox, roy, rhalf,
        camera.eye, out_frame, oox, ooy, ohalf, float(camera.near), col_e, row_e, w > 0, image, depth,
    )  # fmt: skip
    return image, depth


@numba.njit(cache=True, nogil=True)
def _splat_bounds(x, n, size):  # pragma: no cover - compiled
    """First and last pixel (inclusive) of a ``size``-wide point at window coordinate ``x`` (GL rule)."""
    if size % 2 == 1:
        c = int(math.floor(x))
        return c - (size - 1) // 2, c + (size - 1) // 2
    c = int(math.floor(x + 0.5))
    return c - size // 2, c + size // 2 - 1


@numba.njit(cache=True, nogil=True)
def _warp_sample(
    z, r, c, colour, layer, ref_eye, ref_frame, rox, roy, rhalf, n, eye, frame, oox, ooy, ohalf, near, image, depth
):  # pragma: no cover - compiled
    m = image.shape[0]
    tx = rox + (2.0 * (c + 0.5) / n - 1.0) * rhalf
    ty = roy - (2.0 * (r + 0.5) / n - 1.0) * rhalf
    px = ref_eye[0] + z * (tx * ref_frame[0, 0] + ty * ref_frame[1, 0] + ref_frame[2, 0])
    py = ref_eye[1] + z * (tx * ref_frame[0, 1] + ty * ref_frame[1, 1] + ref_frame[2, 1])
    pz = ref_eye[2] + z * (tx * ref_frame[0, 2] + ty * ref_frame[1, 2] + ref_frame[2, 2])
    dx, dy, dz = px - eye[0], py - eye[1], pz - eye[2]
    zt = dx * frame[2, 0] + dy * frame[2, 1] + dz * frame[2, 2]
    if zt <= near:
        return
    xt = (dx * frame[0, 0] + dy * frame[0, 1] + dz * frame[0, 2]) / zt - oox
    yt = (dx * frame[1, 0] + dy * frame[1, 1] + dz * frame[1, 2]) / zt - ooy
    wx = (xt + ohalf) / (2.0 * ohalf) * m  # window coordinates, x right, y down
    wy = (ohalf - yt) / (2.0 * ohalf) * m
    width = (2.0 * rhalf / n) * z / (zt * (2.0 * ohalf / m))
    size = min(max(int(math.ceil(width - 1e-9)), 1), 8)
    c0, c1 = _splat_bounds(wx, m, size)
    r0, r1 = _splat_bounds(wy, m, size)
    for rr in range(max(r0, 0), min(r1, m - 1) + 1):
        for cc in range(max(c0, 0), min(c1, m - 1) + 1):
            for k in range(4):
                image[rr, cc, k] = colour[layer, r, c, k]
            depth[rr, cc] = zt


@numba.njit(cache=True, nogil=True)
def _warp_kernel(
    ldi_depth,
    colour,
    ref_eye,
    ref_frame,
    rox,
    roy,
    rhalf,
    eye,
    frame,
    oox,
    ooy,
    ohalf,
    near,
    col_e,
    row_e,
    positive,
    image,
    depth,
):  # pragma: no cover - compiled
    layers, n, _ = ldi_depth.shape
    # The sheets split at the epipole between pixel centres (c + 0.5): columns <= ce lie left of it.
    ce = min(max(int(math.floor(col_e - 0.5)), -1), n)
    re = min(max(int(math.floor(row_e - 0.5)), -1), n)
    for sheet in range(4):
        # rows: sheet 0, 1 above-or-at the epipole row, 2, 3 below; columns: 0, 2 left, 1, 3 right
        upper = sheet < 2
        left = sheet % 2 == 0
        r_lo, r_hi = (0, re) if upper else (re + 1, n - 1)
        c_lo, c_hi = (0, ce) if left else (ce + 1, n - 1)
        r_lo, r_hi = max(r_lo, 0), min(r_hi, n - 1)
        c_lo, c_hi = max(c_lo, 0), min(c_hi, n - 1)
        if r_lo > r_hi or c_lo > c_hi:
            continue
        # toward the epipole when positive: from the far edge of the sheet
        r_down = upper == positive
        c_right = left == positive
        for i in range(r_hi - r_lo + 1):
            r = r_lo + i if r_down else r_hi - i
            for j in range(c_hi - c_lo + 1):
                c = c_lo + j if c_right else c_hi - j
                for k in range(layers - 1, -1, -1):  # back to front
                    z = ldi_depth[k, r, c]
                    if not np.isfinite(z):
                        continue
                    _warp_sample(
                        z,
                        r,
                        c,
                        colour,
                        k,
                        ref_eye,
                        ref_frame,
                        rox,
                        roy,
                        rhalf,
                        n,
                        eye,
                        frame,
                        oox,
                        ooy,
                        ohalf,
                        near,
                        image,
                        depth,
                    )


def fill_pin_holes(
    image: np.ndarray, reached: np.ndarray, neighbours: int = FILL_NEIGHBOURS, empty: np.ndarray | None = None
) -> np.ndarray:
    """The 3x3 pass (module docstring): ``image`` (h, w, 4) uint8 with its unreached pixels (only the
    ``empty`` ones, if given) that have at least ``neighbours`` reached ones among their 8 set to
    those neighbours' mean; returns a copy."""
    h, w = reached.shape
    pad = np.pad(reached, 1)
    colour = np.pad(image.astype(np.float64) * reached[..., None], ((1, 1), (1, 1), (0, 0)))
    total = np.zeros((h, w, 4))
    hits = np.zeros((h, w))
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr == dc == 0:
                continue
            hits += pad[1 + dr : 1 + dr + h, 1 + dc : 1 + dc + w]
            total += colour[1 + dr : 1 + dr + h, 1 + dc : 1 + dc + w]
    fill = ~reached & (hits >= neighbours)
    if empty is not None:
        fill &= empty
    out = image.copy()
    out[fill] = np.round(total[fill] / hits[fill, None]).astype(np.uint8)
    return out
