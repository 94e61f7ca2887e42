"""Texture atlases: n tiles of (n, 2) int64 sizes ``[w, h]`` packed onto p power-of-two (H, W, 4) uint8 pages.

Seed 000 §3.6 ("Efficient Graphics-Hardware Treatment Using Texture Atlases"): the many small
textures of the layer quads (:mod:`farfield.core.layering.quads`) are packed into few atlases, because texture
switches are costly and power-of-two textures are what every GPU handles.  :func:`pack` decides
pages and positions, :func:`compose` paints the pages, :func:`tile_uvs` gives each tile's corner UVs.

Conventions (:mod:`farfield.core.impostor.impostor`): pages are top row first, pixel positions are x right, y down,
UVs are glTF's, (0, 0) at the top-left of the page and (1, 1) at its bottom-right.

Rotation: a tile wider than tall is stored rotated 90° *clockwise* as seen in its image (top row
first), so that its larger side is vertical.  Its original top-left texel lands at the stored tile's
top-right, i.e. ``stored = np.rot90(tile, k=-1)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from farfield.core.errors import AtlasOverflowError, LayerPlanError


@dataclass(frozen=True, slots=True)
class AtlasLayout:
    """Where every tile lies in which atlas page (seed 000 §3.6)."""

    sizes: np.ndarray  # (n, 2) int64 original tile size [w, h] in texels, before any rotation
    page: np.ndarray  # (n,) int64 page index of each tile
    x: np.ndarray  # (n,) int64 page pixel column of the tile interior's left edge (inside padding)
    y: np.ndarray  # (n,) int64 page pixel row of the tile interior's top edge (y down)
    rotated: np.ndarray  # (n,) bool: stored rotated 90° clockwise (np.rot90(tile, k=-1))
    page_sizes: np.ndarray  # (p, 2) int64 [W, H] of each page, powers of two
    padding: int  # texels of edge extension around every tile

    @property
    def stored_sizes(self) -> np.ndarray:
        """(n, 2) int64 ``[w, h]`` of each tile interior as stored on its page (after rotation)."""
        return np.where(self.rotated[:, None], self.sizes[:, ::-1], self.sizes)

    @property
    def page_area(self) -> int:
        """Texels of all pages together."""
        return int(np.prod(self.page_sizes, axis=1).sum())

    @property
    def tile_area(self) -> int:
        """Texels of all tile interiors together (no padding)."""
        return int(np.prod(self.sizes, axis=1).sum())


def _next_pow2(v: int) -> int:
    """Smallest power of two >= v (v >= 1)."""
    return 1 << (int(v) - 1).bit_length()


def _check_int(value, what: str, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise LayerPlanError(f"{what} must be an integer >= {low}, got {value!r}")
    return int(value)


# The default largest page side, texels: what most GPUs take (WebGL2 guarantees 2,048; many mobile
# GPUs stop at 4,096).  A technique's ``max_page`` option changes it.
MAX_PAGE = 4096


def pack(sizes: np.ndarray, padding: int = 2, max_page: int = MAX_PAGE, min_fill: float = 0.75) -> AtlasLayout:
    """Pack tiles of (n, 2) int ``[w, h]`` sizes into power-of-two pages (seed 000 §3.6).

    The thesis's greedy: rotate every tile so its larger side is vertical; sort by decreasing
    (padded) height, then decreasing width (stable, so equal tiles keep input order).  A new page is
    as tall as the first remaining tile, and as wide as the summed area of all remaining tiles over
    that height, both rounded up to a power of two (the width at least the widest remaining tile, at
    most ``max_page``).  Tiles are tried in list order, each at the lowest possible position, like
    "Tetris" (here: the smallest y in a y-down page, the leftmost x among equals, on a skyline of
    column heights, so a tile never goes under an overhang).  What did not fit starts the next page.

    Deviation (``min_fill``): rounding the width up to a power of two can leave a page up to half
    empty, and the thesis then has nothing left over for a next page.  When the padded area of the
    remaining tiles would fill less than ``min_fill`` of the rounded-up page, the width is halved
    instead and what does not fit spills onto further, smaller pages.  On a few hundred quads of
    blobby layers this takes page area from 1.3-2.3x the tile area to 1.2-1.4x (padding 2), at
    the price of more pages (typically 5-10 instead of 1-6).  ``min_fill=0`` is the thesis exactly
    (as long as the tiles fit one strip of ``max_page`` width: beyond that, pages grow in height
    rather than multiply, which keeps packing from turning quadratic in the tile count).

    Parameters
    ----------
    sizes : (n, 2) int
        Tile interior sizes ``[w, h]`` in texels, each >= 1.
    padding : int
        Texels of edge extension on every side of every tile (>= 0), against bilinear and mipmap
        bleeding between neighbours.  Padded size = size + 2 * padding.
    max_page : int
        Largest page side in texels, a power of two (GPU texture limit).
    min_fill : float
        In [0, 1]: smallest share of a page's area the remaining tiles must cover before the page
        width is halved and the rest spills onto more pages; 0 never spills (seed 000 exactly).

    Returns
    -------
    AtlasLayout
        ``x, y`` are the tile interior's top-left, inside the padding.

    Raises
    ------
    AtlasOverflowError
        A padded tile is larger than ``max_page``.
    LayerPlanError
        Malformed ``sizes``, negative ``padding``, ``max_page`` not a power of two, or
        ``min_fill`` outside [0, 1].

    Examples
    --------
    Two 4 x 8 tiles (one rotated) and a 4 x 4 one; the thesis's page is a fifth empty:

    >>> lay = pack([[4, 8], [8, 4], [4, 4]], padding=0, min_fill=0)
    >>> lay.page_sizes.tolist(), lay.rotated.tolist()
    ([[16, 8]], [False, True, False])
    >>> lay.x.tolist(), lay.y.tolist()
    ([0, 4, 8], [0, 0, 0])

    With the default ``min_fill`` the small tile spills onto a second page instead:

    >>> lay = pack([[4, 8], [8, 4], [4, 4]], padding=0)
    >>> lay.page_sizes.tolist(), lay.page.tolist()
    ([[8, 8], [4, 4]], [0, 0, 1])
    >>> pack(np.zeros((0, 2), dtype=int)).page_sizes.shape
    (0, 2)
    """
    padding = _check_int(padding, "atlas padding", 0)
    max_page = _check_int(max_page, "largest atlas page side", 1)
    if max_page & (max_page - 1):
        raise LayerPlanError(f"largest atlas page side must be a power of two, got {max_page}")
    if not (0.0 <= float(min_fill) <= 1.0):
        raise LayerPlanError(f"atlas min_fill must lie in [0, 1], got {min_fill!r}")
    raw = np.asarray(sizes)
    if raw.ndim != 2 or raw.shape[1] != 2:
        raise LayerPlanError(f"tile sizes must be an (n, 2) array of [w, h], got shape {raw.shape}")
    if raw.size and raw.dtype.kind not in "iuf":
        raise LayerPlanError(f"tile sizes must be integers, got dtype {raw.dtype}")
    bad = np.flatnonzero(np.any((raw < 1) | (raw != np.round(raw)), axis=1)) if raw.size else []
    if len(bad):
        i = int(bad[0])
        raise LayerPlanError(f"tile sizes must be integers >= 1, got [w, h] = {raw[i].tolist()} for tile {i}")
    sz = raw.astype(np.int64).reshape(-1, 2)
    n = sz.shape[0]

    rotated = sz[:, 0] > sz[:, 1]
    stored = np.where(rotated[:, None], sz[:, ::-1], sz)
    pw = stored[:, 0] + 2 * padding
    ph = stored[:, 1] + 2 * padding  # ph >= pw after the rotation
    big = np.flatnonzero(ph > max_page)
    if big.size:
        i = int(big[0])
        raise AtlasOverflowError(
            f"tile {i} of {sz[i, 0]}x{sz[i, 1]} texels is {pw[i]}x{ph[i]} with padding {padding}, "
            f"larger than the largest page side {max_page}"
        )

    order = np.lexsort((np.arange(n), -pw, -ph))
    page = np.full(n, -1, dtype=np.int64)
    px = np.zeros(n, dtype=np.int64)
    py = np.zeros(n, dtype=np.int64)
    page_sizes: list[tuple[int, int]] = []
    remaining = order.tolist()
    while remaining:
        rem = np.asarray(remaining)
        height = _next_pow2(ph[rem[0]])
        area = int((pw[rem] * ph[rem]).sum())
        if area > height * max_page:
            # Deviation: the thesis's strip (as tall as the tallest tile) would need many pages, and
            # every page pass tests every remaining tile (quadratic in the tile count); let the
            # page grow towards a square of at most max_page instead.
            height = min(max_page, _next_pow2(-(-area // max_page)))
        widest = _next_pow2(int(pw[rem].max()))
        width = max(_next_pow2(-(-area // height)), widest)
        if width > widest and area < min_fill * width * height:
            width //= 2  # spill instead of a mostly empty page (see the docstring)
        width = min(width, max_page)
        index = len(page_sizes)
        shortest = int(ph[remaining[-1]])  # remaining is sorted by decreasing padded height
        left_over = _fill_page(np.asarray(remaining, np.int64), pw, ph, width, height, shortest, padding, index,
                               page, px, py).tolist()  # fmt: skip
        page_sizes.append((width, height))
        remaining = left_over
    return AtlasLayout(
        sizes=sz,
        page=page,
        x=px,
        y=py,
        rotated=rotated,
        page_sizes=np.asarray(page_sizes, dtype=np.int64).reshape(-1, 2),
        padding=padding,
    )


@njit(cache=True, nogil=True)
def _fill_page(remaining, pw, ph, width: int, height: int, shortest: int, padding: int, index: int, page, px, py):
    """Place the tiles ``remaining`` (indices into the padded sizes ``pw``, ``ph``, in packing order)
    on page ``index`` of ``width`` x ``height`` as :func:`pack` describes: each at the lowest
    position of the skyline of column heights, the leftmost among equals, or left over.  Writes
    ``page``, ``px``, ``py`` (interior top-left, inside ``padding``) of each placed tile; returns
    the tiles left over, in order.  Once not even the ``shortest`` remaining tile fits under the
    lowest column, the rest are left over untested.

    Compiled: the window maxima of the skyline by a monotonic queue, O(width) a tile, in one pass
    with the leftmost minimum (in numpy, van Herk / Gil-Werman window maxima and an argmin a tile
    took 0.42 s CPU for the 9,582 tiles of the layered benchmark at 1024 px, this 0.13 s)."""
    skyline = np.zeros(width, np.int64)
    queue = np.empty(width, np.int64)
    left = np.empty(remaining.size, np.int64)
    n_left = 0
    lowest = 0  # skyline.min()
    for j in range(remaining.size):
        i = remaining[j]
        if lowest + shortest > height:
            for k in range(j, remaining.size):
                left[n_left] = remaining[k]
                n_left += 1
            break
        w_i, h_i = pw[i], ph[i]
        if w_i > width or lowest + h_i > height:
            left[n_left] = i
            n_left += 1
            continue
        # The leftmost lowest window of w_i columns: max of each window, first minimum of those.
        head, tail = 0, 0
        best_x, best_y = -1, np.iinfo(np.int64).max
        for x in range(width):
            v = skyline[x]
            while tail > head and skyline[queue[tail - 1]] <= v:
                tail -= 1
            queue[tail] = x
            tail += 1
            if queue[head] <= x - w_i:
                head += 1
            if x >= w_i - 1 and skyline[queue[head]] < best_y:
                best_y = skyline[queue[head]]
                best_x = x - w_i + 1
        if best_y + h_i > height:
            left[n_left] = i
            n_left += 1
            continue
        skyline[best_x : best_x + w_i] = best_y + h_i
        lowest = skyline.min()
        page[i], px[i], py[i] = index, best_x + padding, best_y + padding
    return left[:n_left]


def tile_uvs(layout: AtlasLayout, indices=None) -> np.ndarray:
    """(m, 4, 2) float64 page UVs of the ORIGINAL tiles' corners TL, TR, BR, BL (glTF convention).

    UVs lie on texel edges: the edges of the tile interior, not texel centres.  For a tile stored
    rotated 90° clockwise, the original TL corner is the stored top-right, TR the stored
    bottom-right, BR the stored bottom-left and BL the stored top-left.

    Parameters
    ----------
    layout : AtlasLayout
    indices : (m,) int or None
        Tiles to give; all when None.

    Examples
    --------
    >>> lay = pack([[2, 4], [4, 2]], padding=0)
    >>> (tile_uvs(lay) * lay.page_sizes[0]).tolist()
    [[[0.0, 0.0], [2.0, 0.0], [2.0, 4.0], [0.0, 4.0]], [[4.0, 0.0], [4.0, 4.0], [2.0, 4.0], [2.0, 0.0]]]
    """
    idx = np.arange(layout.page.size) if indices is None else np.asarray(indices, dtype=np.int64).reshape(-1)
    ws, hs = layout.stored_sizes[idx].T
    x0 = layout.x[idx].astype(np.float64)
    y0 = layout.y[idx].astype(np.float64)
    x1, y1 = x0 + ws, y0 + hs
    plain = np.stack(
        [np.stack([x0, y0], -1), np.stack([x1, y0], -1), np.stack([x1, y1], -1), np.stack([x0, y1], -1)], 1
    )
    # Clockwise storage: original (TL, TR, BR, BL) sit at stored (TR, BR, BL, TL).
    turned = plain[:, [1, 2, 3, 0]]
    corners = np.where(layout.rotated[idx][:, None, None], turned, plain)
    return corners / layout.page_sizes[layout.page[idx]][:, None, :].astype(np.float64)


def tile_uv(layout: AtlasLayout, i: int) -> np.ndarray:
    """(4, 2) float64 page UVs of tile ``i``'s original corners TL, TR, BR, BL (see :func:`tile_uvs`)."""
    return tile_uvs(layout, [i])[0]


