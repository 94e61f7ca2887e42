"""Layer quads: (q, 4) int64 texel rectangles ``[x0, y0, x1, y1)`` that cover a (h, w) bool layer coverage.

Seed 000 §3.5 ("Memory-Efficient Layer Encoding"): instead of one quad per layer, every layer gets a
set of quads that together enclose all of its opaque texels, found by greedy *box growing* on a
coarse grid of ``cell`` × ``cell`` texel grid cells.  Rectangles follow :mod:`farfield.core.impostor.impostor`'s
convention: integer texel indices, x right, y down, images top row first.

The baselines of the memory comparison in seed 000 Table 3.1 are here too: :func:`full_quad` (one
quad over the whole layer, "approximately 6.15 MB" for the dragon) and :func:`single_quad` (one
tight quad per layer, Schaufler's choice [Scha98b], the last column of the table).
"""

from __future__ import annotations

import math

import numpy as np

from farfield.core.errors import LayerPlanError

# Growth directions in tie-breaking order: (rows added above, below, columns added left, right).
# A diagonal step extends two sides at once (seed 000 §3.5: "grown at steps of one cell in
# axis-parallel and diagonal directions").
_DIRECTIONS: tuple[tuple[int, int, int, int], ...] = (
    (1, 0, 0, 0),  # N
    (0, 1, 0, 0),  # S
    (0, 0, 1, 0),  # W
    (0, 0, 0, 1),  # E
    (1, 0, 1, 0),  # NW
    (1, 0, 0, 1),  # NE
    (0, 1, 1, 0),  # SW
    (0, 1, 0, 1),  # SE
)


def _check_coverage(coverage, ndim: int) -> np.ndarray:
    cov = np.asarray(coverage)
    if cov.ndim != ndim:
        raise LayerPlanError(f"coverage must be a {ndim}-D bool array, got shape {cov.shape}")
    return cov.astype(bool, copy=False)


def _check_cell(cell) -> int:
    if isinstance(cell, bool) or not isinstance(cell, (int, np.integer)) or cell < 1:
        raise LayerPlanError(f"grid cell size must be an integer >= 1 texel, got {cell!r}")
    return int(cell)


def _check_threshold(fill_threshold) -> float:
    t = float(fill_threshold)
    if not (math.isfinite(t) and 0.0 < t <= 1.0):
        raise LayerPlanError(f"fill threshold must lie in (0, 1], got {fill_threshold!r}")
    return t


