"""The inner image-placement loop (seed 004 §3.3.2): the contiguous subset of cells one view replaces with
an image, chosen by the cost-benefit function over 6-tuple subsets.

**Subsets** (§3.3.2.2, Fig. 9).  The cells a subset may take are projected from the grid point in the
view's direction: each has a screen box ``[x0, x1] x [y0, y1]`` (in units of ``tan(alpha)``, the
frame spanning -1..1) and a depth range ``[z0, z1]`` along the view direction.  Five sorted lists
hold the distinct left, right, bottom, top and near borders; a subset ``(l, r, b, t, n)`` holds the
cells whose borders lie inside those indices' values.  Moving a border to its next value changes
one index.  The far border is never moved (the paper's sixth index): an image replaces what lies
behind its plane.

**Cost-benefit** (§3.3.2.1): ``CB = C (1 - g_c / G_c) + B (B1 (1 - max(I_w, I_h) / max(S_w, S_h)) +
B2 d / A)`` with ``C = 0.4, B = 0.6, B1 = 0.1, B2 = 0.9`` (§5).  ``g_c`` is what the view still draws,
``G_c`` what it drew, ``I`` the subset's screen box clamped to the frame (``S = 2``), ``d`` the
distance from the grid point to the subset's nearest cell corner, ``A`` the model's longest side.

**Search** (§3.3.2.3).  From the subset of all the cells, each step makes five subsets: the near
border moved halfway back, the top halfway down, the bottom halfway up, the right halfway left and
the left halfway right.  "Halfway" is the paper's binary-search step, which it leaves unspecified.
Here a border moves half the way, in its own list, to the last index that still leaves the subset
a cell on that axis.  Each of the five is scored by looking ``lookahead`` steps further (the best
CB of a subset that still culls enough, among it and its descendants).  The best is taken, ties in
the order listed.  When no halfway move culls enough, the step is halved (a quarter, an eighth,
..., one index) before the search stops.  The answer is the subset the search stops at, the
smallest it reached that still culls enough (``g_c <= p_opt``), as in the paper: "iterations stop
when the subset no longer culls enough geometry".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from farfield.core.placement.yaw_ranges import forward, right

C, B, B1, B2 = 0.4, 0.6, 0.1, 0.9  # seed 004 §5
DEFAULT_LOOKAHEAD = 2
MOVES = ("near", "top", "bottom", "right", "left")  # the paper's order, which breaks ties


@dataclass(frozen=True)
class CellSubset:
    """A chosen subset: the cells (indices into the cells the search was given), what the view still
    draws, its score, and the image quad (4 corners, world units) at its nearest depth."""

    cells: np.ndarray  # (k,) int64
    drawn: float  # g_c
    score: float  # CB
    depth: float  # the quad's distance ahead of the grid point
    quad: np.ndarray  # (4, 3) float64: corners, counter-clockwise from bottom-left as seen from the grid point
    steps: int  # subsets evaluated


def corners_of(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(n, 8, 3): the corners of boxes ``lo``..``hi``."""
    pick = [(i, j, k) for i in (0, 1) for j in (0, 1) for k in (0, 1)]
    bounds = (lo, hi)
    return np.stack([np.stack([bounds[i][:, 0], bounds[j][:, 1], bounds[k][:, 2]], axis=1) for i, j, k in pick], axis=1)


def project_cells(lo: np.ndarray, hi: np.ndarray, apex: np.ndarray, yaw: float, half: float) -> dict[str, np.ndarray]:
    """Screen boxes (units of ``tan(half)``), depths and nearest-corner distances of boxes wholly ahead of ``apex``."""
    c = corners_of(lo, hi) - apex  # (n, 8, 3)
    f, r, t = forward(yaw), right(yaw), math.tan(half)
    z = c @ f
    if np.any(z <= 0.0):
        raise ValueError("project_cells needs boxes wholly ahead of the apex")
    x = (c @ r) / (z * t)
    y = c[..., 1] / (z * t)
    return {"x0": x.min(axis=1), "x1": x.max(axis=1), "y0": y.min(axis=1), "y1": y.max(axis=1),
            "z0": z.min(axis=1), "z1": z.max(axis=1), "near": np.linalg.norm(c, axis=2).min(axis=1)}  # fmt: skip


