"""Atlas pages of texel *masks*: charts of any shape packed by first fit, keeping a gap between them.

:mod:`farfield.core.layering.atlas` packs rectangles, which suits the layered technique's quad tiles.  The charts of a
textured depth mesh (:mod:`farfield.core.techniques.tdm.texture`) are not rectangles: on the house benchmark at 90 m
(512 px) their bounding rectangles held 133k texels for 72k needed ones.  This module places each
chart's *needed texels* (a boolean mask) instead, so that charts nest into each other's concave
parts:

* Masks go tallest first (then largest), each to the first position in row-major order (top row
  first, then left) where it lies inside the page and no texel of it comes within ``padding``
  texels (Chebyshev distance) of a texel already placed: its mask dilated by ``padding`` must meet
  no placed texel.  The search is one numba kernel (:func:`_first_fit`) that skips rows without
  enough free cells or a long enough free run, tests a mask row's runs against the page's free
  runs in one read each and jumps over blocked runs, so its cost grows with the free runs it
  meets, not with the area already packed (30,957 charts of a 327,680-triangle sphere from a
  close cell: 60 s instead of more than 10 minutes, then 14.5 s with texel tests, 6.5 s with run
  tests, the same layout each time; see ``benchmarks/bench_tdm_scale.py``).  A mask the same texel for texel as one placed before
  starts its search where that one went (:func:`_pack`).  A mask that fits no page opens a new one.
* Pages have a fixed width, a multiple of the square root of the masks' area (rounded up to a
  multiple of 4, never narrower than the widest mask), and end below their lowest texel (rounded
  up to a multiple of 4).  The packing is run for each width of :data:`WIDTH_SCALES`, one thread
  per width, and the smallest total page area is kept (on the house benchmark, 512 px, f = 2: 0-3 % less than the
  single width 1.5 of earlier versions).  They are not powers of two: glTF 2.0 and every current
  GPU API take any size.

``padding`` is the gap between the texels of different masks, for mip levels: the bilinear ring
is already part of a chart's mask (:func:`farfield.core.techniques.tdm.texture.build_charts`), and the gap texels are
filled from the nearest chart texel (:func:`farfield.core.techniques.tdm.texture.chart_pages`).  Each chart thus gets
its ring plus ``padding / 2`` texels of extension on every side, as each rectangle of
:mod:`farfield.core.layering.atlas` gets ``padding`` texels of edge extension, the first of which serves bilinear
filtering.
"""

from __future__ import annotations

from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.ndimage import binary_dilation

from farfield.core.cores import usable_cores
from farfield.core.errors import AtlasOverflowError, LayerPlanError
from farfield.core.layering.atlas import MAX_PAGE


@dataclass(frozen=True, slots=True)
class MaskLayout:
    """Where every mask lies: page, and the page row and column of its array's top-left texel."""

    page: np.ndarray  # (n,) int64
    x: np.ndarray  # (n,) int64 page column of the mask's column 0
    y: np.ndarray  # (n,) int64 page row of the mask's row 0 (y down)
    page_sizes: np.ndarray  # (p, 2) int64 [W, H] of each page

    @property
    def page_area(self) -> int:
        """Texels of all pages together."""
        return int(np.prod(self.page_sizes, axis=1).sum())


