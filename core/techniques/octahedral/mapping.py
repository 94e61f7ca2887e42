"""The octahedral map: (n, 3) float64 unit directions <-> (n, 2) float64 grid coordinates in [0, 1]².

Full sphere (Cigolle, Donow, Evangelakos, Mara, McGuire, Meyer, *A Survey of Efficient
Representations for Independent Unit Vectors*, JCGT 3(2) 2014, §3.4 "oct"): a direction ``d`` is
projected onto the octahedron ``|x| + |y| + |z| = 1`` (``p = d / (|x| + |y| + |z|)``); the upper
half (``z >= 0``) keeps ``(p.x, p.y)``, the lower half is folded out over the square's corners,
``(1 - |p.y|, 1 - |p.x|)`` with the signs of ``(p.x, p.y)``; ``[-1, 1]² -> [0, 1]²``.  World ``+z``
is up (farfield's convention), so the top-down view lands in the square's centre.

Hemisphere (the hemi-octahedral map of the same survey's §3.5 and of the impostor bakers, e.g.
Ryan Brucks' for Unreal and Amplify Impostors): only ``z >= 0``; the upper pyramid's diamond
``|x| + |y| <= 1`` is turned by 45° to fill the square, ``(p.x + p.y, p.x - p.y)``; the horizon
is the square's border.  Directions below the horizon are clamped onto it.

A **frame grid** of ``N x N`` frames puts frame ``(i, j)`` (column i along the map's first
coordinate, row j along the second) at the grid point ``(i, j) / (N - 1)``: the frames sit on the
square's corners and border too, so every direction lies inside one grid cell, whose two
triangles (split along the (0, 0)-(1, 1) diagonal... the anti-diagonal, see :func:`blend_frames`)
give the three frames a runtime blends by their barycentric weights.  On the full sphere's
border two grid points of mirrored positions are the same direction: both frames are kept, so a
cell never wraps around.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np


def _unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def encode(directions: np.ndarray, hemisphere: bool = False) -> np.ndarray:
    """(n, 2) float64 map coordinates in [0, 1]² of (n, 3) directions (need not be unit).

    >>> encode(np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])).tolist()
    [[0.5, 0.5], [1.0, 0.5], [1.0, 1.0]]
    >>> encode(np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]), hemisphere=True).tolist()
    [[0.5, 0.5], [1.0, 1.0], [0.0, 1.0]]
    >>> encode(np.array([[1.0, 0.0, -1.0], [0.0, 0.0, -1.0]]), hemisphere=True).tolist()  # below: onto the horizon
    [[1.0, 1.0], [1.0, 1.0]]
    """
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    p = d / np.sum(np.abs(d), axis=1, keepdims=True)
    if hemisphere:
        x, y = p[:, 0].copy(), p[:, 1].copy()
        below = p[:, 2] < 0.0  # clamped onto the horizon, straight down onto its +x point
        ring = np.abs(x) + np.abs(y)
        x[below & (ring == 0.0)], ring[below & (ring == 0.0)] = 1.0, 1.0
        x[below], y[below] = x[below] / ring[below], y[below] / ring[below]
        uv = np.stack([x + y, x - y], axis=1)
    else:
        xy = p[:, :2].copy()
        lower = p[:, 2] < 0.0
        sign = np.where(xy >= 0.0, 1.0, -1.0)
        folded = (1.0 - np.abs(xy[:, ::-1])) * sign
        uv = np.where(lower[:, None], folded, xy)
    return np.clip(uv * 0.5 + 0.5, 0.0, 1.0)


def decode(uv: np.ndarray, hemisphere: bool = False) -> np.ndarray:
    """(n, 3) float64 unit directions of (n, 2) map coordinates in [0, 1]² (inverse of :func:`encode`).

    >>> decode(np.array([[0.5, 0.5], [1.0, 0.5], [1.0, 1.0]])).round(12).tolist()
    [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]
    >>> decode(np.array([[1.0, 1.0], [0.0, 1.0]]), hemisphere=True).round(12).tolist()
    [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]
    """
    f = np.asarray(uv, dtype=np.float64).reshape(-1, 2) * 2.0 - 1.0
    if hemisphere:
        x, y = 0.5 * (f[:, 0] + f[:, 1]), 0.5 * (f[:, 0] - f[:, 1])
        z = 1.0 - np.abs(x) - np.abs(y)
        return _unit(np.stack([x, y, z], axis=1))
    x, y = f[:, 0], f[:, 1]
    z = 1.0 - np.abs(x) - np.abs(y)
    t = np.maximum(-z, 0.0)  # the lower half: fold back (Cigolle et al. 2014, listing 6's form)
    x = x - np.where(x >= 0.0, t, -t)
    y = y - np.where(y >= 0.0, t, -t)
    return _unit(np.stack([x, y, z], axis=1))


def frame_directions(n: int, hemisphere: bool = False) -> np.ndarray:
    """(n*n, 3) float64 unit directions (from the part towards the viewer) of the ``n x n`` frame
    grid, frame ``j * n + i`` at grid point ``(i, j) / (n - 1)``.

    >>> frame_directions(3).round(12).tolist()[4], frame_directions(3, hemisphere=True).round(12).tolist()[0]
    ([0.0, 0.0, 1.0], [-1.0, 0.0, 0.0])
    """
    j, i = np.divmod(np.arange(n * n), n)
    return decode(np.stack([i, j], axis=1) / (n - 1), hemisphere)


def blend_frames(directions: np.ndarray, n: int, hemisphere: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The three frames around each of (m, 3) view directions (from the part towards the viewer)
    and their barycentric weights: ((m, 3) int64 frame indices, (m, 3) float64 weights summing to 1).

    The direction's map point falls in the grid cell ``(i, j)``-``(i+1, j+1)``; with fractions
    ``(fx, fy)`` the cell's lower triangle (``fx + fy <= 1``) blends the corners ``(i, j)``,
    ``(i+1, j)``, ``(i, j+1)`` by ``(1 - fx - fy, fx, fy)``, the upper one ``(i+1, j+1)``,
    ``(i+1, j)``, ``(i, j+1)`` by ``(fx + fy - 1, 1 - fy, 1 - fx)``.

    >>> frames, weights = blend_frames(np.array([[0.0, 0.0, 1.0]]), 3)
    >>> frames.tolist(), weights.tolist()
    ([[4, 5, 7]], [[1.0, 0.0, 0.0]])
    """
    g = encode(directions, hemisphere) * (n - 1)
    cell = np.minimum(np.floor(g), n - 2).astype(np.int64)
    f = g - cell
    fx, fy = f[:, 0], f[:, 1]
    i, j = cell[:, 0], cell[:, 1]
    upper = fx + fy > 1.0
    first = np.where(upper, (j + 1) * n + i + 1, j * n + i)
    frames = np.stack([first, j * n + i + 1, (j + 1) * n + i], axis=1)
    weights = np.where(
        upper[:, None],
        np.stack([fx + fy - 1.0, 1.0 - fy, 1.0 - fx], axis=1),
        np.stack([1.0 - fx - fy, fx, fy], axis=1),
    )
    return frames, np.clip(weights, 0.0, 1.0)


