"""Gap filling between two adjacent impostor layers: (h, w, 4) uint8 RGBA layers (or (h, w, 8): RGBA
then the encoded normal, recorded with the normal channel) in, the farther one filled, out.

Seed 002 (Jeschke, Wimmer, Schumann, GI 2002) §5.1: a continuous surface sampled in two layers may
leave a transparent texel in the farther layer right behind the closer layer's last opaque texel,
and a one-texel hole opens when the viewer moves.  The fix copies the *opaque border texels* of
the closer layer (opaque with at least one transparent 8-neighbour) into the farther layer at the
same positions, where the farther layer is opaque or a *transparent border texel* (transparent with
at least one opaque 8-neighbour).

farfield's conservative recording (seed 000 §3.3.2, :mod:`farfield.core.layering.recording`) already writes a surface
that crosses a border into both layers, so with it this step only ever touches texels that the
recording covered too; it is kept as the paper's step (and as a knob) because it also closes gaps
left by a non-conservative recording.

A texel is copied whole: with the normal channel the closer layer's normal goes where its colour
goes, so every filled texel shows the normal of the surface whose colour it shows.
"""

from __future__ import annotations

import numpy as np

from farfield.core.layering.culling import _shift

_NEIGHBOURS = tuple((dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0))


def _any_neighbour(mask: np.ndarray) -> np.ndarray:
    """(h, w) bool: positions with at least one 8-neighbour set in ``mask``."""
    out = np.zeros_like(mask)
    for dy, dx in _NEIGHBOURS:
        out |= _shift(mask, dy, dx)
    return out


def border_texels(opaque: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(opaque border, transparent border) texels of an (h, w) bool coverage (seed 002 §5.1).

    Outside the image counts as transparent, so opaque texels on the image edge are border texels.

    >>> cov = np.zeros((3, 4), bool); cov[1, 1:3] = True
    >>> ob, tb = border_texels(cov)
    >>> int(ob.sum()), int(tb.sum())
    (2, 10)
    """
    opaque = np.asarray(opaque, dtype=bool)
    padded = np.pad(opaque, 1, constant_values=False)
    transparent_near = _any_neighbour(~padded)[1:-1, 1:-1]
    return opaque & transparent_near, ~opaque & _any_neighbour(opaque)


def fill_gaps(closer: np.ndarray, farther: np.ndarray) -> tuple[np.ndarray, int]:
    """Copy ``closer``'s opaque border texels into ``farther`` (both (h, w, 4) uint8, or both (h, w, 8)
    with the normal channel: the texels are copied whole) where §5.1 allows.  Coverage is the
    colour's alpha (channel 3).

    Returns the filled copy of ``farther`` and the number of texels that were transparent before
    (the texels the step added; overwritten opaque texels are not counted).

    >>> near = np.zeros((1, 4, 4), np.uint8); near[0, 1] = (9, 9, 9, 255)
    >>> far = np.zeros((1, 4, 4), np.uint8); far[0, 3] = (5, 5, 5, 255)
    >>> filled, added = fill_gaps(near, far)
    >>> filled[0, :, 0].tolist(), added
    ([0, 0, 0, 5], 0)
    >>> far[0, 2] = (5, 5, 5, 255); filled, added = fill_gaps(near, far)
    >>> filled[0, :, 0].tolist(), added
    ([0, 9, 5, 5], 1)

    With the normal channel, the normal travels with the colour, and only there:

    >>> near8 = np.concatenate([near, np.full_like(near, 200)], axis=-1)
    >>> far8 = np.concatenate([far, np.full_like(far, 50)], axis=-1)
    >>> filled8, added8 = fill_gaps(near8, far8)
    >>> filled8[0, :, 0].tolist(), filled8[0, :, 4].tolist(), added8
    ([0, 9, 5, 5], [50, 200, 50, 50], 1)
    """
    near_opaque = closer[..., 3] > 0
    far_opaque = farther[..., 3] > 0
    near_border, _ = border_texels(near_opaque)
    _, far_transparent_border = border_texels(far_opaque)
    target = near_border & (far_opaque | far_transparent_border)
    out = farther.copy()
    out[target] = closer[target]
    return out, int((target & ~far_opaque).sum())
