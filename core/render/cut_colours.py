"""Colours of alpha-cut textures for recording: (h, w, 4) uint8 sRGB in, (h, w, 4) float16 linear RGB
premultiplied by alpha out, to be mipmapped by the GL.

A conservatively recorded texel (``slab.frag``) is kept when *any* point under its footprint may
pass the alpha cut, so a texel can be kept for a leaf that covers a tenth of it, and a point sample
of the texture there often lands on the transparent part, whose RGB is whatever the painter left
(about (10, 12, 8) in the scrub pine's ``LushPine.png``) and which the source never shows.  Such a
texel should hold what the geometry shows under it: the **alpha-weighted mean** colour of the
texture over its footprint.  Box-filtered mip levels of premultiplied colour give exactly that
sum(alpha x colour) / sum(alpha) over power-of-two blocks; ``slab.frag`` reads the level as wide as
the footprint (a coarser one where everything under it is transparent) and divides by alpha.
Colours are averaged in linear light (:mod:`core.colour_space`), as a renderer's filtering does.
Only recording reads this; the source geometry is always drawn from its own texture.
"""

from __future__ import annotations

import numpy as np

from farfield.core.colour_space import srgb_to_linear


def premultiplied_linear(texture: np.ndarray) -> np.ndarray:
    """(h, w, 4) float16: linear RGB x alpha, and alpha, of sRGB ``texture`` (h, w, 4) uint8.

    >>> t = np.array([[[255, 128, 0, 255], [255, 255, 255, 0]]], dtype=np.uint8)
    >>> premultiplied_linear(t).astype(float).round(3).tolist()
    [[[1.0, 0.216, 0.0, 1.0], [0.0, 0.0, 0.0, 0.0]]]
    """
    lut = srgb_to_linear(np.arange(256) / 255.0).astype(np.float32)
    out = np.empty(texture.shape, dtype=np.float32)
    alpha = texture[..., 3].astype(np.float32) / 255.0
    out[..., 3] = alpha
    out[..., :3] = lut[texture[..., :3]] * alpha[..., None]
    return out.astype(np.float16)
