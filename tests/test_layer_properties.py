"""Properties of the layer mathematics over its whole valid domain (hypothesis), and its refusals outside it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from farfield.core.errors import LayerPlanError, ViewCellError
from farfield.core.layering.plan import layer_spacing, parallax_angles, part_view, plan_layers
from farfield.core.pixel_angles import pixel_angle, texture_resolution
from farfield.core.techniques.envmap.arrangement import envmap_plan, layers_for_near_field, near_field_distance
from farfield.core.viewcells import BoxCell, ShaftCell

SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])

# A part in front of a cubic cell of side `cell`, `gap` away, `depth` deep, `width` wide.
distances = st.floats(min_value=0.3, max_value=50.0)  # gap / cell size
depths = st.floats(min_value=0.0, max_value=3.0)  # depth / cell size
widths = st.floats(min_value=0.05, max_value=3.0)  # width / cell size
resolutions = st.integers(min_value=16, max_value=1024)
fovs = st.floats(min_value=10.0, max_value=120.0)
scales = st.floats(min_value=1e-3, max_value=1e5)
models = st.sampled_from(["min", "center"])


def scene(scale: float, gap: float, depth: float, width: float, cell: float = 1.0):
    c = BoxCell.from_center([0.0, 0.0, 0.0], cell * scale)
    near = (0.5 * cell + gap * cell) * scale
    half = 0.5 * width * cell * scale
    bounds = [[near, -half, -0.7 * half], [near + depth * cell * scale, half, 0.7 * half]]
    return c, bounds


def check_plan(plan):
    d, b = plan.distances, plan.borders
    assert np.all(np.isfinite(d)) and np.all(np.isfinite(b))
    assert np.all(np.diff(d) > 0)
    assert np.all(np.diff(b) >= 0)
    assert b[0] == plan.t0 and b[-1] == pytest.approx(plan.t0 + plan.depth)
    # every layer lies inside the depth range it represents
    assert np.all(d >= b[:-1] * (1 - 1e-12)) and np.all(d <= b[1:] * (1 + 1e-12))
    assert plan.front_range > 0 and plan.back_limit > 0
    assert not math.isnan(plan.back_limit)


@SETTINGS
@given(gap=distances, depth=depths, width=widths, res=st.integers(16, 512), fov=fovs, model=models, k=scales)
@pytest.mark.slow
def test_uniform_scaling_changes_no_layer_count(gap, depth, width, res, fov, model, k):
    cell1, b1 = scene(1.0, gap, depth, width)
    cellk, bk = scene(k, gap, depth, width)
    p1 = plan_layers(cell1, b1, math.radians(fov), res, model)
    pk = plan_layers(cellk, bk, math.radians(fov), res, model)
    assert pk.count == p1.count
    assert pk.texture_resolution.tolist() == p1.texture_resolution.tolist()
    np.testing.assert_allclose(pk.distances, p1.distances * k, rtol=1e-9)
    np.testing.assert_allclose(pk.borders, p1.borders * k, rtol=1e-9)


@SETTINGS
@given(gap=distances, depth=depths, width=widths, res=st.integers(16, 512), fov=fovs, model=models)
@pytest.mark.slow
def test_no_nan_negative_or_infinite_spacing(gap, depth, width, res, fov, model):
    cell, bounds = scene(1.0, gap, depth, width)
    plan = plan_layers(cell, bounds, math.radians(fov), res, model)
    check_plan(plan)
    view = part_view(cell, bounds)
    t = plan.distances[plan.distances < plan.single_layer_distance]
    c = layer_spacing(t, plan.reference_offset, view, plan.frustum_half_tangents, plan.texture_resolution)
    assert np.all(c > 0) and not np.any(np.isnan(c))


@SETTINGS
@given(
    gap=distances,
    factor=st.floats(1.05, 4.0),
    depth=st.floats(0.05, 3.0),
    width=widths,
    res=st.integers(16, 512),
    model=models,
)
@pytest.mark.slow
def test_layer_count_falls_with_distance(gap, factor, depth, width, res, model):
    fov = math.radians(45)
    near = plan_layers(*scene(1.0, gap, depth, width), fov, res, model)
    far = plan_layers(*scene(1.0, gap * factor, depth, width), fov, res, model)
    assert far.count <= near.count


@SETTINGS
@given(
    gap=distances,
    depth=st.floats(0.05, 3.0),
    width=widths,
    res=st.integers(16, 512),
    factor=st.floats(1.05, 4.0),
    model=models,
)
@pytest.mark.slow
def test_layer_count_rises_with_resolution(gap, depth, width, res, factor, model):
    fov = math.radians(45)
    cell, bounds = scene(1.0, gap, depth, width)
    low = plan_layers(cell, bounds, fov, res, model)
    high = plan_layers(cell, bounds, fov, int(res * factor), model)
    assert high.count >= low.count


@SETTINGS
@given(
    gap=st.floats(2.0, 50.0),
    depth=st.floats(0.05, 3.0),
    width=widths,
    res=st.integers(16, 512),
    factor=st.floats(1.05, 3.0),
    model=models,
)
@pytest.mark.slow
def test_layer_count_rises_with_view_cell_size(gap, depth, width, res, factor, model):
    """The part stays put; the cell grows about its centre."""
    fov = math.radians(45)
    cell, bounds = scene(1.0, gap, depth, width)
    bigger = BoxCell.from_center([0.0, 0.0, 0.0], factor)
    assume(bigger.hi[0] < bounds[0][0])
    assert plan_layers(bigger, bounds, fov, res, model).count >= plan_layers(cell, bounds, fov, res, model).count


@SETTINGS
@given(k=scales, n=st.integers(1, 300), res=st.integers(16, 2048))
def test_envmap_scale_invariance_and_round_trip(k, n, res):
    alpha = pixel_angle(math.pi / 2, res, "min")
    d1 = near_field_distance(10.0, res, n, alpha)
    dk = near_field_distance(10.0 * k, res, n, alpha)
    assert dk == pytest.approx(d1 * k, rel=1e-12)
    assert layers_for_near_field(10.0 * k, res, dk, alpha) == n
    plan = envmap_plan(10.0 * k, res, n, alpha)
    assert np.all(np.isfinite(plan.distances)) and np.all(np.diff(plan.distances) > 0)
    assert np.all(np.diff(plan.borders) > 0) and plan.borders[0] > 5.0 * k


@SETTINGS
@given(n=st.integers(1, 200), res=st.integers(16, 2048), extra=st.integers(1, 50))
def test_envmap_more_layers_bring_the_near_field_closer(n, res, extra):
    alpha = pixel_angle(math.pi / 2, res, "min")
    assert near_field_distance(10.0, res, n + extra, alpha) < near_field_distance(10.0, res, n, alpha)


def test_shaft_plan_is_valid_and_scale_invariant():
    for k in (1e-3, 1.0, 1e5):
        shaft = ShaftCell([0.0, 0.0, 0.0], [1.0, 0.2, 0.1], math.radians(30), 200.0 * k)
        plan = plan_layers(shaft, np.array([[-20, -15, -10], [25, 15, 10]]) * k, math.radians(45), 512)
        check_plan(plan)
        assert plan.reference_offset == pytest.approx(200 * k * math.tan(math.radians(15)))
        if k == 1e-3:
            first = plan
        assert plan.count == first.count


def test_diagonal_part_uses_the_line_between_centres():
    cell = BoxCell.from_center([0, 0, 0], 10.0)
    plan = plan_layers(cell, [[100, 100, -5], [110, 110, 5]], math.radians(45), 256)
    np.testing.assert_allclose(plan.axis, [math.sqrt(0.5), math.sqrt(0.5), 0.0], atol=1e-12)
    check_plan(plan)


# --- the one-pixel budget shared by texels and parallax (texel_share) -----------------------------

SHARED = settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
shares = st.sampled_from([0.5, 0.7, 0.9])


def worst_parallax_measured(plan, cell) -> float:
    """The largest angle, from the cell's corners, between points of the frustum at each slab
    border and their images on the slab's layer plane: parallax_angles on a 65 x 65 grid of the
    cross-section, independently of the plan's own (coarser, ray-based) search."""
    frame = np.stack([plan.u, plan.v, plan.axis])
    corners = (cell.corners() - plan.reference_viewpoint) @ frame.T
    g = np.linspace(-1.0, 1.0, 65)
    section = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2) * plan.frustum_half_tangents
    s = plan.reference_offset
    worst = 0.0
    for i in range(plan.count):
        for z in (plan.borders[i] + s, plan.borders[i + 1] + s):
            points = np.column_stack([section * z, np.full(section.shape[0], z)])
            worst = max(worst, float(parallax_angles(points, corners, plan.distances[i] + s).max()))
    return worst


