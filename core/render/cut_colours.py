"""Colours of alpha-cut textures for recording: (h, w, 4) uint8 sRGB in, (h, w, 4) float16 linear RGB
weighted by whether each texel passes the alpha cut, and that weight, out, to be mipmapped by the GL.

A conservatively recorded texel (``slab.frag``) is kept when *any* point under its footprint may
pass the alpha cut, so a texel can be kept for a leaf that covers a tenth of it, and a point sample
of the texture there often lands on the transparent part, whose RGB is whatever the painter left
(0 in the scrub pine's ``LushPine.png``) and which the source never shows.  Such a texel should
hold what the geometry shows under it: the **mean colour of the texels under its footprint that
pass the cut**.  Box-filtered mip levels of (linear colour x pass, pass) give exactly that
sum(pass x colour) / sum(pass) over power-of-two blocks; ``slab.frag`` reads the level as wide as
the footprint (a coarser one where nothing under it passes) and divides by the fourth channel.
Colours are averaged in linear light (:mod:`farfield.core.colour_space`), as a renderer's filtering does.

Weighting by pass/fail rather than by alpha matters where a texture's soft edge (alpha above 0,
below the cut) is painted in another colour than its opaque body: ``LushPine.png`` holds 20,033
texels of alpha 1..127 averaging sRGB (106, 118, 77) around 62,000 texels of alpha >= 128
averaging about (57, 68, 27).  The source cuts the soft edge away; an alpha-weighted mean took it
in and made the pine's impostor brighter than the pine by about 3 of 255 in linear-light mean
(issue 23).  Only recording reads this; the source geometry is always drawn from its own texture.
"""

from __future__ import annotations

import numpy as np

from farfield.core.colour_space import srgb_to_linear

_LINEAR = srgb_to_linear(np.arange(256) / 255.0).astype(np.float32)


def cut_weighted_linear(texture: np.ndarray, cut: float) -> np.ndarray:
    """(h, w, 4) float16: linear RGB x pass, and pass, of sRGB ``texture`` (h, w, 4) uint8, where
    pass is 1 for a texel whose alpha reaches ``cut`` (0..1, the cut on the texture's own alpha)
    and 0 elsewhere.  A texture none of whose texels passes (the cut is met only with help from
    vertex colours, say) is weighted by alpha instead, so a kept texel still never takes the RGB
    of fully transparent texels.

    >>> t = np.array([[[255, 128, 0, 255], [255, 255, 255, 0], [0, 255, 0, 100]]], dtype=np.uint8)
    >>> cut_weighted_linear(t, 0.5).astype(float).round(3).tolist()
    [[[1.0, 0.216, 0.0, 1.0], [0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]]]
    >>> cut_weighted_linear(t, 1.5)[0, :, 3].astype(float).round(3).tolist()  # none passes: alpha
    [1.0, 0.0, 0.392]
    """
    alpha = texture[..., 3].astype(np.float32) / 255.0
    weight = (alpha >= np.float32(cut)).astype(np.float32)  # the shaders' test: alpha 127 does not pass 0.5
    if not weight.any():
        weight = alpha
    out = np.empty(texture.shape, dtype=np.float32)
    out[..., 3] = weight
    out[..., :3] = _LINEAR[texture[..., :3]] * weight[..., None]
    return out.astype(np.float16)
