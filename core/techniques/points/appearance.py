"""The directional appearance of a point-based impostor's points: seed 001 §4.3 (Eq. 1) and §5.2.

Each point p_j gets a tile of ``tu x tv`` texels (the paper's 8 x 2) over the **sampling
rectangle**, the bounding rectangle of the polygon where the rays from the view cell to the part
cross the sampling plane (:class:`farfield.core.techniques.points.sampling.PointSampling`).  At run time a point shows
the bilinear look-up of its tile where the ray from the eye to the point crosses that plane
(§5.3, :mod:`farfield.core.render.points`); texel i of point j holds the weight

    c_ij = ∫∫∫ PIF(s, θ, x) q_j(s, θ, x) b_i(s) ds dθ dx          (Eq. 1)

estimated by Monte Carlo (§5.2) on the GL instead of the paper's ray tracer, one **view** at a time:

- a viewpoint s drawn in the view cell (a scrambled Sobol sequence over the box, seeded: equal
  inputs give equal tiles) and a camera at the baked resolution and field of view looking at the
  part, its direction jittered by up to half a pixel (θ: "a random camera orientation in which the
  point is in the frustum"; the part is in frame, so every point is);
- **visibility** v_j(s, θ): the points themselves drawn as one-pixel points with a z-buffer and an
  id per point (:meth:`~farfield.core.render.points.PointRenderer.render_ids`): a point counts in this view
  only where it wins its pixel, exactly as the runtime will show it;
- **the pixel footprint** q_j: the part's real geometry drawn with ``samples x samples`` samples per
  pixel (only the window of the image around the part) and filtered with a Gaussian of σ = 0.5
  pixel centred on each pixel's centre ("a Gaussian distribution centered over the pixel which the
  point projects to"), in linear light with the coverage as weight: the colour of what covers the
  footprint (uncovered samples, the background, carry no weight), and the **coverage**, the
  covered share of the footprint's weight, as alpha: a runtime composites a point over what lies
  behind the impostor with it, and the evaluation reads a pixel's colour as that of what covers it;
- **the viewpoint basis** b_i: the sample adds to each texel of the point's tile with the weight of
  a Gaussian (σ = :data:`TEXEL_SIGMA` texel) around the texel's centre, at the place (in texels)
  where the ray from s to the point crosses the sampling rectangle: the paper approximates the dual
  of the bilinear basis by a Gaussian (§4.3) and draws s from it; here s is drawn uniformly over
  the cell and weighted, which estimates the same normalised integral.

Each texel's estimate is the weighted mean of its samples, normalised by the visible samples'
weight.  Views are added in batches of :data:`BATCH` until the 95th percentile of the texels'
standard errors (of the linear luminance, over texels with at least two samples' worth of weight)
is at most ``error``, after at least ``min_views`` views (:data:`MIN_VIEWS` by default; the
first nine are the cell's corners and centre) and at most ``max_views``.  Texels
never reached keep the mean of the point's reached texels; points never visible keep the colour
they were sampled with.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
from scipy.stats import qmc

from farfield.core.colour_space import linear_to_srgb, srgb_to_linear
from farfield.core.errors import LayerPlanError
from farfield.core.render.points import PointRenderer
from farfield.core.render.raster import Camera, MeshRenderer, depth_bounds
from farfield.core.scene import SceneObject
from farfield.core.techniques.points.sampling import PointSampling
from farfield.core.viewcells import BoxCell, box_corners

MIN_VIEWS = 32
BATCH = 16
TEXEL_SIGMA = 0.5  # texels: the Gaussian of the viewpoint basis b_i
PIXEL_SIGMA = 0.5  # output pixels: the Gaussian of the pixel footprint q_j
MIN_WEIGHT = 1e-3  # a texel's Gaussian weight below this adds nothing
CHUNK = 65536  # points whose sums are turned into tiles (and standard errors) at a time
MAX_WINDOW = 4096  # pixels per side of one supersampled geometry window
WINDOW_STEP = 32  # window sides are multiples of this
_LUMA = np.array([0.2126, 0.7152, 0.0722])  # Rec. 709 / sRGB primaries

Progress = Callable[[int, int], None]  # (views done, most views)


@dataclass(frozen=True, slots=True)
class PointAppearance:
    """``tiles`` (n, tv, tu, 4) uint8 sRGB (row 0 at the rectangle's low v, column 0 at low u),
    alpha the covered share of the footprint over every view the point won a pixel in (at least
    1); ``seen`` (n,) bool: the point won a pixel whose footprint the part covers in some view;
    ``stats``: views, the final standard error, shares."""

    tiles: np.ndarray
    seen: np.ndarray
    stats: dict


def plane_coordinates(sampling: PointSampling, eye: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(n, 2) float64: where the rays from ``eye`` (3,) to ``points`` (n, 3) cross the sampling
    plane, in units of the sampling rectangle (0 at its low corner, 1 at its high one).

    >>> from farfield.core.techniques.points.sampling import plan_point_sampling
    >>> s = plan_point_sampling(BoxCell.from_center([0.0, 0.0, 0.0], 1.0), np.array([[-2.0, -2.0, 10.0], [2.0, 2.0, 12.0]]), 45.0, 64)
    >>> bool(np.all((plane_coordinates(s, np.array([0.5, 0.5, -0.5]), box_corners(np.array([[-2.0, -2.0, 10.0], [2.0, 2.0, 12.0]]))) >= -1e-9)))
    True
    """
    eye = np.asarray(eye, dtype=np.float64)
    d = np.asarray(points, dtype=np.float64) - eye
    t = (sampling.offset - sampling.normal @ eye) / (d @ sampling.normal)
    crossing = eye + t[:, None] * d
    lo, hi = sampling.rectangle
    return (np.stack([crossing @ sampling.u, crossing @ sampling.v], axis=1) - lo) / (hi - lo)


def texel_weights(coordinates: np.ndarray, tile: tuple[int, int]) -> np.ndarray:
    """(n, tv * tu) float64 the viewpoint basis b_i of every texel (row-major, v then u) at
    ``coordinates`` (n, 2) in rectangle units: a Gaussian of :data:`TEXEL_SIGMA` texels around
    each texel's centre, zero below :data:`MIN_WEIGHT`.

    >>> w = texel_weights(np.array([[0.5 / 8, 0.5 / 2]]), (8, 2))  # on texel (0, 0)'s centre
    >>> float(w[0, 0]), int(np.count_nonzero(w))
    (1.0, 4)
    """
    tu, tv = tile
    x = coordinates[:, 0:1] * tu - 0.5 - np.tile(np.arange(tu, dtype=np.float64), tv)[None, :]
    y = coordinates[:, 1:2] * tv - 0.5 - np.repeat(np.arange(tv, dtype=np.float64), tu)[None, :]
    w = np.exp(-(x * x + y * y) / (2.0 * TEXEL_SIGMA**2))
    return np.where(w >= MIN_WEIGHT, w, 0.0)


def footprint_filter(image: np.ndarray, samples: int) -> tuple[np.ndarray, np.ndarray]:
    """The pixel footprint q_j over an (h s, w s, 4) uint8 sRGB render with ``samples`` s per pixel
    side: ((h, w, 3) linear colour of what covers each pixel's Gaussian footprint (σ =
    :data:`PIXEL_SIGMA` pixel, centred on the pixel's centre, 1.5 pixels each way), (h, w) the
    covered share of the footprint's weight).  Colour is NaN where nothing covers it."""
    s = int(samples)
    h, w = image.shape[0] // s, image.shape[1] // s
    alpha = (image[..., 3] > 0).astype(np.float64)
    premultiplied = np.concatenate(
        [srgb_to_linear(image[..., :3] / 255.0) * alpha[..., None], alpha[..., None]], axis=2
    )
    offsets = np.arange(3 * s) - (3 * s - 1) / 2.0  # sample centres relative to the pixel's centre
    kernel = np.exp(-((offsets / s) ** 2) / (2.0 * PIXEL_SIGMA**2))
    kernel /= kernel.sum()
    padded = np.pad(premultiplied, ((s, s), (s, s), (0, 0)))
    rows = sum(kernel[k] * padded[k : k + h * s : s] for k in range(3 * s))  # (h, W + 2s, 4)
    both = sum(kernel[k] * rows[:, k : k + w * s : s] for k in range(3 * s))  # (h, w, 4)
    cover = both[..., 3]
    with np.errstate(invalid="ignore", divide="ignore"):
        colour = both[..., :3] / cover[..., None]
    return np.where(cover[..., None] > 0.0, colour, np.nan), cover


def _view_camera(
    eye: np.ndarray, target: np.ndarray, jitter: np.ndarray, fov: float, resolution: int, extent: np.ndarray
) -> Camera:
    """The output camera at ``eye`` looking at ``target`` moved by ``jitter`` (2,) pixels."""
    base = Camera.look_at(eye, target, fov, resolution, 1.0, 2.0)
    pixel = 2.0 * math.tan(0.5 * fov) / resolution * float(np.linalg.norm(target - eye))
    moved = target + pixel * (jitter[0] * base.right + jitter[1] * base.up)
    forward = (moved - eye) / np.linalg.norm(moved - eye)
    near, far = depth_bounds(eye, forward, extent)
    return Camera.look_at(eye, moved, fov, resolution, near, far)


def _extent(objects, points: np.ndarray) -> np.ndarray:
    """(8, 3) the corners of the box holding ``objects`` and ``points``."""
    bounds = np.stack([points.min(axis=0), points.max(axis=0)]) if points.shape[0] else np.zeros((2, 3))
    return box_corners(
        np.stack(
            [
                np.minimum(bounds[0], np.min([o.bounds[0] for o in objects], axis=0)),
                np.maximum(bounds[1], np.max([o.bounds[1] for o in objects], axis=0)),
            ]
        )
    )


def _views(cell: BoxCell, seed: int, max_views: int) -> Iterator[np.ndarray]:
    """Batches (k, 5) of the Monte Carlo views, each a viewpoint in the cell (3, box units) and a
    jitter (2, pixels + 0.5): the cell's corners and centre first (where views differ most), then
    a scrambled Sobol sequence seeded by ``seed``, :data:`BATCH` at a time, ``max_views`` in all."""
    sobol = qmc.Sobol(5, scramble=True, seed=seed)
    fixed = np.concatenate(
        [np.array(np.meshgrid([0.0, 1.0], [0.0, 1.0], [0.0, 1.0], indexing="ij")).reshape(3, -1).T, [[0.5, 0.5, 0.5]]]
    )
    views = 0
    while views < max_views:
        batch = sobol.random(BATCH)[: max_views - views]
        if views < fixed.shape[0]:
            batch[: fixed.shape[0] - views, :3] = fixed[views : views + batch.shape[0]]
        yield batch
        views += batch.shape[0]


def _window(q: np.ndarray, cell: BoxCell, target: np.ndarray, fov: float, resolution: int, extent: np.ndarray):
    """(eye, camera, x0, y0, size) of view ``q``: the square window of its image around the part."""
    eye = cell.lo + q[:3] * (cell.hi - cell.lo)
    camera = _view_camera(eye, target, q[3:] - 0.5, fov, resolution, extent)
    pixels = camera.project(extent)
    x0, y0 = np.floor(pixels.min(axis=0)).astype(int) - 2
    # Window sides rounded up to WINDOW_STEP, so the renderers keep a few targets.
    size = -(-(int(np.ceil(float(np.max(pixels.max(axis=0) - pixels.min(axis=0))))) + 5) // WINDOW_STEP) * WINDOW_STEP
    if size > MAX_WINDOW:
        raise LayerPlanError(
            f"the part spans {size} pixels from the view cell at {resolution} px (at most {MAX_WINDOW}): "
            "lower the resolution, or split the part"
        )
    return eye, camera, int(x0), int(y0), size


def integrate_appearance(
    objects: list[SceneObject] | tuple[SceneObject, ...],
    points: np.ndarray,
    fallback: np.ndarray,
    sampling: PointSampling,
    cell: BoxCell,
    fov_deg: float,
    resolution: int,
    tile: tuple[int, int] = (8, 2),
    samples: int = 4,
    error: float = 0.01,
    max_views: int = 256,
    min_views: int = MIN_VIEWS,
    seed: int = 0,
    progress: Progress | None = None,
) -> PointAppearance:
    """The tiles of ``points`` (n, 3) float64 (module docstring): ``objects`` the part's geometry,
    ``fallback`` (n, 4) uint8 sRGB the colour a never-visible point keeps, the others as for
    :func:`farfield.core.techniques.points.samples.gather_point_samples`; ``samples`` per pixel side of the footprint's
    geometry, ``error`` the standard error to stop at (linear luminance, 0-1), ``max_views`` the
    most views, ``min_views`` the fewest (every view also judges which points are ever visible:
    :attr:`PointAppearance.seen`).  The accumulators are float32, 28 bytes per texel (weight, its
    square, colour, coverage and its weight, luminance squared): 448 bytes a point at 8 x 2 texels."""
    start = time.perf_counter()
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n = points.shape[0]
    tu, tv = (int(t) for t in tile)
    texels = tu * tv
    if max_views < 1 or samples < 1 or not error > 0.0:
        raise LayerPlanError(
            f"appearance needs max_views >= 1, samples >= 1 and error > 0, got {max_views}, {samples}, {error}"
        )
    fov = math.radians(float(fov_deg))
    extent = _extent(objects, points)
    target = 0.5 * (extent.min(axis=0) + extent.max(axis=0))
    f32 = np.float32
    weight = np.zeros((n, texels), f32)
    weight2 = np.zeros((n, texels), f32)
    colour = np.zeros((n, texels, 3), f32)
    coverage = np.zeros((n, texels), f32)
    coverage_weight = np.zeros((n, texels), f32)
    luma2 = np.zeros((n, texels), f32)
    luma = _LUMA.astype(f32)
    views = 0
    se95 = float("inf")
    with MeshRenderer(objects) as geometry, PointRenderer(points, np.zeros((n, 4), np.uint8)) as ids:
        for batch in _views(cell, seed, max_views if n else 0):
            for q in batch:
                eye, camera, x0, y0, size = _window(q, cell, target, fov, resolution, extent)
                s = max(1, min(int(samples), MAX_WINDOW // size))
                drawn = ids.render_ids(camera.window(x0, y0, size, size))
                linear, cover = footprint_filter(geometry.render(camera.window(x0, y0, size, size * s)), s)
                row, col = np.nonzero(drawn >= 0)  # each point wins at most one pixel
                j = drawn[row, col]
                w = texel_weights(plane_coordinates(sampling, eye, points[j]), (tu, tv))
                coverage[j] += w * cover[row, col][:, None]  # the coverage counts every view a point wins
                coverage_weight[j] += w
                covered = cover[row, col] > 0.0  # the colour, those where something covers its footprint
                j, w, seen_colour = j[covered], w[covered], linear[row[covered], col[covered]]
                weight[j] += w
                weight2[j] += w * w
                colour[j] += w[..., None] * seen_colour[:, None, :]
                luma2[j] += w * (seen_colour @ _LUMA)[:, None] ** 2
            views += batch.shape[0]
            if progress is not None:
                progress(views, max_views)
            se95 = _standard_error_p95(weight, weight2, colour, luma2, luma)
            if views >= min_views and se95 <= error:
                break
    fallback_linear = srgb_to_linear(np.asarray(fallback, dtype=np.float64)[:, :3] / 255.0)
    tiles = np.zeros((n, texels, 4), np.uint8)
    seen = np.zeros(n, dtype=bool)
    for lo in range(0, n, CHUNK):  # the float64 arithmetic a chunk of points at a time
        part = slice(lo, lo + CHUNK)
        tiles[part], seen[part] = _tiles(
            weight[part].astype(np.float64), colour[part].astype(np.float64),
            coverage[part].astype(np.float64), coverage_weight[part].astype(np.float64), fallback_linear[part],
        )  # fmt: skip
    stats = {
        "views": views,
        "standard_error_p95": se95 if math.isfinite(se95) else None,
        "points_seen_share": float(seen.mean()) if n else 0.0,
        "texels_reached_share": float((weight > 0.0).mean()) if n else 0.0,
        "seconds": time.perf_counter() - start,
    }
    return PointAppearance(tiles.reshape(n, tv, tu, 4), seen, stats)


def _standard_error_p95(weight, weight2, colour, luma2, luma) -> float:
    """The 95th percentile of the texels' standard errors of the linear luminance, over texels
    with at least two samples' worth of weight (module docstring), a chunk of points at a time."""
    judged = []
    for lo in range(0, weight.shape[0], CHUNK):
        part = slice(lo, lo + CHUNK)
        w = weight[part].astype(np.float64)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean_luma = (colour[part] @ luma).astype(np.float64) / w
            variance = np.maximum(luma2[part] / w - mean_luma**2, 0.0)
            effective = w**2 / weight2[part]
            standard = np.sqrt(variance / effective)
        judged.append(standard[effective >= 2.0])
    values = np.concatenate(judged) if judged else np.zeros(0)
    return float(np.percentile(values, 95)) if values.size else float("inf")


def _tiles(weight, colour, coverage, coverage_weight, fallback_linear) -> tuple[np.ndarray, np.ndarray]:
    """((m, texels, 4) uint8 sRGB tiles, (m,) bool seen) of a chunk of points' sums (module
    docstring: texels never reached keep the mean of the point's reached texels; points never
    visible keep their fallback colour)."""
    reached = weight > 0.0
    seen = reached.any(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        texel_colour = colour / weight[..., None]
        texel_cover = coverage / coverage_weight
        point_mean = colour.sum(axis=1) / weight.sum(axis=1)[:, None]  # the point's mean over its samples
        point_cover = coverage.sum(axis=1) / coverage_weight.sum(axis=1)
    point_mean = np.where(seen[:, None], point_mean, fallback_linear)
    point_cover = np.where(seen, point_cover, 1.0)
    texel_colour = np.where(reached[..., None], texel_colour, point_mean[:, None, :])
    texel_cover = np.where(coverage_weight > 0.0, texel_cover, point_cover[:, None])
    rgb = np.rint(np.clip(linear_to_srgb(texel_colour), 0.0, 1.0) * 255.0).astype(np.uint8)
    alpha = np.clip(np.rint(texel_cover * 255.0), 1, 255).astype(np.uint8)  # a point covers at least 1/255
    return np.concatenate([rgb, alpha[..., None]], axis=2), seen


def single_colour(tiles: np.ndarray, threshold: float) -> np.ndarray:
    """(n,) bool: the points whose tile varies less than ``threshold`` (the standard deviation of
    its texels, sRGB levels 0-255, largest over R, G, B and alpha): §5.3's compression stores one colour for
    them.

    >>> tiles = np.zeros((2, 2, 8, 4), np.uint8); tiles[1, 0, 0, 0] = 200
    >>> single_colour(tiles, 2.0).tolist()
    [True, False]
    """
    flat = tiles.reshape(tiles.shape[0], -1, 4).astype(np.float64)
    return flat.std(axis=1).max(axis=1, initial=0.0) < float(threshold) if flat.size else np.zeros(tiles.shape[0], bool)


def mean_colour(tiles: np.ndarray) -> np.ndarray:
    """(n, 4) uint8 sRGB: each tile's mean colour, averaged in linear light, and mean alpha."""
    flat = tiles.reshape(tiles.shape[0], -1, 4) / 255.0
    rgb = np.rint(np.clip(linear_to_srgb(srgb_to_linear(flat[..., :3]).mean(axis=1)), 0.0, 1.0) * 255.0).astype(
        np.uint8
    )
    alpha = np.clip(np.rint(flat[..., 3].mean(axis=1) * 255.0), 1, 255).astype(np.uint8)
    return np.concatenate([rgb, alpha[:, None]], axis=1)