@SHARED
@given(
    gap=st.floats(1.0, 30.0), depth=depths, width=widths, res=st.integers(16, 256), fov=fovs, model=models, share=shares
)
@pytest.mark.slow
def test_shared_budget_keeps_texels_and_parallax_within_one_pixel(gap, depth, width, res, fov, model, share):
    cell, bounds = scene(1.0, gap, depth, width)
    plan = plan_layers(cell, bounds, math.radians(fov), res, model, texel_share=share)
    check_plan(plan)
    assert plan.texel_angle + plan.parallax_angle <= plan.alpha
    # A texel of the nearest layer plane, seen from the near border, subtends at most the texel angle.
    s = plan.reference_offset
    texel = 2.0 * plan.frustum_half_tangents * (plan.t0 + s) / plan.texture_resolution / plan.t0
    assert np.all(texel <= plan.texel_angle * (1 + 1e-9))
    assert worst_parallax_measured(plan, cell) <= plan.parallax_angle * (1 + 1e-3)


@SHARED
@given(gap=st.floats(1.0, 30.0), depth=depths, width=widths, res=st.integers(16, 256), fov=fovs, share=shares, k=scales)
@pytest.mark.slow
def test_shared_budget_is_scale_invariant(gap, depth, width, res, fov, share, k):
    p1 = plan_layers(*scene(1.0, gap, depth, width), math.radians(fov), res, texel_share=share)
    pk = plan_layers(*scene(k, gap, depth, width), math.radians(fov), res, texel_share=share)
    assert pk.count == p1.count
    np.testing.assert_allclose(pk.distances, p1.distances * k, rtol=1e-9)
    np.testing.assert_allclose(pk.borders, p1.borders * k, rtol=1e-9)