@njit(cache=True, nogil=True)
def _first_fit(span, most, free, run, run_rows, run_cols, run_lens, height, width, need, need_run, start_y, start_x):
    """First (row, column) in row-major order, from (``start_y``, ``start_x``) on, where the runs
    of a mask of ``height`` x ``width`` (row ``run_rows``, first column ``run_cols``, ``run_lens``
    cells) meet no blocked cell of the page; (-1, -1) if none.

    The answer is the plain row-major scan's; what makes it cheaper:

    * ``free`` counts each page row's unblocked cells and ``run`` their longest run; ``need``
      counts each mask row's cells and ``need_run`` their longest run: a row without enough of
      either is skipped whole.
    * ``span[r, c]`` is the length of the free run that starts at cell (r, c), or minus the length
      of the blocked run that starts there: a mask run is tested in one read, and where it does not
      fit, no column before the one that puts its first cell on the next free cell after the
      blocking one can fit either, so the scan jumps there.  The mask's longest run is tested
      first (it fails most often), then the others in row-major order.
    * Where the longest run does not fit, ``most`` (the largest ``span`` of each :data:`BLOCK`
      columns of a row) finds the next cell of its row that starts a free run long enough for it
      (:func:`_long_enough`): the free runs too short for it, which the jumps above visit one by
      one, are passed a block at a time.
    """
    page_h, page_w = span.shape
    m = run_rows.size
    anchor = 0
    for j in range(1, m):
        if run_lens[j] > run_lens[anchor]:
            anchor = j
    for y in range(start_y, page_h - height + 1):
        enough = True
        for r in range(height):
            if free[y + r] < need[r] or run[y + r] < need_run[r]:
                enough = False
                break
        if not enough:
            continue
        x = start_x if y == start_y else 0
        while x <= page_w - width:
            fits = True
            for t in range(m):
                j = anchor if t == 0 else (t - 1 if t - 1 < anchor else t)
                r, c = y + run_rows[j], x + run_cols[j]
                length = span[r, c]
                if length < run_lens[j]:
                    if t == 0:  # the anchor: on to the first cell after c that starts a long enough free run
                        x = _long_enough(span, most, r, c, run_lens[j]) - run_cols[j]
                    else:
                        end = c + length if length > 0 else c  # the first blocked cell at or after c
                        x = page_w if end >= page_w else end - span[r, end] - run_cols[j]
                    fits = False
                    break
            if fits:
                return y, x
    return -1, -1


BLOCK = 32  # columns per entry of a page row's ``most`` (the largest ``span`` among them)