class SubsetSearch:
    """The 6-tuple search over ``cells`` (a view's candidate cells) for one view."""

    def __init__(self, screen: dict[str, np.ndarray], triangles: np.ndarray, drawn_before: float, p_opt: float,
                 model_extent: float, lookahead: int = DEFAULT_LOOKAHEAD) -> None:  # fmt: skip
        self.screen, self.tris = screen, np.asarray(triangles, dtype=np.float64)
        self.total, self.p_opt, self.extent, self.lookahead = (
            float(drawn_before),
            float(p_opt),
            float(model_extent),
            int(lookahead),
        )
        self.lists, self.rank = {}, {}
        for name, key in (("l", "x0"), ("r", "x1"), ("b", "y0"), ("t", "y1"), ("n", "z0")):
            values = np.unique(screen[key])
            self.lists[name] = values
            self.rank[name] = np.searchsorted(values, screen[key])
        self.memo: dict[tuple, tuple[bool, float]] = {}

    def members(self, s: tuple[int, int, int, int, int]) -> np.ndarray:
        rk = self.rank
        return (rk["l"] >= s[0]) & (rk["r"] <= s[1]) & (rk["b"] >= s[2]) & (rk["t"] <= s[3]) & (rk["n"] >= s[4])

    def evaluate(self, s: tuple) -> tuple[bool, float]:
        """(culls enough, CB) of subset ``s``."""
        if s in self.memo:
            return self.memo[s]
        m = self.members(s)
        if not m.any():
            out = (False, -math.inf)
        else:
            drawn = self.total - float(self.tris[m].sum())
            sc = self.screen
            width = np.clip(sc["x1"][m].max(), -1, 1) - np.clip(sc["x0"][m].min(), -1, 1)
            height = np.clip(sc["y1"][m].max(), -1, 1) - np.clip(sc["y0"][m].min(), -1, 1)
            benefit = B1 * (1.0 - max(width, height) / 2.0) + B2 * min(float(sc["near"][m].min()) / self.extent, 1.0)
            out = (drawn <= self.p_opt, C * (1.0 - drawn / self.total) + B * benefit)
        self.memo[s] = out
        return out

    def moves(self, s: tuple, fraction: float) -> list[tuple]:
        """The five subsets one step from ``s`` (a border moved ``fraction`` of its way), in the paper's order."""
        l, r, b, t, n = s
        L, R, Bt, T, N = (self.lists[k] for k in "lrbtn")
        out = []

        def step(span: int) -> int:
            return max(1, int(math.ceil(span * fraction))) if span > 0 else 0

        n_end = len(N) - 1
        out.append((l, r, b, t, n + step(n_end - n)))
        t_end = int(
            np.searchsorted(T, Bt[b], side="left")
        )  # lowest top that keeps a cell's top above the bottom border
        out.append((l, r, b, t - step(t - t_end), n))
        b_end = int(np.searchsorted(Bt, T[t], side="right")) - 1
        out.append((l, r, b + step(b_end - b), t, n))
        r_end = int(np.searchsorted(R, L[l], side="left"))
        out.append((l, r - step(r - r_end), b, t, n))
        l_end = int(np.searchsorted(L, R[r], side="right")) - 1
        out.append((l + step(l_end - l), r, b, t, n))
        return [m for m in out if m != s]

    def value(self, s: tuple, depth: int, fraction: float) -> float:
        """Best CB among ``s`` and its descendants ``depth`` steps ahead that cull enough (-inf if none)."""
        ok, score = self.evaluate(s)
        if not ok:
            return -math.inf  # shrinking a subset only culls less
        best = score
        if depth > 0:
            for m in self.moves(s, fraction):
                best = max(best, self.value(m, depth - 1, fraction))
        return best

    def run(self) -> tuple[tuple, float] | None:
        """(subset, CB) where the search stops, or None when even all the cells do not cull enough."""
        s = (0, len(self.lists["r"]) - 1, 0, len(self.lists["t"]) - 1, 0)
        ok, score = self.evaluate(s)
        if not ok:
            return None
        fraction = 0.5
        while True:
            options = [(self.value(m, self.lookahead, fraction), i, m) for i, m in enumerate(self.moves(s, fraction))]
            options = [o for o in options if o[0] > -math.inf]
            if not options:
                if fraction * max(len(v) for v in self.lists.values()) <= 1.0:
                    return s, score
                fraction /= 2.0
                continue
            top = max(o[0] for o in options)
            s = next(o[2] for o in options if o[0] == top)  # ties: the first in the paper's order
            ok, score = self.evaluate(s)


def place_image(lo: np.ndarray, hi: np.ndarray, triangles: np.ndarray, apex: np.ndarray, yaw: float, half: float,
                drawn_before: float, p_opt: float, model_extent: float, lookahead: int = DEFAULT_LOOKAHEAD) -> CellSubset | None:  # fmt: skip
    """The subset of the given cells (all wholly ahead of ``apex`` at ``yaw``) that one image replaces so
    that the view draws at most ``p_opt``; None when replacing every one of them is not enough."""
    screen = project_cells(lo, hi, apex, yaw, half)
    search = SubsetSearch(screen, triangles, drawn_before, p_opt, model_extent, lookahead)
    found = search.run()
    if found is None:
        return None
    s, score = found
    m = search.members(s)
    depth = float(screen["z0"][m].min())
    t = math.tan(half)
    x0, x1 = float(screen["x0"][m].min()) * t, float(screen["x1"][m].max()) * t
    y0, y1 = float(screen["y0"][m].min()) * t, float(screen["y1"][m].max()) * t
    f, r, u = forward(yaw), right(yaw), np.array([0.0, 1.0, 0.0])
    quad = np.stack([apex + depth * (f + x * r + y * u) for x, y in ((x0, y0), (x1, y0), (x1, y1), (x0, y1))])
    return CellSubset(
        np.flatnonzero(m),
        drawn_before - float(np.asarray(triangles, dtype=np.float64)[m].sum()),
        score,
        depth,
        quad,
        len(search.memo),
    )