def filled_cells(coverage: np.ndarray, cell: int) -> np.ndarray:
    """(ceil(h / cell), ceil(w / cell)) bool grid: True where a grid cell holds >= 1 covered texel.

    Grid cells on the right and bottom border are clipped to the image (seed 000 §3.5, "filled").

    >>> filled_cells(np.eye(3, dtype=bool), 2).astype(int).tolist()
    [[1, 0], [0, 1]]
    """
    cov = _check_coverage(coverage, 2)
    cell = _check_cell(cell)
    h, w = cov.shape
    filled = np.zeros((-(-h // cell), -(-w // cell)), dtype=bool)
    # Each covered texel marks its cell: a layer keeps a few per cent of its texels, so this beats
    # reducing a padded copy of the whole layer per cell (CPU for the 97 layers of the layered
    # benchmark at 1024 px: 0.03 s against 0.31 s).
    covered = np.flatnonzero(cov)
    filled[covered // w // cell, covered % w // cell] = True
    return filled


def grow_quads(coverage: np.ndarray, cell: int = 8, fill_threshold: float = 0.8) -> np.ndarray:
    """(q, 4) int64 rects ``[x0, y0, x1, y1)`` covering every True texel of ``coverage``.

    Greedy box growing of seed 000 §3.5.  Grid cells with at least one covered texel are *filled*.
    The first remaining filled cell in row-major order seeds a rectangle of cells, which grows one
    cell at a time along one of 4 axis directions or 4 diagonals (a diagonal extends two sides and
    their corner).  Each step takes the candidate whose added cells have the best fill ratio
    (filled / added); ties go to the candidate adding more filled cells, then to the fixed order
    N, S, W, E, NW, NE, SW, SE.  Growth stops when no candidate adds a filled cell, or when the best
    one would bring the whole rectangle's fill ratio below ``fill_threshold`` (as in the thesis, the
    other candidates are then not tried).  The rectangle is emitted and its cells are removed; this
    repeats until no filled cell remains.

    Deviation from the thesis: the thesis marks an emitted rectangle's cells *empty*, so a later
    rectangle may grow over them as waste.  Here they are *blocked*: a later rectangle may not
    include them, so the quads are disjoint in grid cells and no texel is stored twice.

    Parameters
    ----------
    coverage : (h, w) bool
        Covered (opaque) texels of one layer, top row first.
    cell : int
        Grid cell size in texels (>= 1).  Smaller cells waste fewer texels but give more quads
        (seed 000 Table 3.1).
    fill_threshold : float
        Smallest fill ratio (filled / all grid cells) a rectangle may reach, in (0, 1].  Smaller
        values give fewer quads and more wasted texels; the thesis found 0.8 "to work well".

    Returns
    -------
    rects : (q, 4) int64
        ``[x0, y0, x1, y1)`` in texels, aligned to the cell grid except where clipped to the image
        border.  Disjoint; together they contain every True texel.  Emitted in seed order.

    Raises
    ------
    LayerPlanError
        ``coverage`` is not 2-D, ``cell`` is not an integer >= 1, or ``fill_threshold`` is not in
        (0, 1].

    Examples
    --------
    An L shape of three filled cells becomes two quads at threshold 1, one at 0.75:

    >>> cov = np.zeros((4, 4), dtype=bool); cov[:2, :] = True; cov[2:, :2] = True
    >>> grow_quads(cov, cell=2, fill_threshold=1.0).tolist()
    [[0, 0, 2, 4], [2, 0, 4, 2]]
    >>> grow_quads(cov, cell=2, fill_threshold=0.75).tolist()
    [[0, 0, 4, 4]]

    Grid cells are clipped at the image border, and an empty layer has no quads:

    >>> grow_quads(np.ones((3, 5), dtype=bool), cell=4).tolist()
    [[0, 0, 5, 3]]
    >>> grow_quads(np.zeros((3, 5), dtype=bool)).shape
    (0, 4)
    """
    cov = _check_coverage(coverage, 2)
    cell = _check_cell(cell)
    threshold = _check_threshold(fill_threshold)
    h, w = cov.shape
    if h == 0 or w == 0 or not cov.any():
        return np.zeros((0, 4), dtype=np.int64)
    filled = filled_cells(cov, cell)
    cells = _grow_cells(filled, threshold)
    rects = cells[:, [2, 0, 3, 1]] * cell  # cell rows/cols -> texel x0, y0, x1, y1
    np.minimum(rects, [w, h, w, h], out=rects)
    return rects


def _grow_cells(filled: np.ndarray, threshold: float) -> np.ndarray:
    """(q, 4) int64 cell rectangles ``[r0, r1, c0, c1)`` of the greedy box growing on ``filled``.

    A Python loop on purpose: each step is a handful of O(1) integer look-ups (a summed-area table
    of the filled cells as nested lists, and bit masks of blocked cells per row and per column),
    which beats numpy's per-call overhead at this grain.  Measured: 2-9 ms for a blobby 512 x 512
    layer at cell 8 (a 64 x 64 grid), ``tests/test_quads.py::test_speed_512`` guards it.
    """
    gh, gw = filled.shape
    sat_arr = np.zeros((gh + 1, gw + 1), dtype=np.int64)
    np.cumsum(np.cumsum(filled, axis=0, dtype=np.int64), axis=1, out=sat_arr[1:, 1:])
    sat = sat_arr.tolist()
    # Emitted cells: bit c of row_blocked[r] and bit r of col_blocked[c].  Any rectangle grown
    # from here on holds no blocked cell, so the static table counts its remaining filled cells.
    row_blocked = [0] * gh
    col_blocked = [0] * gw
    out: list[tuple[int, int, int, int]] = []

    def strip_free(masks: list[int], line: int, lo: int, hi: int) -> bool:
        return not (masks[line] >> lo) & ((1 << (hi - lo)) - 1)

    for seed in np.flatnonzero(filled).tolist():
        r, c = divmod(seed, gw)
        if (row_blocked[r] >> c) & 1:
            continue
        r0, r1, c0, c1 = r, r + 1, c, c + 1
        n_filled, n_cells = 1, 1
        while True:
            # Which sides (and corners) may be added: inside the grid and free of blocked cells.
            n_ok = r0 > 0 and strip_free(row_blocked, r0 - 1, c0, c1)
            s_ok = r1 < gh and strip_free(row_blocked, r1, c0, c1)
            w_ok = c0 > 0 and strip_free(col_blocked, c0 - 1, r0, r1)
            e_ok = c1 < gw and strip_free(col_blocked, c1, r0, r1)
            best = None
            best_f = 0
            best_a = 1
            for dn, ds, dw, de in _DIRECTIONS:
                if (dn and not n_ok) or (ds and not s_ok) or (dw and not w_ok) or (de and not e_ok):
                    continue
                nr0, nr1, nc0, nc1 = r0 - dn, r1 + ds, c0 - dw, c1 + de
                if (dn or ds) and (dw or de):
                    cr = nr0 if dn else r1
                    cc = nc0 if dw else c1
                    if (row_blocked[cr] >> cc) & 1:
                        continue
                f = sat[nr1][nc1] - sat[nr0][nc1] - sat[nr1][nc0] + sat[nr0][nc0] - n_filled
                if f == 0:
                    continue
                a = (nr1 - nr0) * (nc1 - nc0) - n_cells
                # Integer cross-multiplication compares f/a exactly.
                if best is None or f * best_a > best_f * a or (f * best_a == best_f * a and f > best_f):
                    best, best_f, best_a = (nr0, nr1, nc0, nc1), f, a
            if best is None or (n_filled + best_f) < threshold * (n_cells + best_a):
                break
            r0, r1, c0, c1 = best
            n_filled += best_f
            n_cells += best_a
        out.append((r0, r1, c0, c1))
        col_mask = ((1 << (c1 - c0)) - 1) << c0
        row_mask = ((1 << (r1 - r0)) - 1) << r0
        for rr in range(r0, r1):
            row_blocked[rr] |= col_mask
        for cc in range(c0, c1):
            col_blocked[cc] |= row_mask
    return np.asarray(out, dtype=np.int64).reshape(-1, 4)


def quads_for_layers(coverage: np.ndarray, cell: int = 8, fill_threshold: float = 0.8) -> list[np.ndarray]:
    """One (q_i, 4) int64 rect array per layer of a (k, h, w) bool coverage stack (see :func:`grow_quads`).

    >>> cov = np.zeros((2, 4, 4), dtype=bool); cov[0, 0, 0] = True
    >>> [r.tolist() for r in quads_for_layers(cov, cell=2)]
    [[[0, 0, 2, 2]], []]
    """
    cov = _check_coverage(coverage, 3)
    cell = _check_cell(cell)
    threshold = _check_threshold(fill_threshold)
    return [grow_quads(layer, cell, threshold) for layer in cov]


def single_quad(coverage: np.ndarray) -> np.ndarray:
    """(0 or 1, 4) int64: the tight bounding rect ``[x0, y0, x1, y1)`` of the True texels.

    One tightly enclosing quad per layer, as proposed by Schaufler [Scha98b] (seed 000 §3.5, the
    last column of Table 3.1).

    >>> cov = np.zeros((5, 6), dtype=bool); cov[1, 2] = cov[3, 4] = True
    >>> single_quad(cov).tolist()
    [[2, 1, 5, 4]]
    >>> single_quad(np.zeros((5, 6), dtype=bool)).shape
    (0, 4)
    """
    cov = _check_coverage(coverage, 2)
    rows = np.flatnonzero(cov.any(axis=1))
    if rows.size == 0:
        return np.zeros((0, 4), dtype=np.int64)
    cols = np.flatnonzero(cov.any(axis=0))
    return np.array([[cols[0], rows[0], cols[-1] + 1, rows[-1] + 1]], dtype=np.int64)


def full_quad(h: int, w: int) -> np.ndarray:
    """(1, 4) int64: the whole-layer rect ``[0, 0, w, h)``, the one-quad-per-layer baseline (seed 000 §3.5).

    >>> full_quad(3, 5).tolist()
    [[0, 0, 5, 3]]
    """
    if isinstance(h, bool) or isinstance(w, bool) or int(h) != h or int(w) != w or h < 0 or w < 0:
        raise LayerPlanError(f"layer size must be non-negative integers, got h={h!r}, w={w!r}")
    return np.array([[0, 0, int(w), int(h)]], dtype=np.int64)


def rect_areas(rects: np.ndarray) -> np.ndarray:
    """(q,) int64 texel count of each ``[x0, y0, x1, y1)`` rect of a (q, 4) int array.

    The texture-memory measure of seed 000 Table 3.1 is ``rect_areas(rects).sum()`` times the bytes
    per texel.

    >>> rect_areas(np.array([[0, 0, 5, 3], [2, 2, 4, 3]])).tolist()
    [15, 2]
    """
    r = np.asarray(rects, dtype=np.int64).reshape(-1, 4)
    return (r[:, 2] - r[:, 0]) * (r[:, 3] - r[:, 1])