@SHARED
@given(
    gap=st.floats(1.0, 30.0),
    depth=depths,
    width=widths,
    res=st.integers(16, 128),
    factor=st.floats(1.1, 3.0),
    share=shares,
)
@pytest.mark.slow
def test_shared_budget_layer_count_rises_with_resolution(gap, depth, width, res, factor, share):
    cell, bounds = scene(1.0, gap, depth, width)
    low = plan_layers(cell, bounds, math.radians(45), res, texel_share=share)
    high = plan_layers(cell, bounds, math.radians(45), int(res * factor), texel_share=share)
    assert high.count >= low.count


def test_thesis_depth_ranges_exceed_the_pixel_seen_from_the_far_corners():
    """Eq. 3.7 (seed 000 §3.3.1) bounds parallax for a viewer on the near border in the diagonal
    plane; from the far corners of a deep cell the frustum's edge moves further (the scrub pine
    cell of issue 23: 1.2 alpha before the first layer).  The shared budget measures it in 3D."""
    cell = BoxCell.from_center([-2500.0, 470.0, 0.0], 100.0)
    bounds = [[-374.5, 3.0, -431.9], [341.1, 933.9, 269.7]]
    thesis = plan_layers(cell, bounds, math.radians(45), 512)
    assert worst_parallax_measured(thesis, cell) > 1.15 * thesis.alpha
    shared = plan_layers(cell, bounds, math.radians(45), 512, texel_share=0.7)
    assert worst_parallax_measured(shared, cell) <= shared.parallax_angle * (1 + 1e-3)


