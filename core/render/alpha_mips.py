"""Max-alpha mip chains: (h, w) uint8 alpha in, a list of (H >> L, W >> L) uint8 levels (power-of-two) out.

Conservative alpha-cut recording needs the largest alpha that bilinear filtering gives anywhere
under a texel's footprint.  :func:`bilinear_square_max` first turns every texel into the largest
value bilinear filtering takes on its square; the result is resampled to the next power of two on
each axis, every new texel taking the maximum of the original texels it overlaps; each further
level takes the maximum of 2x2 blocks.  The fragment shader then reads the texels of one level
whose squares meet the footprint.
"""

from __future__ import annotations

import moderngl
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


def bilinear_square_max(alpha: np.ndarray) -> np.ndarray:
    """(h, w) uint8: for every texel of ``alpha`` (h, w) uint8, the largest value bilinear
    filtering with repeat wrapping (GL_LINEAR, GL_REPEAT) takes anywhere on its square.

    The lines through the texel's centre cut its square into quarters that each lie between four
    texel centres, where the filter is bilinear, so linear along each axis: its largest value on a
    quarter is at one of the quarter's corners.  Those are the texel's centre (the texel itself),
    the midpoints of its sides (the mean with that side's neighbour) and its corners (the mean of
    the 2x2 texels around it).  Means are rounded half down: a side between alpha 0 and 255 is
    exactly at a 0.5 cut only on the line itself, which the opaque texel's square holds.  Reading
    raw alphas instead would need each square grown by half a texel, and the largest alpha of a
    grown square (a neighbour that bilinear filtering mixes in at most halfway) keeps texels where
    the filtered alpha never reaches the cut.

    >>> bilinear_square_max(np.array([[0, 255, 0, 0]], dtype=np.uint8)).tolist()
    [[127, 255, 127, 0]]
    >>> int(bilinear_square_max(np.array([[127, 128], [128, 128]], dtype=np.uint8))[0, 0])  # corner mean 127.75
    128
    """
    a = np.asarray(alpha, dtype=np.int32)
    out = a.copy()

    def half_down(total: np.ndarray, count: int) -> np.ndarray:
        # ceil(total / count - 1/2) in integers: the mean rounded to nearest, ties down.
        return -((-(2 * total - count)) // (2 * count))

    for axis in (0, 1):
        for shift in (1, -1):
            out = np.maximum(out, half_down(a + np.roll(a, shift, axis), 2))
    for dy in (1, -1):
        for dx in (1, -1):
            down = np.roll(a, dy, 0)
            out = np.maximum(out, half_down(a + down + np.roll(a, dx, 1) + np.roll(down, dx, 1), 4))
    return out.astype(np.uint8)


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


def max_alpha_texture(ctx: moderngl.Context, alpha: np.ndarray) -> moderngl.Texture:
    """The GL texture of the max-alpha chain of ``alpha`` (h, w) uint8, top row first (each
    texel's largest bilinear alpha on its square, :func:`bilinear_square_max`, then
    :func:`max_alpha_levels`): one channel, rows bottom first as every farfield texture is
    uploaded, nearest filtering, one mip level per chain level."""
    levels = max_alpha_levels(bilinear_square_max(alpha))
    texture = ctx.texture((levels[0].shape[1], levels[0].shape[0]), 1, dtype="f1")
    texture.build_mipmaps(0, len(levels) - 1)
    for level, data in enumerate(levels):
        texture.write(np.ascontiguousarray(data[::-1]).tobytes(), level=level)
    texture.filter = (moderngl.NEAREST_MIPMAP_NEAREST, moderngl.NEAREST)
    return texture
