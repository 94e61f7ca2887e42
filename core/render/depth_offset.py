"""A reference drawing of a quad impostor's depth as an engine sees it, with or without a pixel
depth offset from the depth channel (:mod:`farfield.core.impostor.depth`): for each pixel of a
camera, the eye depth of the impostor's nearest fragment that passes the alpha cut.

Without the offset a fragment's depth is its quad's, a plane per layer: geometry that cuts
through the impostor (a terrain, a wall, a character) meets it in a staircase of layer planes.
With it, the fragment at the quad point H takes the depth of H moved along the reference
viewpoint's ray to the texel's decoded point, ``V + (H - V) s`` (``s`` from the texel's code and
its quad's range), as a pixel-depth-offset shader writes ``gl_FragDepth``; the fragment keeps its
place in the image.

Ray casting on the CPU (numpy; nearest texel, alpha cut at 0.5, the quads' float64 corners), for
tests and measurements at small resolutions: no GL, no shared renderer.
"""

from __future__ import annotations

import math

import numpy as np

from farfield.core.render.raster import Camera


def camera_rays(camera: Camera) -> np.ndarray:
    """(h, w, 3) float64 ray directions through every pixel centre of ``camera`` (top row first),
    with unit eye depth (``d . forward = 1``); an off-axis camera's offset applied."""
    r, t = camera.resolution, math.tan(0.5 * camera.fov)
    ys, xs = np.mgrid[0:r, 0:r] + 0.5
    x = camera.offset[0] + (xs / r * 2.0 - 1.0) * t
    y = camera.offset[1] + (1.0 - ys / r * 2.0) * t
    return x[..., None] * camera.right + y[..., None] * camera.up + camera.forward


def impostor_depth(impostor, camera: Camera, offset: bool = True) -> np.ndarray:
    """(h, w) float64 eye depth of ``impostor``'s nearest visible fragment at each pixel of
    ``camera`` (inf where none): with ``offset`` the depth channel's pixel depth offset (the
    impostor must keep depth), else the quads' own depth.

    Each quad is intersected with the pixel rays; a hit takes the page texel under its uv
    (nearest) and is a fragment where that texel's alpha reaches 128 (the GLB's alpha cut).
    """
    payload = impostor.payload
    if offset and getattr(payload, "depth_range", None) is None:
        raise ValueError(f"this {impostor.technique} impostor keeps no depth channel")
    rays = camera_rays(camera).reshape(-1, 3)
    eye = np.asarray(camera.eye, dtype=np.float64)
    viewpoint = np.asarray(impostor.reference_viewpoint, dtype=np.float64)
    best = np.full(rays.shape[0], np.inf)
    for q in range(payload.count):
        c, uv = payload.corners[q], payload.uv[q]
        e1, e2 = c[1] - c[0], c[3] - c[0]
        normal = np.cross(e1, e2)
        facing = rays @ normal
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((c[0] - eye) @ normal) / facing
        hit = np.isfinite(t) & (t > 0.0)
        h = eye + rays * t[:, None]
        a = (h - c[0]) @ e1 / (e1 @ e1)
        b = (h - c[0]) @ e2 / (e2 @ e2)
        hit &= (a >= 0.0) & (a <= 1.0) & (b >= 0.0) & (b <= 1.0)
        if not hit.any():
            continue
        index = np.flatnonzero(hit)
        page = int(payload.page[q])
        colour = impostor.pages[page]
        rows, cols = colour.shape[:2]
        at = uv[0] + a[index, None] * (uv[1] - uv[0]) + b[index, None] * (uv[3] - uv[0])
        x = np.clip(np.floor(at[:, 0] * cols).astype(np.int64), 0, cols - 1)
        y = np.clip(np.floor(at[:, 1] * rows).astype(np.int64), 0, rows - 1)
        shown = colour[y, x, 3] >= 128
        index, x, y = index[shown], x[shown], y[shown]
        depth = t[index]  # unit eye depth rays: t is the eye depth
        if offset:
            s0, s1 = payload.depth_range[q]
            scale = s0 + impostor.channels["normal"][page][y, x, 3] / 255.0 * (s1 - s0)
            moved = viewpoint + (h[index] - viewpoint) * scale[:, None]
            depth = (moved - eye) @ camera.forward
        best[index] = np.minimum(best[index], depth)
    return best.reshape(camera.resolution, camera.resolution)
