"""Box and shaft view cells: construction, containment, corners, distances and deterministic sampling."""

from __future__ import annotations

import math

import numpy as np
import pytest

from farfield.core.errors import ViewCellError
from farfield.core.viewcells import BoxCell, ShaftCell, grid_boxes, parse_viewcell, sample_viewpoints


def test_box_corners_centre_and_containment():
    cell = BoxCell([0, 0, 0], [2, 4, 6])
    corners = cell.corners()
    assert corners.shape == (8, 3) and corners.dtype == np.float64
    assert {tuple(c) for c in corners} == {(x, y, z) for x in (0, 2) for y in (0, 4) for z in (0, 6)}
    assert cell.center.tolist() == [1, 2, 3]
    assert cell.contains(corners).all()
    outside = np.array([[-1e-9, 1, 1], [1, 4.000001, 1], [1, 1, 7]])
    assert not cell.contains(outside).any()
    assert cell.contains(outside[:1], tol=1e-6).all()


@pytest.mark.parametrize(
    ("bounds", "expected"),
    [
        ([[5, 0, 0], [6, 1, 1]], 3.0),  # along x
        ([[5, 7, 0], [6, 8, 1]], 5.0),  # 3-4-5 diagonal gap
        ([[1, 1, 1], [3, 3, 3]], 0.0),  # overlapping
        ([[2, 0, 0], [3, 1, 1]], 0.0),  # touching a face
    ],
)
def test_box_distance_to_box(bounds, expected):
    assert BoxCell([0, 0, 0], [2, 3, 2]).distance_to_box(bounds) == pytest.approx(expected)


@pytest.mark.parametrize(
    ("lo", "hi"),
    [([0, 0, 0], [0, 1, 1]), ([0, 0, 0], [-1, 1, 1]), ([0, 0, float("nan")], [1, 1, 1]), ([0, 0], [1, 1])],
)
def test_bad_boxes_are_refused(lo, hi):
    with pytest.raises(ViewCellError):
        BoxCell(lo, hi)


def test_box_sampling_is_deterministic_and_inside():
    cell = BoxCell([-1e6, 2e6, 0.001], [-1e6 + 10, 2e6 + 10, 0.002])  # continental offset, mm depth
    a = sample_viewpoints(cell, random_count=100, seed=7)
    b = sample_viewpoints(cell, random_count=100, seed=7)
    c = sample_viewpoints(cell, random_count=100, seed=8)
    assert a.shape == (8 + 1 + 100, 3)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert cell.contains(a).all()
    np.testing.assert_array_equal(a[:8], cell.corners())
    np.testing.assert_array_equal(a[8], cell.center)


def test_shaft_geometry_and_containment():
    shaft = ShaftCell([0, 0, 0], [0, 0, 2], math.radians(90), 10.0, 20.0)
    assert shaft.direction.tolist() == [0, 0, 1]
    corners = shaft.corners()
    assert corners.shape == (8, 3)
    # 90° apex: the half-width equals the distance.
    np.testing.assert_allclose(np.abs(corners[:4, :2]), 10.0, atol=1e-12)
    np.testing.assert_allclose(np.abs(corners[4:, :2]), 20.0, atol=1e-12)
    assert shaft.contains(corners, tol=1e-9).all()
    assert shaft.contains([[0, 0, 15], [14, -14, 15]]).all()
    assert not shaft.contains([[0, 0, 9], [16, 0, 15], [0, 0, 21], [0, 0, -15]]).any()
    points = sample_viewpoints(shaft, random_count=200, seed=3)
    assert shaft.contains(points, tol=1e-9).all()


def test_unbounded_shaft_needs_a_depth_to_sample():
    shaft = ShaftCell([0, 0, 0], [1, 0, 0], math.radians(20), 100.0)
    assert shaft.corners().shape == (4, 3)
    with pytest.raises(ViewCellError, match="depth"):
        sample_viewpoints(shaft, random_count=5)
    pts = sample_viewpoints(shaft, random_count=5, seed=1, depth=50.0)
    assert shaft.contains(pts, tol=1e-9).all()
    assert pts[:, 0].max() <= 150.0 + 1e-9


def test_shaft_distance_to_box():
    shaft = ShaftCell([0, 0, 0], [1, 0, 0], math.radians(60), 100.0)
    # The part around the apex: the near cap is 100 - 10 away from its near face.
    assert shaft.distance_to_box([[-10, -10, -10], [10, 10, 10]]) == pytest.approx(90.0, abs=1e-6)


