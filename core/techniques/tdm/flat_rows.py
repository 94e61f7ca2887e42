"""Flat rows of the initial mesh: the quads of a layer's flat regions merged row by row before the
simplification (farfield's addition to seed 003 §5).

The rule sets of :mod:`farfield.core.techniques.tdm.mesh` give every voxel four vertices, and a
layer's flat run of voxels becomes a grid of quads on that layer whose inner vertices the
simplification's first pass then contracts away one edge at a time (seed 003 §6): on the scan of
``benchmarks/bench_tdm_scale.py --scene scan`` that pass removes 96 % of 8.8 M initial triangles
and was two thirds of the cascade's time.  Here the grid is thinned before the simplification:

* a vertex is *inner* when exactly four quads use it, all lying in its layer (none standing between
  two layers) and each with it at a different corner: the four cells around it on one plane.  An
  inner vertex whose grid column is not a multiple of ``every`` is dropped;
* each maximal row of such quads (one layer, one grid row, consecutive columns) is cut at the
  columns whose top and bottom vertices both stay, and each piece with a dropped vertex becomes a
  strip of triangles between its kept top and bottom vertices (a zipper, left to right): the same
  rectangle of the plane, the same orientation, no T-junction (a dropped vertex is in no triangle
  at all, and every kept vertex on a row's edge is a vertex of both rows beside it).

Nothing else changes: the boundary, the standing walls, the meshes and the slits are the same, and
every voxel a merged quad stored goes to a strip triangle that meets its box (the strips cover the
quads' rectangles exactly, so one does).  The kept columns bound a strip's length, and so the
valence of its vertices (a zipper with one long side is a fan), which the simplification's
neighbour lists pay for quadratically.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from farfield.core.errors import InternalError
from farfield.core.techniques.tdm.simplify import _vertex_slab

# Columns of the half-texel vertex grid (two a texel) between kept columns of inner vertices.
KEEP_EVERY = 16


def inner_vertices(corner_index: np.ndarray, flat: np.ndarray, vertex_count: int) -> np.ndarray:
    """(v,) bool: the inner vertices (module docstring) of quads whose corners are ``corner_index``
    (q, 4) vertex numbers in the order (X, Y), (X + 1, Y), (X + 1, Y + 1), (X, Y + 1), of which
    ``flat`` (q,) lie in one layer.

    >>> quads = np.array([[0, 1, 4, 3], [1, 2, 5, 4], [3, 4, 7, 6], [4, 5, 8, 7]])  # a 2 x 2 grid
    >>> np.flatnonzero(inner_vertices(quads, np.ones(4, bool), 9)).tolist()
    [4]
    >>> np.flatnonzero(inner_vertices(quads, np.array([1, 1, 1, 0], bool), 9)).tolist()
    []
    """
    used = np.bincount(corner_index.ravel(), minlength=vertex_count)
    inner = used == 4
    for corner in range(4):
        inner &= np.bincount(corner_index[flat, corner], minlength=vertex_count) == 1
    return inner


def merge_flat_rows(
    vertices: np.ndarray,
    quads: np.ndarray,
    corner_index: np.ndarray,
    column: np.ndarray,
    owner: np.ndarray,
    centres: np.ndarray,
    every: int = KEEP_EVERY,
) -> tuple[np.ndarray, np.ndarray, int]:
    """The initial mesh with its flat rows merged (module docstring): (triangles (t, 3) int64,
    each voxel's storing triangle among them, the quads merged).

    ``quads`` (q, 4, 3) int64: each quad's corners (X, Y, layer) in the half-texel grid, in the
    order above; ``corner_index`` (q, 4): their vertex numbers; ``column`` (v,): each vertex's grid
    X; ``owner`` (n,): each voxel's triangle in the quads' triangles (quad i: 2i, 2i + 1).  The
    triangles come in the quads' order, a merged piece's where its first quad was."""
    count = quads.shape[0]
    flat = (quads[:, :, 2] == quads[:, :1, 2]).all(axis=1)
    drop = inner_vertices(corner_index, flat, len(vertices))
    if every > 0:
        drop &= column % every != 0
    rows = np.flatnonzero(flat)
    # The flat quads by (layer, Y, X) of their first corner: rows of consecutive columns.
    first = quads[rows, 0]
    rows = rows[np.lexsort((first[:, 0], first[:, 1], first[:, 2]))]
    piece, starts, strips = _zip_rows(
        rows,
        np.ascontiguousarray(quads[:, 0]),
        np.ascontiguousarray(corner_index, dtype=np.int64),
        drop,
        vertices[:, 0].copy(),
        count,
    )
    triangles, remap, placed = _emit(piece, starts, strips, np.ascontiguousarray(corner_index, dtype=np.int64))
    owner, missed = _reassign(owner, remap, piece, starts, placed, triangles, vertices, centres)
    if missed:
        raise InternalError(f"{missed} voxels of merged flat rows met no strip triangle")
    return triangles, owner, int((piece >= 0).sum())


@njit(cache=True)
def _zip_rows(rows, corner, index, drop, xpos, count):
    """The pieces of the sorted flat quads ``rows`` (module docstring): each quad's piece (-1 where
    it stays as it is), the pieces' first strip triangles (offsets) and the strip triangles."""
    n = rows.shape[0]
    piece = np.full(count, -1, np.int64)
    starts = np.empty(n + 1, np.int64)
    strips = np.empty((2 * n + 2, 3), np.int64)
    top = np.empty(n + 1, np.int64)
    bottom = np.empty(n + 1, np.int64)
    made = 0
    pieces = 0
    i = 0
    while i < n:
        j = i + 1
        while (
            j < n
            and corner[rows[j], 2] == corner[rows[i], 2]
            and corner[rows[j], 1] == corner[rows[i], 1]
            and corner[rows[j], 0] == corner[rows[j - 1], 0] + 1
        ):
            j += 1
        length = j - i
        for k in range(length):
            top[k] = index[rows[i + k], 0]
            bottom[k] = index[rows[i + k], 3]
        top[length] = index[rows[j - 1], 1]
        bottom[length] = index[rows[j - 1], 2]
        start = 0
        for c in range(1, length + 1):
            if c < length and (drop[top[c]] or drop[bottom[c]]):
                continue
            if c - start > 1:  # columns start .. c with a dropped vertex between: one strip
                starts[pieces] = made
                for k in range(start, c):
                    piece[rows[i + k]] = pieces
                t, b = start, start
                while t < c or b < c:
                    tn = t + 1
                    while tn < c and drop[top[tn]]:
                        tn += 1
                    bn = b + 1
                    while bn < c and drop[bottom[bn]]:
                        bn += 1
                    if b == c or (t < c and xpos[top[tn]] <= xpos[bottom[bn]]):
                        strips[made, 0], strips[made, 1], strips[made, 2] = top[t], top[tn], bottom[b]
                        t = tn
                    else:
                        strips[made, 0], strips[made, 1], strips[made, 2] = top[t], bottom[bn], bottom[b]
                        b = bn
                    made += 1
                pieces += 1
            start = c
        i = j
    starts[pieces] = made
    return piece, starts[: pieces + 1].copy(), strips[:made].copy()


