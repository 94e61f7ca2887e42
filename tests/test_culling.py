"""In-impostor occlusion culling (seed 000 §3.4, §3.4.1) on synthetic layer stacks."""

from __future__ import annotations

import numpy as np
import pytest

from farfield.core.errors import LayerPlanError
from farfield.core.layering.culling import hidden_texels


def stack(*layers: np.ndarray) -> np.ndarray:
    return np.stack([np.asarray(layer, dtype=bool) for layer in layers])


def test_opaque_3x3_block_hides_only_the_centre_behind_it():
    near = np.zeros((5, 5), bool)
    near[1:4, 1:4] = True
    far = np.ones((5, 5), bool)
    hidden = hidden_texels(stack(near, far), "umbra")
    expected = np.zeros((5, 5), bool)
    expected[2, 2] = True
    np.testing.assert_array_equal(hidden[1], expected)
    assert not hidden[0].any()


def test_hidden_positions_count_as_opaque_further_back():
    """Fig. 3.12 (c): an empty layer between occluder and occludee keeps the umbra."""
    near = np.ones((9, 9), bool)
    gap = np.zeros((9, 9), bool)
    far = np.ones((9, 9), bool)
    hidden = hidden_texels(stack(near, gap, far), "umbra")
    # The umbra shrinks by one texel per layer: 7x7 behind the first layer, 5x5 two layers back.
    assert hidden[2].sum() == 25 and hidden[2][2:7, 2:7].all()


def test_umbra_fuses_across_layers():
    """Two half-occluders in consecutive layers hide what neither hides alone."""
    a = np.zeros((7, 12), bool)
    a[:, :6] = True
    b = np.zeros((7, 12), bool)
    b[:, 5:] = True
    far = np.ones((7, 12), bool)
    hidden = hidden_texels(stack(a, b, far), "umbra")
    assert hidden[2][3, 6]  # behind the seam, covered by a's umbra plus b


@pytest.mark.parametrize("seed", range(6))
def test_penumbra_mode_finds_everything_the_umbra_rule_finds(seed):
    rng = np.random.default_rng(seed)
    layers = rng.random((6, 40, 40)) < 0.7
    umbra = hidden_texels(layers, "umbra")
    penumbra = hidden_texels(layers, "penumbra")
    assert np.all(penumbra[umbra])
    assert not np.any(penumbra & ~layers)


def test_penumbra_overlap_hides_more():
    """Fig. 3.15: a one-texel gap in the first layer with a texel behind it in the second; from
    each view-cell part one neighbour of the gap still blocks, so the third layer is hidden there,
    which the 3x3 umbra rule cannot see."""
    near = np.ones((9, 9), bool)
    near[:, 4] = False
    middle = np.zeros((9, 9), bool)
    middle[:, 4] = True
    far = np.ones((9, 9), bool)
    layers = stack(near, middle, far)
    umbra, penumbra = hidden_texels(layers, "umbra"), hidden_texels(layers, "penumbra")
    assert not umbra[2][2:7, 4].any()
    assert penumbra[2][2:7, 4].all()


def test_off_and_bad_mode():
    layers = np.ones((3, 5, 5), bool)
    assert not hidden_texels(layers, "off").any()
    with pytest.raises(LayerPlanError, match="culling mode"):
        hidden_texels(layers, "everything")
