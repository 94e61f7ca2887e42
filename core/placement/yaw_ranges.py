"""The view-directions set of a grid point (seed 004 §3.3.1, Fig. 8): yaw ranges over which the cells a
frustum meets stay the same, and the primitives each range can draw.

Views turn about the vertical axis only (pitch 0, no roll); the frame is square with field of view
``2 alpha`` both ways.  Yaw ``theta`` looks along ``(sin theta, 0, -cos theta)``: 0 is the paper's
starting direction ``z = -1``, and a point's *azimuth* ``phi`` is its yaw seen from the apex, so its
distance ahead is ``rho cos(phi - theta)`` (``rho``: its horizontal distance).

**A cell's yaws.**  From an apex ``g`` a cell is counted at yaw ``theta`` when
- its footprint (the xz rectangle of its bounds) meets the horizontal wedge ``theta +- alpha``:
  exactly when its azimuths ``[phi_lo, phi_hi]`` meet it, so ``theta`` lies in the arc
  ``[phi_lo - alpha, phi_hi + alpha]`` (every yaw when the apex lies over the footprint), and
- it is not wholly above the top plane or below the bottom one for *some* yaw of that arc: every
  corner's azimuth lies inside the arc, so a corner can come straight ahead, and the test is
  ``y_lo - g_y <= tan(alpha) rho_max`` and ``y_hi - g_y >= -tan(alpha) rho_max``, with ``rho_max``
  the footprint's farthest corner.
That is a superset of the cells the exact frustum meets at any yaw of the arc.  The run time
(:func:`drawn_cells`) tests the exact wedge and the top and bottom planes at the eye.  Both only
shrink when the apex moves into a frustum of the same direction (parallel half-spaces nest), so
an eye inside grid point ``g``'s frustum draws no cell that ``g``'s range did not count
(§3.1, Fig. 3).

**Ranges.**  The arcs' ends are the breakpoints.  A range is the half-open yaw interval between two
consecutive breakpoints, cyclic; a cell counts in every range whose interval meets its closed arc.
The paper represents a range by the direction where it starts; its images face the range's middle
here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

TWO_PI = 2.0 * math.pi
HIDDEN, ARC, ALL = 0, 1, 2  # how a cell is seen over the yaws


def forward(yaw: float | np.ndarray) -> np.ndarray:
    """The unit view direction(s) of yaw ``yaw`` (radians): ``(sin, 0, -cos)``."""
    yaw = np.asarray(yaw, dtype=np.float64)
    return np.stack([np.sin(yaw), np.zeros_like(yaw), -np.cos(yaw)], axis=-1)


def right(yaw: float | np.ndarray) -> np.ndarray:
    """The unit right vector(s) of yaw ``yaw``: ``forward x up = (cos, 0, sin)``."""
    yaw = np.asarray(yaw, dtype=np.float64)
    return np.stack([np.cos(yaw), np.zeros_like(yaw), np.sin(yaw)], axis=-1)


def _wrap(angle: np.ndarray) -> np.ndarray:
    out = np.mod(angle, TWO_PI)
    out[out >= TWO_PI] = 0.0  # np.mod of a tiny negative number rounds up to 2 pi
    return out


def azimuth_spans(
    lo: np.ndarray, hi: np.ndarray, apex: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per box: (over, phi_lo, phi_hi, rho_max): whether the apex lies over its footprint (inclusive),
    the azimuth interval of its footprint (unwrapped about its centre; meaningless when ``over``) and
    the horizontal distance of its farthest footprint corner."""
    x = np.stack([lo[:, 0], hi[:, 0], hi[:, 0], lo[:, 0]], axis=1) - apex[0]  # (n, 4) footprint corners
    z = np.stack([lo[:, 2], lo[:, 2], hi[:, 2], hi[:, 2]], axis=1) - apex[2]
    over = (lo[:, 0] <= apex[0]) & (apex[0] <= hi[:, 0]) & (lo[:, 2] <= apex[2]) & (apex[2] <= hi[:, 2])
    phi = np.arctan2(x, -z)
    centre = np.arctan2(x.mean(axis=1), -z.mean(axis=1))
    rel = np.mod(phi - centre[:, None] + math.pi, TWO_PI) - math.pi
    return over, centre + rel.min(axis=1), centre + rel.max(axis=1), np.hypot(x, z).max(axis=1)