@njit(cache=True)
def _emit(piece, starts, strips, index):
    """The triangles in the quads' order (a quad's two, or its piece's strip at the piece's first
    quad), each old triangle's new number (-1: merged) and each piece's first new triangle."""
    count = piece.shape[0]
    pieces = starts.shape[0] - 1
    out = np.empty((2 * count, 3), np.int64)
    remap = np.full(2 * count, -1, np.int64)
    placed = np.full(pieces, -1, np.int64)
    made = 0
    for q in range(count):
        s = piece[q]
        if s < 0:
            out[made, 0], out[made, 1], out[made, 2] = index[q, 0], index[q, 1], index[q, 2]
            out[made + 1, 0], out[made + 1, 1], out[made + 1, 2] = index[q, 0], index[q, 2], index[q, 3]
            remap[2 * q], remap[2 * q + 1] = made, made + 1
            made += 2
        elif placed[s] < 0:
            placed[s] = made
            for k in range(starts[s], starts[s + 1]):
                out[made, 0], out[made, 1], out[made, 2] = strips[k, 0], strips[k, 1], strips[k, 2]
                made += 1
    return out[:made].copy(), remap, placed


@njit(cache=True)
def _reassign(owner, remap, piece, starts, placed, triangles, vertices, centres):
    """Each voxel's triangle after the merge: its own renumbered, or the first triangle of its
    merged quad's strip that meets its unit box; and how many found none (0)."""
    out = np.empty_like(owner)
    missed = 0
    for v in range(owner.shape[0]):
        t = owner[v]
        if remap[t] >= 0:
            out[v] = remap[t]
            continue
        s = piece[t // 2]
        out[v] = -1
        for k in range(placed[s], placed[s] + starts[s + 1] - starts[s]):
            if _vertex_slab(vertices, triangles[k, 0], triangles[k, 1], triangles[k, 2],
                            centres[v, 0], centres[v, 1], centres[v, 2], 0.5, 0.5):  # fmt: skip
                out[v] = k
                break
        if out[v] < 0:
            missed += 1
    return out, missed
