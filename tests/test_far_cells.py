"""View cells at the far end of float64 (issue 59, item 1): a cell near 1e300 made a job's planning
divide by zero (the length of a coordinate difference overflowed to inf, its direction to zero),
a 500.  Every technique now plans it or refuses it with a farfield error."""

from __future__ import annotations

import numpy as np
import pytest

from farfield.core.errors import FarfieldError
from farfield.core.techniques import TECHNIQUES, get_technique
from farfield.core.viewcells import BoxCell, length_and_unit


@pytest.mark.parametrize("name", sorted(TECHNIQUES))
@pytest.mark.parametrize("at", [1e300, 1e200, 1e154])
def test_a_cell_near_the_largest_float_is_planned_or_refused_never_a_crash(name, at):
    technique = get_technique(name)
    cell = BoxCell(np.full(3, at), np.full(3, at * (1.0 + 1e-7)))
    part = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    try:
        cost = technique.check(cell, technique.options(), None if technique.scope == "scene" else part)
    except FarfieldError:
        return
    assert cost.layers >= 1


def test_the_part_techniques_need_one_layer_for_a_part_that_far():
    cell = BoxCell(np.full(3, 1e300), np.full(3, 1e300 * (1.0 + 1e-7)))
    part = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    for name in ("layered", "tdm"):
        assert get_technique(name).check(cell, get_technique(name).options(), part).layers == 1


def test_length_and_unit_of_vectors_whose_squares_overflow_or_underflow():
    for scale in (1e300, 1e-300, 1.0):
        length, unit = length_and_unit(np.array([3.0, 0.0, 4.0]) * scale)
        assert length == pytest.approx(5.0 * scale) and np.allclose(unit, [0.6, 0.0, 0.8])


def test_a_request_or_command_line_cell_past_the_coordinate_limit_is_refused_by_name():
    """Issue 59's campaign: a tiny box at 1e300 was planned, then failed on the worker as an internal
    error (its GLB is float32 relative to the viewpoint), retried until its attempts ran out.  What a
    request or a command line gives is bounded as scene coordinates are (TOL.max_coordinate)."""
    from farfield.core.errors import ViewCellError
    from farfield.core.viewcells import grid_boxes, parse_viewcell, viewcell_from_dict

    with pytest.raises(ViewCellError, match="exceeds the limit 1e\\+12"):
        viewcell_from_dict({"kind": "box", "lo": [1e300] * 3, "hi": [1.0000001e300] * 3})
    with pytest.raises(ViewCellError, match="exceeds the limit"):
        parse_viewcell("box-center:1e13,0,0,1")
    with pytest.raises(ViewCellError, match="exceeds the limit"):
        grid_boxes([1e13, 0, 0], [1.1e13, 1, 1], [1, 1, 1])
    with pytest.raises(ViewCellError, match="exceeds the limit"):
        viewcell_from_dict({"kind": "outside-sphere", "centre": [0, 0, 0], "radius": 1e20})
    assert viewcell_from_dict({"kind": "box", "lo": [9e11, 0, 0], "hi": [9e11 + 1e6, 1e6, 1e6]}).lo[0] == 9e11