@pytest.mark.parametrize(
    "args",
    [
        ([0, 0, 0], [0, 0, 0], 0.5, 10.0),  # zero direction
        ([0, 0, 0], [1, 0, 0], 0.0, 10.0),  # zero apex angle
        ([0, 0, 0], [1, 0, 0], math.pi, 10.0),  # 180°
        ([0, 0, 0], [1, 0, 0], 0.5, 0.0),  # touching the apex
        ([0, 0, 0], [1, 0, 0], 0.5, -1.0),
    ],
)
def test_bad_shafts_are_refused(args):
    with pytest.raises(ViewCellError):
        ShaftCell(*args)


def test_parse_viewcell():
    assert parse_viewcell("box:0,0,0,1,2,3").size.tolist() == [1, 2, 3]
    shaft = parse_viewcell("shaft:0,0,0,0,1,0,30,50,80")
    assert isinstance(shaft, ShaftCell) and shaft.max_distance == 80.0
    assert math.degrees(shaft.apex_angle) == pytest.approx(30)
    for bad in ("box:1,2", "cube:0,0,0,1", "box:a,b,c,d,e,f", ""):
        with pytest.raises(ViewCellError):
            parse_viewcell(bad)


def test_refusals_name_what_is_wrong_at_extreme_coordinates():
    """Finite corners whose difference overflows, and a box thin for its coordinates' magnitude: the
    message says so, instead of 'not finite, got [nan ...]' or 'needs lo < hi' where lo < hi holds."""
    with pytest.raises(ViewCellError, match=r"grid box's size hi - lo is not finite in float64"):
        grid_boxes([-1e308, 0, 0], [1e308, 1, 1], [2, 1, 1])
    with pytest.raises(
        ViewCellError, match=r"too thin for coordinates up to 1e\+15: its size on y 0.5, z 0.5 must exceed 1"
    ):
        BoxCell(np.array([1e15, 0, 0]), np.array([1.0000001e15, 0.5, 0.5]))
    with pytest.raises(ViewCellError, match="needs lo < hi on every axis"):
        BoxCell(np.array([0.0, 0, 0]), np.array([1.0, 0, 1]))


@pytest.mark.parametrize("kind", ["outside", "sphere", None])
def test_an_unknown_view_cell_kind_names_the_known_ones(kind):
    """``{"kind": "outside", ...}`` (the CLI's spelling, ``outside:cx,cy,cz,R``) was answered only
    "unknown view cell kind 'outside'": the caller could not tell the dictionary's name of it."""
    from farfield.core.viewcells import viewcell_from_dict

    with pytest.raises(ViewCellError, match=r"known kinds: 'box'.*'shaft'.*'outside-sphere'"):
        viewcell_from_dict({"kind": kind, "centre": [0, 0, 0], "radius": 1})


@pytest.mark.parametrize(
    "data, field",
    [
        ({"kind": "box", "lo": [True, False, True], "hi": [2, 2, 2]}, "lo"),
        ({"kind": "box", "lo": ["1", "0", "0"], "hi": [2, 2, 2]}, "lo"),
        ({"kind": "box", "lo": [0, 0, 0], "hi": "222"}, "hi"),
        ({"kind": "outside-sphere", "centre": [0, 0, 0], "radius": "10"}, "radius"),
        ({"kind": "outside-sphere", "centre": [0, 0, 0], "radius": 10, "hemisphere": "false"}, "hemisphere"),
        ({"kind": "outside-sphere", "centre": [0, 0, 0], "radius": 10, "hemisphere": 0}, "hemisphere"),
        (
            {"kind": "shaft", "apex": [0, 0, 0], "direction": [0, 0, 1], "apex_angle_deg": "10", "min_distance": 1},
            "apex_angle_deg",
        ),
        (
            {"kind": "shaft", "apex": [0, 0, 0], "direction": [0, 0, 1], "apex_angle_deg": 10, "min_distance": True},
            "min_distance",
        ),
    ],
)
def test_a_view_cell_description_takes_json_numbers_and_booleans_only(data, field):
    """``true`` and ``"1"`` were read as 1 in a view cell's coordinates, and ``"hemisphere": "false"``
    as a hemisphere (``bool("false")``), where the job's other fields refuse loose types."""
    from farfield.core.viewcells import viewcell_from_dict

    with pytest.raises(ViewCellError, match=field):
        viewcell_from_dict(data)


def test_a_view_cell_description_as_written_reads_back():
    from farfield.core.viewcells import SphereOutsideCell, viewcell_from_dict

    for cell in (
        BoxCell([0, 0, 0], [1, 2, 3]),
        ShaftCell([0, 0, 0], [0, 0, 1], 0.3, 2.0),
        SphereOutsideCell([1, 2, 3], 4.0, True),
    ):
        assert viewcell_from_dict(cell.to_dict()).to_dict() == cell.to_dict()
    assert viewcell_from_dict({"kind": "box", "lo": np.zeros(3), "hi": np.ones(3, dtype=np.int64)}).size.tolist() == [
        1,
        1,
        1,
    ]