@dataclass(frozen=True)
class YawRanges:
    """The yaw ranges of one apex over a set of cells, and which ranges count each cell.

    Range ``i`` is ``[breaks[i], breaks[i + 1])``, the last one wrapping to ``breaks[0] + 2 pi``.
    Cell ``c`` counts in the cyclic run of ranges ``first[c] .. last[c]`` when ``state[c] == ARC``,
    in every range when ``ALL``, in none when ``HIDDEN``.
    """

    apex: np.ndarray  # (3,)
    half: float  # alpha, radians
    breaks: np.ndarray  # (m,) float64 in [0, 2 pi), increasing
    state: np.ndarray  # (n,) int8
    first: np.ndarray  # (n,) int64
    last: np.ndarray  # (n,) int64

    @property
    def count(self) -> int:
        return int(self.breaks.size)

    @classmethod
    def of(cls, lo: np.ndarray, hi: np.ndarray, apex, half: float) -> YawRanges:
        apex = np.asarray(apex, dtype=np.float64)
        over, phi_lo, phi_hi, rho = azimuth_spans(lo, hi, apex)
        reach = math.tan(half) * rho
        seen = (lo[:, 1] - apex[1] <= reach) & (hi[:, 1] - apex[1] >= -reach)
        start, end = phi_lo - half, phi_hi + half
        full = over | (end - start >= TWO_PI)
        state = np.where(seen, np.where(full, ALL, ARC), HIDDEN).astype(np.int8)
        arcs = state == ARC
        start, end = _wrap(start), _wrap(end)
        breaks = np.unique(np.concatenate([start[arcs], end[arcs]]))
        if breaks.size == 0:
            breaks = np.zeros(1)
        first = np.where(arcs, np.searchsorted(breaks, start), 0)
        last = np.where(arcs, np.searchsorted(breaks, end), breaks.size - 1)
        return cls(apex, float(half), breaks, state, first.astype(np.int64), last.astype(np.int64))

    def range_of(self, yaw: float) -> int:
        """The range that holds ``yaw`` (radians, any value)."""
        y = float(_wrap(np.array([yaw]))[0])
        return int((np.searchsorted(self.breaks, y, side="right") - 1) % self.count)

    def middle(self, index: int) -> float:
        """The yaw in the middle of range ``index``."""
        a = self.breaks[index]
        b = self.breaks[index + 1] if index + 1 < self.count else self.breaks[0] + TWO_PI
        return float((a + b) / 2.0) if self.count > 1 else 0.0

    def members(self, index: int) -> np.ndarray:
        """(n,) bool: the cells range ``index`` counts."""
        wraps = self.last < self.first
        inside = np.where(
            wraps, (index >= self.first) | (index <= self.last), (index >= self.first) & (index <= self.last)
        )
        return (self.state == ALL) | ((self.state == ARC) & inside)

    def sums(self, weights: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
        """(m,) per range: the sum of ``weights`` over the cells it counts (only ``mask``'s, if given)."""
        m = self.count
        w = np.asarray(weights, dtype=np.float64)
        keep = np.ones(w.size, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
        total = np.full(m, w[keep & (self.state == ALL)].sum())
        arcs = keep & (self.state == ARC)
        first, last, wa = self.first[arcs], self.last[arcs], w[arcs]
        diff = np.zeros(m + 1)
        plain = last >= first
        np.add.at(diff, first[plain], wa[plain])
        np.add.at(diff, last[plain] + 1, -wa[plain])
        wrap = ~plain  # first .. m-1 and 0 .. last
        np.add.at(diff, first[wrap], wa[wrap])
        diff[0] += wa[wrap].sum()
        np.add.at(diff, last[wrap] + 1, -wa[wrap])
        return total + np.cumsum(diff[:m])


def drawn_cells(lo: np.ndarray, hi: np.ndarray, eye, yaw: float, half: float) -> np.ndarray:
    """(n,) bool: the cells a run-time frustum at ``eye`` with yaw ``yaw`` draws: the exact
    horizontal wedge (azimuths) and the top and bottom planes (a box passes a plane when one of its
    corners lies inside)."""
    eye = np.asarray(eye, dtype=np.float64)
    over, phi_lo, phi_hi, _ = azimuth_spans(lo, hi, eye)
    # wedge: the yaw lies in [phi_lo - half, phi_hi + half] modulo 2 pi
    offset = np.mod(yaw - (phi_lo - half), TWO_PI)
    wedge = over | (offset <= (phi_hi - phi_lo) + 2.0 * half)
    f, t = forward(yaw), math.tan(half)
    corners = np.stack(np.broadcast_arrays(
        *[np.stack([(lo, hi)[i][:, 0], (lo, hi)[j][:, 1], (lo, hi)[k][:, 2]], axis=1) for i in (0, 1) for j in (0, 1) for k in (0, 1)]
    ), axis=1) - eye  # (n, 8, 3)  # fmt: skip
    ahead = corners @ f
    up = corners[..., 1]
    top = (up <= t * ahead).any(axis=1)
    bottom = (up >= -t * ahead).any(axis=1)
    return wedge & top & bottom
