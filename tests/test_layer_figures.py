"""The published figures of the layer mathematics (seeds 000, 001, 002, 003, 004), reproduced to the digit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from farfield.core.layering.plan import (
    border_offset,
    depth_range,
    depth_range_min,
    plan_layers,
    single_layer_distance,
    spacing_left_upper,
    spacing_right,
)
from farfield.core.pixel_angles import perspective_factor, pixel_angle, star_shape_distance
from farfield.core.techniques.envmap.arrangement import (
    alpha_for_spacing,
    envmap_plan,
    layers_for_near_field,
    near_field_distance,
    parallax_factor,
    parallax_step,
    tdm_texel_limit,
    texel_limit,
)
from farfield.core.viewcells import BoxCell

M = 5.0  # half of a 10 m cubic view cell
RES = 512


# --- seed 000 §3.3.1 -----------------------------------------------------------------------------


def test_eq_3_2_right_boundary_spacing():
    assert spacing_right(95, 0, 100, 30, 90, 300) == pytest.approx(0.20098, abs=1e-4)


def test_eq_3_4_equals_eq_3_2_at_s_zero():
    t = np.linspace(90.0, 500.0, 50)
    np.testing.assert_allclose(
        spacing_left_upper(t, 0.0, 100, 30, 90, 300), spacing_right(t, 0.0, 100, 30, 90, 300), rtol=1e-14
    )
    # ... and not for s > 0, so the equality above is not vacuous.
    assert spacing_left_upper(95, 10, 100, 30, 90, 300) != pytest.approx(spacing_right(95, 10, 100, 30, 90, 300))


@pytest.mark.parametrize(("tn", "tf", "s", "d"), [(100, 110, 0, 4.76190), (100, 110, 50, 4.80030)])
def test_eq_3_6_border(tn, tf, s, d):
    assert border_offset(tn, tf, s) == pytest.approx(d, abs=1e-5)


def _eq_3_6_printed(tn, tf, s):
    return (-tn * tn - tn * s + np.sqrt(tf * tn * (tf + s) * (tn + s))) / (tn + tf + s)


def test_eq_3_6_stable_form_keeps_its_digits_in_float32_at_large_distance():
    tn, tf, s = np.float32(2.0e6), np.float32(2.0e6 + 300.0), np.float32(50.0)
    exact = border_offset(float(tn), float(tf), float(s))
    stable = border_offset(tn, tf, s)
    printed = _eq_3_6_printed(tn, tf, s)
    assert stable.dtype == np.float32
    assert abs(stable - exact) / exact < 2e-6
    # The printed form really does lose its digits there, which is why it is not used.
    assert abs(printed - exact) / exact > 100 * abs(stable - exact) / exact


def test_eq_3_6_stable_form_agrees_with_printed_form_in_float64():
    tn = np.geomspace(1e-3, 1e6, 40)
    tf = tn * 1.07
    for s in (0.0, 0.3, 50.0):
        np.testing.assert_allclose(border_offset(tn, tf, s * tn), _eq_3_6_printed(tn, tf, s * tn), rtol=1e-8)


def test_e_min_figure():
    assert depth_range_min(1000, 50, 70.71, 1.618e-3) == pytest.approx(22.0643, abs=1e-4)


def test_e_min_is_the_minimum_of_eq_3_7_over_phi():
    t, s, r, a = 1000.0, 50.0, 70.71, 1.618e-3
    phi = np.linspace(-0.6, 0.9, 20001)
    e = depth_range(t, s, r, a, phi)
    phi_min = 0.5 * math.atan(s / r)
    assert e.min() == pytest.approx(float(depth_range_min(t, s, r, a)), rel=1e-7)
    assert phi[np.argmin(e)] == pytest.approx(phi_min, abs=1e-3)


def test_e_min_pole_unbounded_never_negative():
    s, r, a = 50.0, 70.71, 1.618e-3
    pole = float(single_layer_distance(s, r, a))
    assert pole == pytest.approx((r * math.cos(a) + math.hypot(r, s)) / (2 * math.sin(a)) - s / 2)
    t = np.concatenate([np.linspace(1.0, pole * 0.999999, 500), np.linspace(pole * 1.000001, pole * 10, 500)])
    e = depth_range_min(t, s, r, a)
    assert not np.any(np.isnan(e))
    assert np.all(e > 0)
    assert np.all(np.isfinite(e[t < pole])) and np.all(np.isinf(e[t > pole]))
    # The depth range grows without bound towards the pole.
    assert depth_range_min(pole * 0.999999, s, r, a) > 1e6 * depth_range_min(pole * 0.5, s, r, a)


TABLE_4_1 = {90: 110, 110: 81, 140: 56, 180: 34, 250: 19, 500: 5, 1000: 1}


@pytest.mark.parametrize(("distance", "layers"), sorted(TABLE_4_1.items()))
def test_table_4_1_layer_counts(distance, layers):
    """Seed 000 Table 4.1: one building about 45 m deep, cubic 100 m view cell, 512x512, 45°.

    The thesis's convention is the centre pixel angle ("center").
    """
    cell = BoxCell.from_center([0, 0, 0], 100.0)
    building = [[50.0 + distance, -15.0, -10.0], [50.0 + distance + 45.0, 15.0, 10.0]]
    plan = plan_layers(cell, building, math.radians(45), 512, pixel_model="center")
    assert abs(plan.count - layers) <= 0.1 * layers


def test_table_4_1_is_insensitive_to_the_building_width():
    cell = BoxCell.from_center([0, 0, 0], 100.0)
    counts = {
        plan_layers(cell, [[190.0, -w / 2, -w / 3], [235.0, w / 2, w / 3]], math.radians(45), 512, "center").count
        for w in (20.0, 30.0, 45.0, 60.0)
    }
    assert max(counts) - min(counts) <= 1


# --- seed 002 §4 ---------------------------------------------------------------------------------

PIXEL_SIZED_ALPHAS = [
    pixel_angle(math.pi / 2, RES, "min"),
    2.2661e-3,
    math.radians(90) / RES,
    pixel_angle(math.pi / 2, RES, "center"),
]


@pytest.mark.parametrize("alpha", PIXEL_SIZED_ALPHAS)
def test_near_field_after_64_layers_is_42_m(alpha):
    assert 41.5 <= near_field_distance(10.0, RES, 64, alpha) <= 42.5
    assert 41.5 <= envmap_plan(10.0, RES, 64, alpha).near_field <= 42.5


def test_one_layer_near_field_is_1738_m():
    assert near_field_distance(10.0, RES, 1, 2.2661e-3) == pytest.approx(1738.0, abs=1.0)
    first = parallax_step(math.inf, M, 2.2661e-3)
    assert parallax_step(first, M, 2.2661e-3) == pytest.approx(1738.0, abs=1.0)


@pytest.mark.parametrize("dims", [2, 3])
@pytest.mark.parametrize("alpha", [1e-4, 2.2661e-3, 1e-2])
def test_every_eq_1_step_scales_u_by_one_constant(alpha, dims):
    F = np.concatenate([[math.inf], np.geomspace(M * 1.001, 1e7, 60)])
    ratios = []
    for f in F:
        f2 = parallax_step(f, M, alpha, dims)
        assert M < f2 < f
        ratios.append((1.0 - M / f) / (1.0 - M / f2))
    ratios = np.array(ratios)
    np.testing.assert_allclose(ratios, ratios[0], rtol=1e-9)
    assert ratios[0] == pytest.approx(1.0 / parallax_factor(M, alpha, dims), rel=1e-12)


def test_eq_2_scales_u_by_exactly_one_minus_one_over_res():
    for F in np.geomspace(M * 1.001, 1e9, 50):
        P = texel_limit(F, M, RES)
        assert (1.0 - M / P) / (1.0 - M / F) == pytest.approx(1.0 - 1.0 / RES, rel=1e-12)


@pytest.mark.parametrize("dims", [2, 3])
def test_alpha_recomputation_makes_two_eq_1_steps_land_on_the_eq_2_layer(dims):
    for F in (20.0, 500.0, 1e5):
        P = texel_limit(F, M, RES)
        a = alpha_for_spacing(P, F, M, dims)
        assert parallax_step(parallax_step(F, M, a, dims), M, a, dims) == pytest.approx(P, rel=1e-10)


def test_plan_borders_follow_the_recomputed_alpha():
    plan = envmap_plan(10.0, RES, 8, 2.2661e-3)
    assert set(plan.criterion[:-1]) == {"texel"} and plan.criterion[-1] == "first"
    for i in range(plan.count - 1):
        near, far = plan.distances[i], plan.distances[i + 1]
        a = alpha_for_spacing(near, far, M)
        assert plan.borders[i + 1] == pytest.approx(parallax_step(far, M, a), rel=1e-10)
        assert near == pytest.approx(texel_limit(far, M, RES), rel=1e-10)
    assert plan.distances[-1] == pytest.approx(parallax_step(math.inf, M, 2.2661e-3), rel=1e-12)
    assert plan.near_field == pytest.approx(parallax_step(plan.distances[0], M, 2.2661e-3), rel=1e-10)


def test_parallax_wins_when_alpha_is_small():
    plan = envmap_plan(10.0, RES, 6, 1e-4)
    assert set(plan.criterion[:-1]) == {"parallax"}
    for i in range(plan.count - 1):
        far = plan.distances[i + 1]
        two_steps = parallax_step(parallax_step(far, M, 1e-4), M, 1e-4)
        assert plan.distances[i] == pytest.approx(two_steps, rel=1e-10)


@pytest.mark.parametrize("alpha", PIXEL_SIZED_ALPHAS + [1e-4])
@pytest.mark.parametrize("n", [1, 2, 3, 10, 64, 500])
def test_layers_for_near_field_round_trips(n, alpha):
    d = near_field_distance(10.0, RES, n, alpha)
    assert layers_for_near_field(10.0, RES, d, alpha) == n
    assert layers_for_near_field(10.0, RES, d * (1 + 1e-9), alpha) == n
    if n > 1:
        assert layers_for_near_field(10.0, RES, d * (1 - 1e-9), alpha) == n + 1


# --- seed 003 §4.1, seed 001 §5.1, seed 004 §3.2.1 -------------------------------------------------


def test_tdm_eq_1_is_eq_2_at_90_degrees_and_larger_for_narrow_frusta():
    for F in (6.0, 100.0, 1e6):
        assert tdm_texel_limit(F, M, RES, math.pi / 2) == pytest.approx(texel_limit(F, M, RES), rel=1e-12)
        # A narrow frustum has smaller texels: the next layer must stay closer to F.
        assert texel_limit(F, M, RES) < tdm_texel_limit(F, M, RES, math.radians(20)) < F


def test_perspective_factor_at_45_degrees():
    assert perspective_factor(math.radians(45)) == pytest.approx(1.1716, abs=1e-4)


def test_star_shape_distance_at_most_r_from_53_13_degrees():
    r = 3.7
    threshold = 2 * math.degrees(math.atan(0.5))
    assert threshold == pytest.approx(53.13, abs=5e-3)
    for fov in (threshold + 1e-9, 60.0, 90.0, 120.0):
        assert star_shape_distance(r, math.radians(fov)) <= r
    for fov in (30.0, 53.0, threshold - 1e-6):
        assert star_shape_distance(r, math.radians(fov)) > r
