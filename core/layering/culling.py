"""Occlusion culling inside a layered impostor: (k, h, w) bool opaque texels in, (k, h, w) bool hidden texels out.

Seed 000 §3.4: the one-texel layer spacing lets every texel expose at most the texel behind it
from anywhere in the view cell, so an opaque 3x3 block hides the centre texel of the next layer.
Going from the nearest layer back, positions already hidden count as opaque, which fuses
occluders and their umbrae across layers.

Seed 000 §3.4.1 (penumbra overlap): decompose the view cell into four parts, each bounded by the
reference viewpoint and one corner.  From one part texels move at most one texel towards one
diagonal, so a 2x2 block (the texel and its neighbours in that direction) suffices; a texel
hidden from all four parts is hidden from the whole cell.  This finds every 3x3 occlusion and
more.

Both modes are conservative: a texel seen from anywhere in the view cell is never hidden.  All
operations are whole-layer numpy boolean shifts; work is O(k h w).
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from farfield.core.errors import LayerPlanError

CullingMode = Literal["penumbra", "umbra", "off"]
CULLING_MODES: tuple[str, ...] = ("penumbra", "umbra", "off")


def _shift(mask: np.ndarray, dy: int, dx: int) -> np.ndarray:
    """``mask`` (h, w) moved by (dy, dx): out[y, x] = mask[y - dy, x - dx], False where undefined."""
    h, w = mask.shape
    out = np.zeros_like(mask)
    ys, yd = (slice(0, h - dy), slice(dy, h)) if dy >= 0 else (slice(-dy, h), slice(0, h + dy))
    xs, xd = (slice(0, w - dx), slice(dx, w)) if dx >= 0 else (slice(-dx, w), slice(0, w + dx))
    out[yd, xd] = mask[ys, xs]
    return out


def _blocked_by(blockers: np.ndarray, offsets: tuple[tuple[int, int], ...]) -> np.ndarray:
    """Positions whose neighbours at every (dy, dx) in ``offsets`` are blockers."""
    out = blockers.copy()
    for dy, dx in offsets:
        out &= _shift(blockers, dy, dx)
    return out


# A texel at (y, x) is hidden when blockers sit at (y + dy, x + dx) for every listed offset; _shift
# by (-dy, -dx) brings the neighbour at (y + dy, x + dx) onto (y, x).
_UMBRA = tuple((-dy, -dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0))
_QUADRANTS = tuple(((-sy, 0), (0, -sx), (-sy, -sx)) for sy in (-1, 1) for sx in (-1, 1))


def hidden_texels(opaque: np.ndarray, mode: CullingMode = "penumbra") -> np.ndarray:
    """Texels of each layer hidden from the whole view cell by the layers in front of them.

    Parameters
    ----------
    opaque : (k, h, w) bool
        Covered texels of each layer, nearest layer first.
    mode : {"penumbra", "umbra", "off"}
        §3.4.1 four-part intersection, §3.4 3x3 rule, or no culling.

    Returns
    -------
    (k, h, w) bool
        True where a covered texel can be removed.  Layer 0 is never culled.

    >>> layers = np.zeros((2, 5, 5), bool); layers[:] = True
    >>> int(hidden_texels(layers, "umbra")[1].sum())  # the inner 3x3 of the far layer
    9
    """
    opaque = np.asarray(opaque, dtype=bool)
    culler = LayerCuller(opaque.shape[1:], mode)
    return np.stack([culler.hidden(layer) for layer in opaque]) if opaque.shape[0] else np.zeros_like(opaque)


class LayerCuller:
    """:func:`hidden_texels` one layer at a time, nearest first, keeping only each view-cell part's
    umbra ((h, w) bool per part): memory O(h w) whatever the number of layers."""

    def __init__(self, shape: tuple[int, int], mode: CullingMode = "penumbra"):
        if mode not in CULLING_MODES:
            raise LayerPlanError(f"culling mode must be one of {CULLING_MODES}, got {mode!r}")
        self.mode = mode
        self.parts = () if mode == "off" else ((_UMBRA,) if mode == "umbra" else _QUADRANTS)
        self.umbra = [np.zeros(shape, dtype=bool) for _ in self.parts]
        self.previous: np.ndarray | None = None

    def hidden(self, opaque: np.ndarray) -> np.ndarray:
        """(h, w) bool: covered texels of this layer hidden by the layers given before it."""
        opaque = np.asarray(opaque, dtype=bool)
        if self.previous is None or not self.parts:
            self.previous = opaque
            return np.zeros_like(opaque)
        everywhere = np.ones(opaque.shape, dtype=bool)
        for p, offsets in enumerate(self.parts):
            self.umbra[p] = _blocked_by(self.previous | self.umbra[p], offsets)
            everywhere &= self.umbra[p]
        self.previous = opaque
        return everywhere & opaque
