"""Max-alpha mip chains: (h, w) uint8 alpha in, a list of (H >> L, W >> L) uint8 levels (power-of-two) out.

Conservative alpha-cut recording needs the largest alpha anywhere under a texel's footprint.  The
alpha mask is first resampled to the next power of two on each axis, every new texel taking the
maximum of the original texels it overlaps; each further level takes the maximum of 2x2 blocks.
A footprint no wider than one level-L texel then meets at most 2x2 texels of level L, which the
fragment shader reads with ``texelFetch``.
"""

from __future__ import annotations

import numpy as np


def _next_pow2(n: int) -> int:
    return 1 << max(0, int(n - 1).bit_length())


def _stretch_max(alpha: np.ndarray, axis: int, size: int) -> np.ndarray:
    """Resample ``alpha`` to ``size`` along ``axis`` (size >= current), keeping each new texel's maximum."""
    n = alpha.shape[axis]
    i = np.arange(size)
    first = (i * n) // size
    last = np.minimum(((i + 1) * n + size - 1) // size - 1, n - 1)
    return np.maximum(np.take(alpha, first, axis=axis), np.take(alpha, last, axis=axis))


def max_alpha_levels(alpha: np.ndarray) -> list[np.ndarray]:
    """The max-alpha chain of ``alpha`` (h, w) uint8, top row first; level 0 is (H, W) powers of two.

    >>> levels = max_alpha_levels(np.array([[0, 255, 0]], dtype=np.uint8))
    >>> [lv.shape for lv in levels], int(levels[-1][0, 0])
    ([(1, 4), (1, 2), (1, 1)], 255)
    """
    alpha = np.asarray(alpha, dtype=np.uint8)
    h, w = alpha.shape
    level = _stretch_max(_stretch_max(alpha, 0, _next_pow2(h)), 1, _next_pow2(w))
    levels = [level]
    while level.shape[0] > 1 or level.shape[1] > 1:
        if level.shape[0] > 1:
            level = np.maximum(level[0::2], level[1::2])
        if level.shape[1] > 1:
            level = np.maximum(level[:, 0::2], level[:, 1::2])
        levels.append(level)
    return levels