def bleed_rgb(tile: np.ndarray, iterations: int) -> np.ndarray:
    """(h, w, 4) uint8 copy of ``tile`` whose fully transparent texels take their neighbours' RGB.

    A tile with more channels (a normal channel after the colour, (h, w, 8)) has every channel but
    the colour's alpha (3) bled the same way.

    Each iteration gives every still-uncoloured alpha-0 texel the alpha-weighted mean RGB of its 8
    neighbours that have colour (opaque texels weigh their alpha, texels coloured in an earlier
    iteration weigh 1).  Alpha is unchanged.  Without this, bilinear filtering and mipmapping mix
    the RGB of transparent texels (often black) into the edges of opaque content.  Integer
    arithmetic, so the result is deterministic.

    >>> t = np.zeros((1, 3, 4), dtype=np.uint8); t[0, 0] = (200, 100, 50, 255)
    >>> bleed_rgb(t, 1)[0].tolist()
    [[200, 100, 50, 255], [200, 100, 50, 0], [0, 0, 0, 0]]
    """
    out = np.array(tile, dtype=np.uint8, copy=True)
    weight = out[..., 3].astype(np.int64)
    if iterations <= 0 or weight.all() or not weight.any():
        return out
    colours = [c for c in range(out.shape[2]) if c != 3]
    rgb = out[..., colours].astype(np.int64)
    h, w = weight.shape
    for _ in range(iterations):
        todo = weight == 0
        if not todo.any():
            break
        wp = np.pad(weight, 1)
        cp = np.pad(rgb * weight[..., None], ((1, 1), (1, 1), (0, 0)))
        den = np.zeros((h, w), dtype=np.int64)
        num = np.zeros((h, w, len(colours)), dtype=np.int64)
        for dy in (0, 1, 2):
            for dx in (0, 1, 2):
                if dy == 1 and dx == 1:
                    continue
                den += wp[dy : dy + h, dx : dx + w]
                num += cp[dy : dy + h, dx : dx + w]
        new = todo & (den > 0)
        if not new.any():
            break
        d = den[new][:, None]
        rgb[new] = (num[new] + d // 2) // d  # rounded integer mean
        weight[new] = 1
    out[..., colours] = rgb.astype(np.uint8)
    return out


def fill_nearest_rgb(image: np.ndarray) -> np.ndarray:
    """(h, w, 4) uint8 copy of ``image`` whose transparent texels take the RGB of the nearest opaque texel.

    The whole-layer form of :func:`bleed_rgb` (one Euclidean distance transform instead of
    iterations), so bilinear filtering and every mip level see opaque colours around content.
    Ties between equally near texels are broken by scipy's deterministic scan order.  An image
    with more channels (a normal channel after the colour) has every channel but the colour's
    alpha (3) filled the same way.

    >>> t = np.zeros((1, 3, 4), dtype=np.uint8); t[0, 0] = (200, 100, 50, 255)
    >>> fill_nearest_rgb(t)[0].tolist()
    [[200, 100, 50, 255], [200, 100, 50, 0], [200, 100, 50, 0]]
    """
    from scipy.ndimage import distance_transform_edt

    out = np.array(image, dtype=np.uint8, copy=True)
    opaque = out[..., 3] > 0
    if opaque.all() or not opaque.any():
        return out
    iy, ix = distance_transform_edt(~opaque, return_distances=False, return_indices=True)
    colours = [c for c in range(out.shape[2]) if c != 3]
    out[..., colours] = out[iy, ix][..., colours]
    return out


def compose(layout: AtlasLayout, tiles, padding: int | None = None, bleed: int = 4) -> tuple[np.ndarray, ...]:
    """Paint the atlas pages: a tuple of p (H, W, 4) uint8 arrays, top row first (seed 000 §3.6).

    Every tile is stored rotated 90° clockwise where ``layout.rotated`` says so, its transparent
    texels get RGB bled in from opaque ones (:func:`bleed_rgb`, ``bleed`` iterations), and its
    padding is filled by edge extension (replicating its border texels outward).  Page texels
    outside all padded tiles stay (0, 0, 0, 0).  Byte-identical output for identical input.

    Parameters
    ----------
    layout : AtlasLayout
        From :func:`pack`.
    tiles : sequence of n (h_i, w_i, 4) uint8
        RGBA tiles, top row first, in the order of the sizes given to :func:`pack`; (h_i, w_i, 4c)
        for c channels of four (colour, then normals), every tile alike: the pages have as many.
    padding : int or None
        Must equal ``layout.padding`` when given (the layout was packed for it).
    bleed : int
        Iterations of RGB bleeding into transparent texels; 0 stores the tiles unchanged.

    Raises
    ------
    LayerPlanError
        A tile whose shape or dtype does not match the layout, or a padding other than the layout's.

    Examples
    --------
    >>> tile = np.arange(2 * 3 * 4, dtype=np.uint8).reshape(2, 3, 4)
    >>> lay = pack([[3, 2]], padding=1)
    >>> (page,) = compose(lay, [tile])
    >>> page.shape, lay.rotated.tolist()
    ((8, 4, 4), [True])
    >>> bool((page[1:4, 1:3] == np.rot90(tile, k=-1)).all())
    True
    """
    if padding is not None and _check_int(padding, "atlas padding", 0) != layout.padding:
        raise LayerPlanError(f"padding {padding} differs from the layout's padding {layout.padding}")
    tiles = list(tiles)
    n = layout.page.size
    if len(tiles) != n:
        raise LayerPlanError(f"layout has {n} tiles, got {len(tiles)} images")
    p = layout.padding
    depth = int(np.asarray(tiles[0]).shape[-1]) if tiles and np.asarray(tiles[0]).ndim == 3 else 4
    depth = depth if depth in (4, 8, 12, 16) else 4
    pages = [np.zeros((int(hh), int(ww), depth), dtype=np.uint8) for ww, hh in layout.page_sizes]
    for i, tile in enumerate(tiles):
        t = np.asarray(tile)
        w, h = layout.sizes[i]
        if t.shape != (h, w, depth) or t.dtype != np.uint8:
            raise LayerPlanError(f"tile {i} must be ({h}, {w}, {depth}) uint8, got {t.shape} {t.dtype}")
        if layout.rotated[i]:
            t = np.rot90(t, k=-1)
        if bleed > 0:
            t = bleed_rgb(t, bleed)
        _put_padded(pages[int(layout.page[i])], t, int(layout.x[i]), int(layout.y[i]), p)
    return tuple(pages)


def _put_padded(page: np.ndarray, tile: np.ndarray, x: int, y: int, p: int) -> None:
    """Write ``tile`` (h, w, c) at interior top-left ``x, y`` of ``page`` with ``p`` texels of edge
    extension around it (``np.pad(tile, p, mode="edge")``'s texels, written in place: the first and
    last rows repeated above and below, then the padded first and last columns to the sides, so a
    corner takes the tile's corner texel)."""
    h, w = tile.shape[:2]
    page[y : y + h, x : x + w] = tile
    if p == 0:
        return
    page[y - p : y, x : x + w] = tile[:1]
    page[y + h : y + h + p, x : x + w] = tile[-1:]
    page[y - p : y + h + p, x - p : x] = page[y - p : y + h + p, x : x + 1]
    page[y - p : y + h + p, x + w : x + w + p] = page[y - p : y + h + p, x + w - 1 : x + w]
