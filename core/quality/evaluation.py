"""Evaluation of an impostor against the real geometry: per-viewpoint pixel counts, colour errors and SSIM.

From sampled viewpoints (the view cell's corners, the reference viewpoint and seeded random points
inside; optionally points outside) the part's geometry and the impostor are rendered by the same
renderer at the impostor's output resolution and field of view, looking at the part's centre.
Coverage is measured as area: both are rendered with ``samples x samples`` samples per pixel and
a pixel counts as covered when any of its samples is (with one sample per pixel, sub-pixel detail
such as a trunk thinner than a pixel drops in and out of both renders by aliasing alone; the
one-sample hole count is reported too, as ``hole_pixels_1spp``).  Colours are the mean of a
pixel's covered samples.

hole pixels (``hole_pixels``)
    covered by the geometry with no impostor coverage within one pixel (the guarantee: zero inside
    the view cell), confirmed at fine sampling (below);
bloat pixels (``bloat_pixels``)
    covered by the impostor only; ``bloat_beyond_1px``: those with no geometry within one pixel,
    confirmed at fine sampling (the guarantee allows none of those either); a vertex of an opaque
    object counts as geometry in its pixel even where no sample sees it (:func:`vertex_pixels`);
fine confirmation
    at ``samples x samples`` per pixel a needle or twig narrower than the gap between two samples
    can fall between all of them in its own pixel and its eight neighbours, while the impostor,
    recorded without gaps, rightly keeps it: the coarse count then calls an impostor pixel "bloated
    beyond one pixel" next to geometry that is there (the scrub pine's layered impostor at 512 px,
    4 x 4 samples: 232 such pixels over 13 viewpoints; at 36 x 36 samples every one of them has
    needles within one pixel, some covering ~0.3 % of a pixel).  So each coarse candidate is
    checked again with the other side drawn much more finely, only around the candidates: they are
    grouped in blocks of :data:`CONFIRM_BLOCK` x :data:`CONFIRM_BLOCK` pixels, and for each block
    the other side is drawn through an off-axis camera (:meth:`Camera.window
    <farfield.core.render.raster.Camera.window>`: the same eye and image plane) over exactly that
    block and a one-pixel margin, at ``f x f`` samples per pixel, ``f`` the smallest odd multiple
    of ``samples`` of at least :data:`CONFIRM_SAMPLES` (36 for 4; odd, so that the fine samples
    include the coarse ones).  A candidate counts only if none of the fine samples in its 3 x 3
    neighbourhood is covered.  The work grows with the blocks holding candidates, not with the
    image, and is capped at ``confirm_windows`` blocks per viewpoint and side (densest first): the
    candidates of blocks beyond the cap count without confirmation, and their number is reported
    (``hole_pixels_unconfirmed``, ``bloat_beyond_1px_unconfirmed``; :func:`compare_images` given
    no renderer to confirm with leaves every candidate unconfirmed).  The coarse counts are kept as
    ``hole_pixels_coarse`` and ``bloat_beyond_1px_coarse``.

    Holes are re-checked the same way, the impostor drawn finely around them: the guarantee is
    symmetric (no geometry farther than one pixel from the impostor, no impostor farther than one
    pixel from the geometry), and a coarse hole can be the same artefact the other way round, an
    impostor sliver between the samples.  A coarse hole's own pixel needs no finer look (one of its
    geometry samples is covered already).  Neither figure finds what the coarse sampling missed
    altogether (geometry or impostor between all the samples of a pixel, far from the other side);
    that would need the whole image drawn finely;
colour error (``colour_error_mean``, ``colour_error_p99``, ``colour_error_max``)
    where both cover, the difference of the two pixels (max over RGB, 0..255): its mean, 99th
    percentile and maximum.  This is what a viewer sees: a fringe or a uniform colour shift counts
    in full wherever it is;
colour error within one pixel (``colour_error_1px_mean``, ``colour_error_1px_max``)
    the smallest difference between the geometry's pixel and the impostor's pixels within one pixel
    (the one-pixel parallax tolerance).  A secondary figure: it forgives an edge displaced by one
    pixel, but also hides a shifted colour that some neighbour happens to match;
SSIM (``ssim``)
    the structural similarity of the two images (Wang et al. 2004, scikit-image's
    ``structural_similarity`` with its Gaussian 11-tap window, sigma 1.5, per RGB channel, averaged
    over channels) averaged over the union of both coverages: 1 when equal, lower as luminance,
    contrast or structure differ.  Uncovered pixels show :data:`BACKGROUND` (mid grey) in both
    images, as if the part stood in front of a neutral backdrop: a hole or a bloated pixel then
    differs from its counterpart by its own colour against grey, never vanishing against a black or
    white one; pixels neither image covers are left out of the average, so the empty frame around a
    small part does not dilute it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from skimage.metrics import structural_similarity

from farfield.core.colour_space import linear_to_srgb, srgb_to_linear
from farfield.core.impostor.impostor import Impostor
from farfield.core.render.points import Appearance
from farfield.core.render.raster import Camera, MeshRenderer, depth_bounds
from farfield.core.scene import Scene, SceneObject
from farfield.core.viewcells import BoxCell, ShaftCell, SphereOutsideCell, ViewCell, box_corners


def impostor_objects(impostor: Impostor) -> list[SceneObject]:
    """The impostor as drawable objects, alpha-cut at 0.5: one per atlas page with geometry
    (its payload's :meth:`~farfield.core.impostor.impostor.Payload.draw_objects`).

    A quad payload gives two triangles per quad, one after the other; a mesh payload its triangles, with the vertices
    they use.  Either way a page's triangles are drawn in payload order.  TypeError for a payload
    that is not drawn as triangles (points, LDI samples).
    """
    objects = impostor.payload.draw_objects(impostor)
    if objects is None:
        raise TypeError(f"no renderer for a {impostor.payload.kind!r} payload")
    return objects


def impostor_renderer(impostor: Impostor) -> MeshRenderer:
    """The renderer that draws ``impostor`` as its runtime does, its payload's
    (:meth:`~farfield.core.impostor.impostor.Payload.renderer`): its textured triangles
    (:func:`impostor_objects`), an LDI's samples as splats (:class:`farfield.core.render.splats.SplatRenderer`), or its points with their directional colours at the baked
    resolution's pixels (:class:`farfield.core.render.points.PointRenderer`)."""
    return impostor.payload.renderer(impostor)


def point_appearance(impostor: Impostor) -> Appearance:
    """The :class:`farfield.core.render.points.Appearance` of a point impostor's payload and pages."""
    return impostor.payload.appearance(impostor.pages)


def _grow(mask: np.ndarray, pixels: int) -> np.ndarray:
    """(h, w) bool grown by ``pixels`` in all eight directions (a square of side 2 pixels + 1)."""
    for _ in range(pixels):
        mask = _dilate(mask)
    return mask


def _dilate(mask: np.ndarray) -> np.ndarray:
    """(h, w) bool grown by one pixel in all eight directions."""
    out = mask.copy()
    out[1:] |= mask[:-1]
    out[:-1] |= mask[1:]
    grown = out.copy()
    grown[:, 1:] |= out[:, :-1]
    grown[:, :-1] |= out[:, 1:]
    return grown


_LINEAR = srgb_to_linear(np.arange(256) / 255.0).astype(np.float32)  # sRGB byte -> linear


def downsample(image: np.ndarray, samples: int) -> np.ndarray:
    """(h, w, 4) uint8 pixels of an (h*s, w*s, 4) render: alpha 255 if any sample is covered, RGB
    the mean of the covered samples in linear light, sRGB-encoded and rounded (what a pixel
    resolved from those samples shows; :mod:`farfield.core.colour_space`)."""
    if samples == 1:
        return image
    h, w = image.shape[0] // samples, image.shape[1] // samples
    covered = image[..., 3] > 0
    masked = _LINEAR[image[..., :3]] * covered[..., None]
    # One strided slice per sample position: a reduction over the reshaped (h, s, w, s) axes took
    # five times as long (most of an evaluation at 512 px).
    rgb = np.zeros((h, w, 3), dtype=np.float32)
    count = np.zeros((h, w), dtype=np.uint32)
    for dy in range(samples):
        for dx in range(samples):
            rgb += masked[dy::samples, dx::samples]
            count += covered[dy::samples, dx::samples]
    out = np.zeros((h, w, 4), dtype=np.uint8)
    out[..., :3] = np.round(linear_to_srgb(rgb / np.maximum(count, 1)[..., None]) * 255.0).astype(np.uint8)
    out[..., 3] = np.where(count > 0, 255, 0)
    return out


def _holes(g: np.ndarray, i: np.ndarray) -> np.ndarray:
    """(h, w) bool: covered by the geometry with no impostor coverage within one pixel."""
    return g & ~_dilate(i)


# What an uncovered pixel shows in SSIM's images (0..255 per channel): a neutral mid grey.
BACKGROUND = 128.0
# SSIM's window: Gaussian, sigma 1.5, 11 taps (Wang et al. 2004, Sec. III-C); smaller images use
# the largest odd window that fits (the Gaussian filter is the same; only the check differs).
SSIM_SIGMA = 1.5
SSIM_WINDOW = 11


def ssim_over_union(geometry: np.ndarray, impostor: np.ndarray) -> float:
    """SSIM of two (h, w, 4) uint8 images over the union of their coverage (see the module docstring).

    Uncovered pixels are shown as :data:`BACKGROUND`; 1.0 when neither covers anything.

    >>> a = np.zeros((16, 16, 4), np.uint8); a[4:12, 4:12] = (200, 40, 40, 255)
    >>> ssim_over_union(a, a)
    1.0
    >>> b = a.copy(); b[4:12, 4:12, :3] = (170, 10, 10)  # the same shape, every channel 30 darker
    >>> round(ssim_over_union(a, b), 3)
    0.837
    >>> ssim_over_union(a, np.zeros_like(a)) < 0.5  # the impostor shows nothing
    True
    >>> ssim_over_union(np.zeros_like(a), np.zeros_like(a))
    1.0
    """
    union = (geometry[..., 3] > 0) | (impostor[..., 3] > 0)
    if not union.any():
        return 1.0

    def backdrop(image):
        # float32: scikit-image then filters in float32, about twice as fast; SSIM needs no more digits.
        return np.where(image[..., 3:4] > 0, image[..., :3], BACKGROUND).astype(np.float32)

    # Only the union's bounding box and a window's margin: the Gaussian filter (radius 5) reaches no
    # farther, so the values over the union are those of the whole frame, for less work.
    rows, cols = np.flatnonzero(union.any(axis=1)), np.flatnonzero(union.any(axis=0))
    box = (
        slice(max(rows[0] - SSIM_WINDOW, 0), rows[-1] + SSIM_WINDOW + 1),
        slice(max(cols[0] - SSIM_WINDOW, 0), cols[-1] + SSIM_WINDOW + 1),
    )
    union = union[box]
    side = min(union.shape)
    window = min(SSIM_WINDOW, side if side % 2 else side - 1)
    _, full = structural_similarity(
        backdrop(geometry[box]), backdrop(impostor[box]), data_range=255.0, channel_axis=2, gaussian_weights=True,
        sigma=SSIM_SIGMA, use_sample_covariance=False, win_size=window, full=True,
    )  # fmt: skip
    return float(full.mean(axis=2)[union].mean())


def _channels(image: np.ndarray, count: int = 3) -> list[np.ndarray]:
    """The first ``count`` channels of an (h, w, 4) uint8 image as contiguous (h, w) int16 arrays."""
    return [image[..., c].astype(np.int16) for c in range(count)]


def _difference(a: list[np.ndarray], b: list[np.ndarray]) -> np.ndarray:
    """(h, w) int16: the largest of the absolute differences of the three channel arrays ``a`` and ``b``."""
    out = np.abs(a[0] - b[0])
    for c in (1, 2):
        np.maximum(out, np.abs(a[c] - b[c]), out=out)  # per channel: a max over a last axis of 3 is 6x slower
    return out


def _within_one_pixel(geometry: np.ndarray, impostor: np.ndarray) -> np.ndarray:
    """(h, w) int16: per pixel, the smallest difference (max over RGB) between the geometry's pixel
    and the covered impostor pixels within one pixel (255 when none is covered)."""
    g = _channels(geometry)
    h, w = geometry.shape[:2]
    padded = _channels(np.pad(impostor, ((1, 1), (1, 1), (0, 0))), 4)
    best = np.full((h, w), 255, dtype=np.int16)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            window = (slice(1 + dy, 1 + dy + h), slice(1 + dx, 1 + dx + w))
            diff = _difference(g, [c[window] for c in padded[:3]])
            diff[padded[3][window] == 0] = 255
            np.minimum(best, diff, out=best)
    return best


def _covered_window(geometry: np.ndarray, impostor: np.ndarray, samples: int) -> tuple[slice, slice]:
    """The part of two (h*s, w*s, 4) renders that :func:`compare_images` needs: the bounding box of
    their coverage in whole pixels, grown by :data:`SSIM_WINDOW` pixels (clipped to the frame).

    Everything outside is uncovered in both: it adds no hole, bloat or colour error, and SSIM's
    filter does not reach past the margin; leaving it out saves most of the downsampling when the
    part fills a fraction of the frame.
    """
    covered = (geometry[..., 3] > 0) | (impostor[..., 3] > 0)
    rows, cols = np.flatnonzero(covered.any(axis=1)), np.flatnonzero(covered.any(axis=0))
    if rows.size == 0:
        return slice(0, 0), slice(0, 0)
    h, w = covered.shape[0] // samples, covered.shape[1] // samples

    def span(first: int, last: int, size: int) -> slice:
        return slice(
            max(first // samples - SSIM_WINDOW, 0) * samples, min(last // samples + 1 + SSIM_WINDOW, size) * samples
        )

    return span(rows[0], rows[-1], h), span(cols[0], cols[-1], w)


# Confirming coarse holes and bloat beyond one pixel (module docstring): at least this many
# samples per pixel side, in windows of this many pixels a side (and a one-pixel margin), at most
# this many windows per viewpoint and side.
CONFIRM_SAMPLES = 32
CONFIRM_BLOCK = 8
CONFIRM_WINDOWS = 64


def fine_samples(samples: int) -> int:
    """Samples per pixel side when confirming: the smallest odd multiple of ``samples`` that is at
    least :data:`CONFIRM_SAMPLES` (odd, so the fine samples include the coarse ones).

    >>> fine_samples(4), fine_samples(2), fine_samples(1), fine_samples(64)
    (36, 34, 33, 64)
    """
    k = max(1, -(-CONFIRM_SAMPLES // samples))
    return samples * (k if k % 2 else k + 1)


# confirm(side, x0, y0, size) -> (size, size) bool: per pixel of the square of the evaluated image
# from pixel (x0, y0) (x right, y down), whether ``side`` ("geometry" | "impostor") covers any of
# its fine samples there.
Confirm = Callable[[str, int, int, int], np.ndarray]


def _confirmed(
    candidates: np.ndarray, side: str, origin: tuple[int, int], confirm: Confirm | None, windows: int
) -> tuple[int, int]:
    """(counted, unconfirmed) of the (h, w) bool ``candidates`` (pixels with no coarse coverage of
    ``side`` within one pixel; ``origin``: the image pixel (x, y) of their [0, 0]): a candidate
    counts unless ``confirm`` finds ``side`` within one pixel of it; those of the blocks beyond the
    first ``windows`` (densest first) count unconfirmed."""
    ys, xs = np.nonzero(candidates)
    if ys.size == 0 or confirm is None or windows <= 0:
        return int(ys.size), int(ys.size)
    b = CONFIRM_BLOCK
    columns = candidates.shape[1] // b + 1
    keys, counts = np.unique((ys // b) * columns + xs // b, return_counts=True)
    order = np.lexsort((keys, -counts))  # the densest blocks first, then in reading order
    counted = unconfirmed = 0
    for n, key in enumerate(keys[order]):
        y0, x0 = int(key // columns) * b, int(key % columns) * b
        block = candidates[y0 : y0 + b, x0 : x0 + b]
        if n >= windows:
            unconfirmed += int(block.sum())
            continue
        covered = np.asarray(confirm(side, origin[0] + x0 - 1, origin[1] + y0 - 1, b + 2), dtype=bool)
        near = _dilate(covered)[1 : 1 + block.shape[0], 1 : 1 + block.shape[1]]
        counted += int((block & ~near).sum())
    return counted + unconfirmed, unconfirmed


def compare_images(geometry: np.ndarray, impostor: np.ndarray, samples: int = 1, confirm: Confirm | None = None, confirm_windows: int = CONFIRM_WINDOWS,
                   reach: Callable[[], np.ndarray] | None = None, budget_px: float = 1.0) -> dict:  # fmt: skip
    """Pixel statistics of two (h*s, w*s, 4) uint8 renders (geometry first) with ``samples`` s per
    pixel side; see the module docstring.  ``confirm`` draws either side finely around coarse holes
    and bloat beyond one pixel (at most ``confirm_windows`` blocks per side); without it they count
    as found, all unconfirmed.  ``reach`` gives the (h, w) pixels the geometry reaches however small
    it is (:func:`vertex_pixels`); called only when there are candidates for bloat beyond one pixel,
    whose geometry side it widens.

    ``budget_px`` is the error budget the impostor was baked for (``max_error_px``):
    ``hole_pixels_beyond_budget`` counts geometry pixels with no impostor pixel within
    ``ceil(budget_px) - 1`` pixels and ``bloat_beyond_budget`` impostor pixels with no geometry
    within ``ceil(budget_px)``; at 1 they are ``hole_pixels`` and ``bloat_beyond_1px`` (confirmed),
    above it coarse counts (an overestimate at worst).

    An impostor whose colours are all 30 darker, over a ramp that rises by 30 a column: each
    pixel's right-hand neighbour holds its old colour, so the within-one-pixel figure sees an error
    in the last column only, the per-pixel one sees 30 everywhere.

    >>> g = np.full((8, 8, 4), 255, np.uint8); g[..., :3] = (30 + 30 * np.arange(8))[None, :, None]
    >>> i = g.copy(); i[..., :3] -= 30
    >>> s = compare_images(g, i)
    >>> s["colour_error_mean"], s["colour_error_p99"], s["colour_error_max"], s["colour_error_1px_mean"]
    (30.0, 30.0, 30, 3.75)
    >>> s["hole_pixels"], s["bloat_beyond_1px"], s["both_pixels"]
    (0, 0, 64)

    Nothing covered by both: no colour error to measure (zeros).

    >>> e = compare_images(np.zeros((8, 8, 4), np.uint8), np.zeros((8, 8, 4), np.uint8))
    >>> e["colour_error_mean"], e["colour_error_p99"], e["ssim"]
    (0.0, 0.0, 1.0)
    """
    window = _covered_window(geometry, impostor, samples)
    geometry, impostor = geometry[window], impostor[window]
    one = _holes(
        geometry[samples // 2 :: samples, samples // 2 :: samples, 3] > 0,
        impostor[samples // 2 :: samples, samples // 2 :: samples, 3] > 0,
    )
    geometry, impostor = downsample(geometry, samples), downsample(impostor, samples)
    g = geometry[..., 3] > 0
    i = impostor[..., 3] > 0
    holes = _holes(g, i)
    beyond = i & ~_dilate(g)
    origin = (window[1].start // samples, window[0].start // samples)
    if (
        reach is not None and beyond.any()
    ):  # geometry smaller than a sample (a part far away) reaches pixels no sample covers
        beyond &= ~_dilate(reach()[origin[1] : origin[1] + g.shape[0], origin[0] : origin[0] + g.shape[1]])
    hole_count, hole_unconfirmed = _confirmed(holes, "impostor", origin, confirm, confirm_windows)
    beyond_count, beyond_unconfirmed = _confirmed(beyond, "geometry", origin, confirm, confirm_windows)
    holes_budget, beyond_budget = hole_count, beyond_count
    if budget_px > 1.0:
        k = math.ceil(budget_px - 1e-9)
        holes_budget = int((g & ~_grow(i, k - 1)).sum())
        widened = _grow(g, k)
        if reach is not None:
            widened |= _grow(reach()[origin[1] : origin[1] + g.shape[0], origin[0] : origin[0] + g.shape[1]], k)
        beyond_budget = int((i & ~widened).sum())
    bloat = i & ~g
    both = g & i
    errors = _difference(_channels(geometry), _channels(impostor))[both]
    nearest = _within_one_pixel(geometry, impostor)[both]
    return {
        "geometry_pixels": int(g.sum()),
        "impostor_pixels": int(i.sum()),
        "both_pixels": int(both.sum()),
        "hole_pixels": hole_count,
        "hole_pixels_coarse": int(holes.sum()),
        "hole_pixels_unconfirmed": hole_unconfirmed,
        "hole_pixels_1spp": int(one.sum()),
        "bloat_pixels": int(bloat.sum()),
        "bloat_beyond_1px": beyond_count,
        "bloat_beyond_1px_coarse": int(beyond.sum()),
        "bloat_beyond_1px_unconfirmed": beyond_unconfirmed,
        "error_budget_px": float(budget_px),
        "hole_pixels_beyond_budget": holes_budget,
        "bloat_beyond_budget": beyond_budget,
        "colour_error_mean": float(errors.mean()) if errors.size else 0.0,
        "colour_error_p99": float(np.percentile(errors, 99)) if errors.size else 0.0,
        "colour_error_max": int(errors.max()) if errors.size else 0,
        "colour_error_1px_mean": float(nearest.mean()) if nearest.size else 0.0,
        "colour_error_1px_max": int(nearest.max()) if nearest.size else 0,
        "ssim": ssim_over_union(geometry, impostor),
    }


def vertex_pixels(objects, camera: Camera, samples: int = 1) -> np.ndarray:
    """(r, r) bool, r = ``camera.resolution // samples``: the pixels (of ``samples`` x ``samples``
    camera pixels each, top row first) holding a vertex of an opaque object in front of ``camera``.

    Geometry is there however small it is: a part whose triangles fall between every sample of a
    pixel (a whole object at 100 km, 0.003 pixels wide) still lies at its vertices, and an
    impostor pixel within one pixel of them keeps the promise.  Alpha-cut objects are left out: a
    card's corners may be cut away.

    >>> c = Camera.look_at(np.zeros(3), np.array([0.0, 1.0, 0.0]), math.radians(90.0), 8, 0.1, 10.0)
    >>> from farfield.core.scene import SceneObject
    >>> tiny = SceneObject("tiny", np.array([[0.51, 1.0, 0.3], [0.52, 1.0, 0.3], [0.51, 1.0, 0.31]]), np.array([[0, 1, 2]]))
    >>> np.argwhere(vertex_pixels([tiny], c, samples=2)).tolist()  # x 6.04-6.08, y 2.76-2.8 of 8 -> pixel (row 1, col 3) of 4
    [[1, 3]]
    """
    size = camera.resolution // samples
    reached = np.zeros((size, size), dtype=bool)
    frame = np.stack([camera.right, camera.up, camera.forward]).T
    for obj in objects:
        if obj.alpha_cutoff is not None:
            continue
        depth = (obj.vertices - camera.eye) @ frame[:, 2]
        front = obj.vertices[(depth >= camera.near) & (depth <= camera.far)]
        if not front.size:
            continue
        pixel = np.floor(camera.project(front) / samples).astype(np.int64)
        inside = np.all((pixel >= 0) & (pixel < size), axis=1)
        reached[pixel[inside, 1], pixel[inside, 0]] = True
    return reached


def _window_coverage(renderers: dict[str, MeshRenderer], camera: Camera, samples: int) -> Confirm:
    """A :data:`Confirm` drawing ``renderers[side]`` through windows of ``camera`` (whose image has
    ``samples`` pixels per side of an evaluated pixel) at :func:`fine_samples` per pixel side."""
    fine = fine_samples(samples)

    def coverage(side: str, x0: int, y0: int, size: int) -> np.ndarray:
        window = camera.window(x0 * samples, y0 * samples, size * samples, size * fine)
        covered = renderers[side].render(window)[..., 3] > 0
        return covered.reshape(size, fine, size, fine).any(axis=(1, 3))

    return coverage


def outside_viewpoints(cell: ViewCell, count: int, seed: int = 0) -> np.ndarray:
    """(count, 3) float64 points just outside ``cell``: its centre pushed 0.6-1.5 cell sizes sideways
    (an outside-sphere cell's: nearer its centre than its radius)."""
    rng = np.random.default_rng(seed)
    if isinstance(cell, SphereOutsideCell):  # nearer than its radius: 0.6-0.95 of it
        direction = rng.normal(size=(count, 3))
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        if cell.hemisphere:
            direction[:, 2] = np.abs(direction[:, 2])
        return cell.centre + direction * cell.radius * rng.uniform(0.6, 0.95, size=(count, 1))
    if isinstance(cell, BoxCell):
        centre, size = cell.center, float(np.max(cell.size))
    else:
        centre, size = cell.center, 2.0 * cell.half_width(cell.min_distance)
    direction = rng.normal(size=(count, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    points = centre + direction * size * rng.uniform(0.9, 1.5, size=(count, 1))
    return points[~cell.contains(points)]


@dataclass(frozen=True, slots=True)
class Evaluation:
    """Per-viewpoint results and totals of one evaluation."""

    viewpoints: list[dict]  # each: position, kind ("corner" | "reference" | "random" | "outside"), inside, stats
    totals: (
        dict  # inside the view cell (see _totals): sums, pooled means, maxima, SSIM; outside: the same under "outside"
    )
    impostor: dict = field(default_factory=dict)  # layers, quads, memory, generation seconds
    seconds: float = 0.0

    def to_dict(self) -> dict:
        return {
            "viewpoints": self.viewpoints,
            "totals": self.totals,
            "impostor": self.impostor,
            "seconds": self.seconds,
        }


def _totals(rows: list[dict]) -> dict:
    """Totals of per-viewpoint ``rows``: pixel counts summed, colour errors over every pixel both
    cover in any viewpoint (``colour_error_p99``: the worst viewpoint's), SSIM averaged over the
    viewpoints (``ssim_min``: the worst one's)."""
    if not rows:
        return {}
    stats = [r["stats"] for r in rows]
    both = sum(s["both_pixels"] for s in stats)

    def pooled(name: str) -> float:  # the mean over every pixel both cover, in all viewpoints
        return float(sum(s[name] * s["both_pixels"] for s in stats) / both) if both else 0.0

    return {
        "viewpoints": len(rows),
        "hole_pixels": sum(s["hole_pixels"] for s in stats),
        "max_hole_pixels": max(s["hole_pixels"] for s in stats),
        "hole_pixels_coarse": sum(s["hole_pixels_coarse"] for s in stats),
        "hole_pixels_unconfirmed": sum(s["hole_pixels_unconfirmed"] for s in stats),
        "hole_pixels_1spp": sum(s["hole_pixels_1spp"] for s in stats),
        "bloat_pixels": sum(s["bloat_pixels"] for s in stats),
        "bloat_beyond_1px": sum(s["bloat_beyond_1px"] for s in stats),
        "bloat_beyond_1px_coarse": sum(s["bloat_beyond_1px_coarse"] for s in stats),
        "bloat_beyond_1px_unconfirmed": sum(s["bloat_beyond_1px_unconfirmed"] for s in stats),
        "error_budget_px": max(s.get("error_budget_px", 1.0) for s in stats),
        "hole_pixels_beyond_budget": sum(s.get("hole_pixels_beyond_budget", s["hole_pixels"]) for s in stats),
        "bloat_beyond_budget": sum(s.get("bloat_beyond_budget", s["bloat_beyond_1px"]) for s in stats),
        "geometry_pixels": sum(s["geometry_pixels"] for s in stats),
        "both_pixels": both,
        "colour_error_mean": pooled("colour_error_mean"),
        "colour_error_p99": max(s["colour_error_p99"] for s in stats),
        "colour_error_max": max(s["colour_error_max"] for s in stats),
        "colour_error_1px_mean": pooled("colour_error_1px_mean"),
        "colour_error_1px_max": max(s["colour_error_1px_max"] for s in stats),
        "ssim": float(np.mean([s["ssim"] for s in stats])),
        "ssim_min": min(s["ssim"] for s in stats),
    }


def spread_corners(cell: ViewCell, start: np.ndarray, count: int) -> np.ndarray:
    """(min(count, corners), 3) float64 corners of ``cell`` far apart: first the corner farthest
    from ``start`` (3,), then each time the corner farthest from those already taken.

    >>> from farfield.core.viewcells import BoxCell
    >>> spread_corners(BoxCell(np.zeros(3), np.array([2.0, 1.0, 1.0])), np.zeros(3), 3).tolist()
    [[2.0, 1.0, 1.0], [0.0, 0.0, 0.0], [2.0, 0.0, 0.0]]
    """
    corners = cell.corners()
    taken = [int(np.argmax(np.linalg.norm(corners - start, axis=1)))]
    while len(taken) < min(count, len(corners)):
        gap = np.min(np.linalg.norm(corners[:, None, :] - corners[taken][None, :, :], axis=2), axis=1)
        taken.append(int(np.argmax(gap)))  # argmax picks the first of equals: deterministic
    return corners[taken]


UNBOUNDED_SHAFT_DEPTH = 3.0  # viewpoints of an unbounded shaft lie within 4x its near distance of the apex


def viewpoints(
    cell: ViewCell,
    reference: np.ndarray,
    random_count: int = 8,
    outside_count: int = 0,
    seed: int = 0,
    depth: float | None = None,
) -> tuple[np.ndarray, list[str]]:
    """(n, 3) float64 viewpoints and their kinds: the cell's corners, the ``reference`` viewpoint,
    ``random_count`` seeded points inside (``depth`` bounds an unbounded shaft: by default
    ``UNBOUNDED_SHAFT_DEPTH`` times its near distance, beyond which the part is under a quarter of its
    size at the near cap) and up to ``outside_count`` just outside."""
    if isinstance(cell, ShaftCell) and not cell.bounded and depth is None:
        depth = UNBOUNDED_SHAFT_DEPTH * cell.min_distance
    points, kinds = [cell.corners()], ["corner"] * len(cell.corners())
    points.append(np.asarray(reference, dtype=np.float64)[None, :])
    kinds.append("reference")
    if random_count:
        random = (
            cell.sample_random(random_count, seed, depth)
            if isinstance(cell, ShaftCell)
            else cell.sample_random(random_count, seed)
        )
        points.append(random)
        kinds += ["random"] * random_count
    if outside_count:
        out = outside_viewpoints(cell, outside_count, seed)
        points.append(out)
        kinds += ["outside"] * len(out)
    return np.concatenate(points), kinds


def evaluate(
    part: Scene,
    impostor: Impostor,
    cell: ViewCell,
    random_count: int = 8,
    outside_count: int = 0,
    seed: int = 0,
    depth: float | None = None,
    samples: int = 4,
    confirm_windows: int = CONFIRM_WINDOWS,
) -> Evaluation:
    """Render ``part`` and ``impostor`` from viewpoints of ``cell`` (:func:`viewpoints`) and compare them.

    ``depth`` bounds the sampling of an unbounded shaft; ``samples`` per pixel side measure coverage;
    ``confirm_windows`` caps the fine confirmation (:func:`evaluate_at`).
    """
    points, kinds = viewpoints(cell, impostor.reference_viewpoint, random_count, outside_count, seed, depth)
    return evaluate_at(part, impostor, points, kinds, samples, confirm_windows)


def error_budget_px(impostor: Impostor) -> float:
    """The error budget, in output pixels, ``impostor`` was baked for (``max_error_px``; 1 for a
    technique without one and for bundles baked before the option existed)."""
    value = impostor.parameters.get("max_error_px", 1.0)
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) and value > 0 else 1.0


def evaluate_at(
    part: Scene,
    impostor: Impostor,
    points: np.ndarray,
    kinds: list[str],
    samples: int = 4,
    confirm_windows: int = CONFIRM_WINDOWS,
) -> Evaluation:
    """Render ``part`` and ``impostor`` from ``points`` (n, 3) (of ``kinds``; "outside" ones are
    totalled apart) at the impostor's resolution and field of view, towards the part's centre, with
    ``samples`` per pixel side, and compare them (:func:`compare_images`), confirming coarse holes
    and bloat beyond one pixel at :func:`fine_samples` per pixel side in at most
    ``confirm_windows`` windows per viewpoint and side (0: no confirmation)."""
    start = time.perf_counter()
    target = 0.5 * (part.bounds[0] + part.bounds[1])
    extent = np.concatenate([box_corners(part.bounds), impostor.payload.world_points()])
    fov = math.radians(impostor.fov_deg)
    rows = []
    budget = error_budget_px(impostor)
    with MeshRenderer(part.objects) as geometry, impostor_renderer(impostor) as stand_in:
        for position, kind in zip(np.asarray(points, dtype=np.float64), kinds):
            forward = (target - position) / np.linalg.norm(target - position)
            near, far = depth_bounds(position, forward, extent)
            camera = Camera.look_at(position, target, fov, impostor.resolution * samples, near, far)
            confirm = _window_coverage({"geometry": geometry, "impostor": stand_in}, camera, samples)
            stats = compare_images(geometry.render(camera), stand_in.render(camera), samples, confirm, confirm_windows,
                                   reach=lambda camera=camera: vertex_pixels(part.objects, camera, samples), budget_px=budget)  # fmt: skip
            rows.append({"position": position.tolist(), "kind": kind, "inside": kind != "outside", "stats": stats})
    totals = _totals([r for r in rows if r["inside"]])
    outside = _totals([r for r in rows if not r["inside"]])
    if outside:
        totals["outside"] = outside
    summary = {k: impostor.stats.get(k) for k in ("layers", "quads", "texture_bytes", "geometry_bytes", "seconds")}
    return Evaluation(rows, totals, summary, time.perf_counter() - start)