def fibonacci_directions(count: int, hemisphere: bool = False) -> np.ndarray:
    """(count, 3) float64 unit directions spread evenly over the sphere (or the upper hemisphere,
    horizon included), deterministic: the spherical Fibonacci lattice.

    >>> d = fibonacci_directions(1000, hemisphere=True)
    >>> bool(np.allclose(np.linalg.norm(d, axis=1), 1.0)), bool(d[:, 2].min() >= 0.0)
    (True, True)
    """
    k = np.arange(count, dtype=np.float64) + 0.5
    z = 1.0 - k / count if hemisphere else 1.0 - 2.0 * k / count
    if hemisphere:
        z = np.concatenate([z[:-1], [0.0]])  # the horizon itself, where the grazing views are
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    s = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)


def median_angle(directions: np.ndarray, n: int, hemisphere: bool = False) -> np.ndarray:
    """(m,) float64 radians: for each view direction, the smallest angle ``theta`` such that the
    blended frames (:func:`blend_frames`) within ``theta`` of it carry more than half the weight.

    A runtime that cuts the blended alpha at 0.5 shows a texel only where frames of more than half
    the weight agree, so the parallax of frames farther than this angle cannot move a silhouette
    (docs/techniques/octahedral.md, "accuracy distance").

    >>> float(median_angle(np.array([[0.0, 0.0, 1.0]]), 5)[0])  # on a frame: that frame alone
    0.0
    """
    d = _unit(np.asarray(directions, dtype=np.float64).reshape(-1, 3))
    frames, weights = blend_frames(d, n, hemisphere)
    grid = frame_directions(n, hemisphere)
    angles = np.arccos(np.clip(np.einsum("mkc,mc->mk", grid[frames], d), -1.0, 1.0))
    order = np.argsort(angles, axis=1, kind="stable")
    sorted_angles = np.take_along_axis(angles, order, axis=1)
    cumulative = np.cumsum(np.take_along_axis(weights, order, axis=1), axis=1)
    first = np.argmax(cumulative > 0.5 - 1e-12, axis=1)
    return sorted_angles[np.arange(d.shape[0]), first]


@lru_cache(maxsize=64)  # the same for every part: a placement asks once per node (0.05 s each)
def grid_angle(n: int, hemisphere: bool = False, samples: int = 20000) -> float:
    """Radians: the largest :func:`median_angle` over ``samples`` directions of the sphere (or
    hemisphere) spread evenly (:func:`fibonacci_directions`): the angular error bound of the grid.

    >>> a8, a16 = grid_angle(8), grid_angle(16)
    >>> 1.8 < a8 / a16 < 2.4  # halves as the grid doubles
    True
    """
    return float(median_angle(fibonacci_directions(samples, hemisphere), n, hemisphere).max())


def opposite_frames(n: int, hemisphere: bool = False) -> np.ndarray:
    """(n*n,) int64: for each frame of the grid, a frame looking the opposite way (direction ``-d``),
    or -1 where the grid has none.  On the full sphere every frame has one when ``n`` is odd (the
    map sends ``-d`` of a grid point to a grid point then); on the hemisphere only the horizon's.

    >>> bool((opposite_frames(5) >= 0).all()), int((opposite_frames(4) >= 0).sum())
    (True, 0)
    >>> d = frame_directions(5); o = opposite_frames(5)
    >>> bool(np.allclose(d[o], -d))
    True
    """
    d = frame_directions(n, hemisphere)
    dots = d @ d.T
    best = np.argmin(dots, axis=1)
    return np.where(dots[np.arange(len(d)), best] < -1.0 + 1e-9, best, -1).astype(np.int64)