@pytest.mark.parametrize("share", [0.0, 1.0, -0.5, math.nan])
def test_texel_share_outside_0_1_is_refused(share):
    with pytest.raises(LayerPlanError, match="texel share"):
        plan_layers(
            BoxCell.from_center([0, 0, 0], 10.0),
            [[50.0, -5.0, -5.0], [60.0, 5.0, 5.0]],
            math.radians(45),
            512,
            texel_share=share,
        )


# --- refusals -------------------------------------------------------------------------------------

CELL = BoxCell.from_center([0, 0, 0], 10.0)
FAR_PART = [[50.0, -5.0, -5.0], [60.0, 5.0, 5.0]]


@pytest.mark.parametrize(
    "bounds",
    [
        [[5.0, -1, -1], [8.0, 1, 1]],  # touching the cell's face
        [[2.0, -1, -1], [8.0, 1, 1]],  # reaching into the cell
        [[-1.0, -1, -1], [1.0, 1, 1]],  # inside the cell
        [[3.0, 3.0, -1], [9.0, 9.0, 1]],  # overlapping diagonally
    ],
)
def test_part_touching_or_inside_the_cell_is_refused(bounds):
    with pytest.raises(LayerPlanError, match="touch|inside|overlap|centred"):
        plan_layers(CELL, bounds, math.radians(45), 512)


@pytest.mark.parametrize("fov", [0.0, 180.0, -10.0, 200.0, float("nan"), float("inf")])
def test_fov_outside_0_180_is_refused(fov):
    with pytest.raises(LayerPlanError, match="field of view"):
        plan_layers(CELL, FAR_PART, math.radians(fov), 512)


@pytest.mark.parametrize("res", [0, -1, 0.5])
def test_resolution_below_one_is_refused(res):
    with pytest.raises(LayerPlanError, match="resolution"):
        plan_layers(CELL, FAR_PART, math.radians(45), res)
    with pytest.raises(LayerPlanError, match="resolution"):
        envmap_plan(10.0, res, 4, 1e-3)


@pytest.mark.parametrize("alpha", [0.0, -1e-3, float("nan"), float("inf")])
def test_alpha_not_positive_is_refused(alpha):
    with pytest.raises(LayerPlanError, match="alpha"):
        envmap_plan(10.0, 512, 4, alpha)
    with pytest.raises(LayerPlanError, match="alpha|parallax"):
        near_field_distance(10.0, 512, 4, alpha)


@pytest.mark.parametrize("size", [0.0, -10.0, float("nan")])
def test_zero_or_negative_sizes_are_refused(size):
    with pytest.raises(LayerPlanError, match="size"):
        envmap_plan(size, 512, 4, 1e-3)
    with pytest.raises(ViewCellError):
        BoxCell.from_center([0, 0, 0], size)
    with pytest.raises(LayerPlanError):
        texture_resolution(size, 10.0, 1e-3)


def test_near_field_inside_the_cell_is_refused():
    with pytest.raises(LayerPlanError, match="outside the view cell"):
        layers_for_near_field(10.0, 512, 4.0, 1e-3)


@pytest.mark.parametrize("alpha", [2.0, math.pi / 2])
def test_huge_alpha_is_refused(alpha):
    with pytest.raises(LayerPlanError, match="alpha"):
        envmap_plan(10.0, 512, 4, alpha)


def test_absurd_texture_resolution_is_refused():
    """A wide part almost touching the cell would need an absurd texture; say so."""
    with pytest.raises(LayerPlanError, match="texels per side"):
        plan_layers(CELL, [[5.0 + 1e-7, -5, -5], [6.0, 5, 5]], math.radians(45), 4096)