@njit(cache=True, nogil=True)
def _long_enough(span, most, r, c, length):
    """The first column after ``c`` of row ``r`` whose ``span`` is at least ``length`` (a free run
    that long starts there: the cells of a free run before it have shorter spans), or the row's
    width if none: the rest of ``c``'s block run by run, then whole blocks whose largest span
    (``most``) is shorter skipped."""
    page_w = span.shape[1]
    end = min(page_w, (c // BLOCK + 1) * BLOCK)
    cc = c
    while cc < end:  # run by run to the end of c's block
        value = span[r, cc]
        if cc > c and value >= length:
            return cc
        cc += value if value > 0 else -value
    for b in range(c // BLOCK + 1, most.shape[1]):
        if most[r, b] >= length:
            cc = b * BLOCK
            while span[r, cc] < length:
                value = span[r, cc]
                cc += value if value > 0 else -value
            return cc
    return page_w


@njit(cache=True, nogil=True)
def _block(span, most, free, run, grown, top, left):
    """Block the cells of ``grown`` (a mask dilated by the padding) with its top-left at (``top``,
    ``left``), clipped to the page, and bring ``span``, ``free`` and ``run`` up to date."""
    page_h, page_w = span.shape
    gh, gw = grown.shape
    for gr in range(gh):
        r = top + gr
        if r < 0 or r >= page_h:
            continue
        right = -1
        for gc in range(gw):
            c = left + gc
            if 0 <= c < page_w and grown[gr, gc] and span[r, c] > 0:
                span[r, c] = 0  # newly blocked: its span is set below
                free[r] -= 1
                right = c
        if right < 0:
            continue
        # The spans change only at and left of the rightmost cell newly blocked, up to the first
        # column left of the mask whose value stays the same.
        c = right
        while c >= 0:
            after = span[r, c + 1] if c + 1 < page_w else 0
            if span[r, c] > 0:
                value = after + 1 if after > 0 else 1
            else:
                value = after - 1 if after < 0 else -1
            if value == span[r, c] and c < left:
                break
            span[r, c] = value
            c -= 1
        # Columns c + 1 to right changed: their blocks' largest spans, then the row's.
        for b in range((c + 1) // BLOCK, right // BLOCK + 1):
            largest = span[r, b * BLOCK]
            for cc in range(b * BLOCK + 1, min(page_w, (b + 1) * BLOCK)):
                largest = max(largest, span[r, cc])
            most[r, b] = largest
        longest = 0
        for b in range(most.shape[1]):
            longest = max(longest, most[r, b])
        run[r] = longest


# Page widths tried, as multiples of the square root of the masks' texels: first fit leaves
# different gaps at different widths, and the smallest total page area wins.
WIDTH_SCALES = (1.0, 1.25, 1.5, 2.0, 3.0)


def _round4(v: int) -> int:
    return -(-int(v) // 4) * 4


def pack_masks(masks: Sequence[np.ndarray], padding: int = 2, max_page: int = MAX_PAGE) -> MaskLayout:
    """Place the (h, w) boolean ``masks`` on pages at most ``max_page`` texels a side, no two
    masks' true texels closer than ``padding`` + 1 (so ``padding`` texels apart).

    Two L shapes nest into a 2 x 3 rectangle, or, one texel apart (``padding=1``), stack:

    >>> ell = np.array([[1, 0], [1, 1]], bool)
    >>> lay = pack_masks([ell, ell[::-1, ::-1]], padding=0)
    >>> lay.page_sizes.tolist(), lay.x.tolist(), lay.y.tolist()
    ([[4, 4]], [0, 1], [0, 0])
    >>> lay = pack_masks([ell, ell[::-1, ::-1]], padding=1)
    >>> lay.x.tolist(), lay.y.tolist()
    ([0, 0], [0, 3])

    Of the widths tried, the one with the least page area wins (the narrowest on a tie): rectangles
    of 3 x 4, 7 x 4 and 4 x 3 texels fill a page 8 wide, where 12 wide (the width 1.5 alone) needs
    12 x 8:

    >>> pack_masks([np.ones((4, 3), bool), np.ones((4, 7), bool), np.ones((3, 4), bool)], padding=0).page_sizes.tolist()
    [[8, 8]]
    """
    if isinstance(padding, bool) or not isinstance(padding, (int, np.integer)) or padding < 0:
        raise LayerPlanError(f"atlas padding must be an integer >= 0, got {padding!r}")
    n = len(masks)
    masks = [np.asarray(m, dtype=bool) for m in masks]
    if n == 0:
        return MaskLayout(
            np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 2), np.int64)
        )
    shapes = np.array([m.shape for m in masks], dtype=np.int64)  # (n, 2) h, w
    big = np.flatnonzero(np.any(shapes > max_page, axis=1))
    if big.size:
        h, w = shapes[big[0]]
        raise AtlasOverflowError(
            f"chart {int(big[0])} of {int(w)}x{int(h)} texels does not fit a page of at most {max_page}x{max_page}"
        )
    texels = np.array([int(m.sum()) for m in masks], dtype=np.int64)
    order = np.lexsort((-texels, -shapes[:, 0]))
    widest = _round4(shapes[:, 1].max())
    widths = sorted({min(max_page, max(widest, _round4(np.ceil(np.sqrt(s * texels.sum()))))) for s in WIDTH_SCALES})
    p = int(padding)
    cells = [tuple(c.astype(np.int64) for c in np.nonzero(m)) for m in masks]
    # Masks alike texel for texel share a number: a search for one resumes where the last ended.
    kinds: dict[tuple, int] = {}
    kind = np.array([kinds.setdefault((m.shape, m.tobytes()), len(kinds)) for m in masks], dtype=np.int64)
    need = [np.bincount(rows, minlength=m.shape[0]).astype(np.int64) for m, (rows, _) in zip(masks, cells)]
    need_run, grown = _stacked(masks, shapes, p)
    flat = _flattened(cells, need, need_run, grown)
    # One thread per width (the kernels release the GIL): the widths are independent packings.
    # The widest, which take longest, start first, so that fewer threads idle at the end (on two
    # cores and five widths of benchmarks/bench_tdm_scale.py, measured in turns in one process:
    # 12.7 and 15.4 s ascending, 11.7 and 13.1 s widest first).
    with ThreadPoolExecutor(max_workers=min(len(widths), usable_cores())) as pool:
        packed = dict(
            zip(
                widths[::-1], pool.map(lambda width: _pack(shapes, flat, kind, order, width, p, max_page), widths[::-1])
            )
        )
    return min((packed[width] for width in widths), key=lambda layout: (layout.page_area, len(layout.page_sizes)))


def _stacked(masks: Sequence[np.ndarray], shapes: np.ndarray, p: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Each mask's longest run of true texels in each row and the mask dilated by ``p`` texels
    (Chebyshev) on an array grown by ``p`` all round, found for many masks at once: masks of about
    the same width (within a factor of two) lie one under the other on one array, ``2 p + 1`` rows
    apart (a call per mask cost more than the packing of the small ones: 31k charts of
    benchmarks/bench_tdm_scale.py, 2.6 s).

    >>> runs, grown = _stacked([np.array([[1, 1, 0, 1]], bool), np.ones((2, 1), bool)], np.array([[1, 4], [2, 1]]), 1)
    >>> [r.tolist() for r in runs], grown[1].astype(int).tolist()
    ([[2], [1, 1]], [[1, 1, 1], [1, 1, 1], [1, 1, 1], [1, 1, 1]])
    """
    runs: list[np.ndarray] = [np.zeros(0, np.int64)] * len(masks)
    grown: list[np.ndarray] = [np.zeros((0, 0), bool)] * len(masks)
    bucket = np.ceil(np.log2(shapes[:, 1] + 2 * p + 2)).astype(np.int64)
    for b in np.unique(bucket):
        group = np.flatnonzero(bucket == b)
        heights, width = shapes[group, 0] + 2 * p + 1, int(shapes[group, 1].max()) + 2 * p
        top = np.concatenate([[0], np.cumsum(heights)[:-1]]) + p  # each mask's row 0 on the stack
        stack = np.zeros((int(heights.sum()) + p, width + 2), bool)  # a false column each side
        for i, row in zip(group.tolist(), top.tolist()):
            stack[row : row + shapes[i, 0], p + 1 : p + 1 + shapes[i, 1]] = masks[i]
        # Runs: where a row turns true and back to false, pairs in row-major order.
        edges = np.diff(stack.view(np.int8), axis=1)
        (start_row, start_col), (_, end_col) = np.nonzero(edges == 1), np.nonzero(edges == -1)
        longest = np.zeros(stack.shape[0], np.int64)
        np.maximum.at(longest, start_row, end_col - start_col)
        dilated = binary_dilation(stack, np.ones((2 * p + 1, 2 * p + 1), bool)) if p else stack
        for i, row in zip(group.tolist(), top.tolist()):
            h, w = (int(v) for v in shapes[i])
            runs[i] = longest[row : row + h].copy()
            grown[i] = np.ascontiguousarray(dilated[row - p : row + h + p, 1 : 1 + w + 2 * p])
    return runs, grown


@njit(cache=True, nogil=True)
def _pack_from(start, order, shapes, kind, run_at, run_rows, run_cols, run_lens, row_at, need, need_run, grown_at, grown, p,
               span, most, free, run, bottoms, resume, page, x, y):  # fmt: skip
    """Place the masks ``order[start:]`` on the pages (:func:`_pack` says how); the position in
    ``order`` of the first mask that fits no page (the caller adds one and goes on from there), or
    ``len(order)`` when every mask is placed.  Mask i's runs are ``run_rows``/``run_cols``/
    ``run_lens`` [``run_at[i]``:``run_at[i + 1]``], its rows' ``need`` and ``need_run``
    [``row_at[i]``:...], its dilated mask ``grown`` [``grown_at[i]``:...] raveled, (h + 2p) x
    (w + 2p)."""
    for j in range(start, order.shape[0]):
        i = order[j]
        h, w = shapes[i, 0], shapes[i, 1]
        lo, hi = run_at[i], run_at[i + 1]
        need_i, run_i = need[row_at[i] : row_at[i + 1]], need_run[row_at[i] : row_at[i + 1]]
        first, start_y, start_x = resume[kind[i], 0], resume[kind[i], 1], resume[kind[i], 2]
        at_y = at_x = -1
        index = first
        while index < span.shape[0]:
            sy, sx = (start_y, start_x) if index == first else (0, 0)
            at_y, at_x = _first_fit(
                span[index],
                most[index],
                free[index],
                run[index],
                run_rows[lo:hi],
                run_cols[lo:hi],
                run_lens[lo:hi],
                h,
                w,
                need_i,
                run_i,
                sy,
                sx,
            )
            if at_y >= 0:
                break
            index += 1
        if at_y < 0:
            return j
        dilated = grown[grown_at[i] : grown_at[i + 1]].reshape(h + 2 * p, w + 2 * p)
        _block(span[index], most[index], free[index], run[index], dilated, at_y - p, at_x - p)
        page[i], y[i], x[i] = index, at_y, at_x
        resume[kind[i], 0], resume[kind[i], 1], resume[kind[i], 2] = index, at_y, at_x
        bottoms[index] = max(bottoms[index], at_y + h)
    return order.shape[0]


def _pack(shapes, flat, kind, order: np.ndarray, width: int, p: int, max_page: int) -> MaskLayout:
    """First fit of the masks (``shapes`` (n, 2) h, w; ``flat`` their runs, rows' needs and
    dilated masks as :func:`_flattened` gives them) in ``order`` onto pages ``width`` texels wide.

    Placed cells only ever block more, so no position before the one where a mask was placed can
    take a mask of the same ``kind`` (the same texels) later: its search starts there.  Of the
    30,957 charts of ``benchmarks/bench_tdm_scale.py``'s sphere, 19,611 kinds: the positions tried
    at one width went from 377 M to 178 M, the same layout.  The loop over the masks is one numba
    kernel (:func:`_pack_from`), which also frees the other packing threads from the GIL: a loop
    in Python cost 0.7 of the 4.6 s of one width there."""
    n = len(shapes)
    # Per page (:func:`_first_fit` says what each holds): the spans of free and blocked runs (a cell
    # is blocked for new texels within ``padding`` of a placed one), free, run, and the lowest
    # texel's row.  Room for twice the pages each time it runs out.
    span = np.empty((1, max_page, width), np.int32)
    most = np.empty((1, max_page, -(-width // BLOCK)), np.int32)
    free = np.empty((1, max_page), np.int64)
    run = np.empty((1, max_page), np.int64)
    bottoms = np.empty(1, np.int64)
    page, x, y = np.zeros(n, np.int64), np.zeros(n, np.int64), np.zeros(n, np.int64)
    resume = np.zeros((int(kind.max(initial=-1)) + 1, 3), np.int64)  # kind -> (page, row, column) of its last placement
    order = np.ascontiguousarray(order, dtype=np.int64)
    start = pages = 0
    while start < n:  # a page more each time a mask fits none
        if pages == len(span):
            span, most, free, run, bottoms = (
                np.concatenate([a, np.empty_like(a)]) for a in (span, most, free, run, bottoms)
            )
        span[pages] = np.arange(width, 0, -1, dtype=np.int32)
        most[pages] = width - BLOCK * np.arange(most.shape[2], dtype=np.int32)  # each block's first span
        free[pages] = run[pages] = width
        bottoms[pages] = 0
        pages += 1
        start = _pack_from(
            start,
            order,
            shapes,
            kind,
            *flat,
            p,
            span[:pages],
            most[:pages],
            free[:pages],
            run[:pages],
            bottoms[:pages],
            resume,
            page,
            x,
            y,
        )
    sizes = np.array([[width, min(max_page, _round4(b))] for b in bottoms[:pages]], dtype=np.int64)
    return MaskLayout(page, x, y, sizes)


def _flattened(cells, need, need_run, grown) -> tuple[np.ndarray, ...]:
    """The per-mask arrays of :func:`_pack` as flat arrays and offsets, for :func:`_pack_from`:
    each mask's cells as runs (row, first column, length) in row-major order."""

    def offsets(counts) -> np.ndarray:
        return np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)

    rows = np.concatenate([c[0] for c in cells]).astype(np.int64)
    cols = np.concatenate([c[1] for c in cells]).astype(np.int64)
    cell_at = offsets([len(c[0]) for c in cells])
    starts = np.ones(len(rows), bool)  # a run starts at a mask's first cell, a new row, or a gap
    starts[1:] = (rows[1:] != rows[:-1]) | (cols[1:] != cols[:-1] + 1)
    starts[cell_at[:-1][cell_at[:-1] < len(rows)]] = True
    first = np.flatnonzero(starts)
    lens = np.diff(np.append(first, len(rows)))
    run_at = np.searchsorted(first, cell_at)  # each mask's first run
    flat_grown = [g.ravel() for g in grown]
    return (
        run_at, rows[first], cols[first], lens,
        offsets([len(part) for part in need]), np.concatenate(need).astype(np.int64), np.concatenate(need_run).astype(np.int64),
        offsets([len(part) for part in flat_grown]), np.concatenate(flat_grown),
    )  # fmt: skip
