"""Primitive-budget image placement (seed 004): octree cells, yaw ranges, 6-tuple subsets, the solution
grid with star-shapes, and the guarantee over sampled views."""

from __future__ import annotations

import itertools
import json
import math

import numpy as np
import pytest
from click.testing import CliRunner
from scenes import write_scene

from farfield.cli.main import _register, cli
from farfield.core import procedural
from farfield.core.placement.cell_subsets import B1, B2, B, C, SubsetSearch, place_image, project_cells
from farfield.core.placement.hierarchy import PlacementError
from farfield.core.placement.octree_cells import octree_cells
from farfield.core.placement.solution_grid import (
    MIN_FOV_DEG,
    UNSOLVED,
    BudgetSettings,
    check_views,
    place_primitives,
    star_radius,
)  # fmt: skip
from farfield.core.placement.yaw_ranges import TWO_PI, YawRanges, drawn_cells, forward, right

# barycentric weights of points on a triangle: corners, edge points and inside points (6 steps a side)
WEIGHTS = np.array([(i, j, 6 - i - j) for i in range(7) for j in range(7 - i)], dtype=np.float64) / 6.0


def _city():
    return procedural.city(64, seed=1, detail=8)


def _view_space(scene, height=3.0):
    lo, hi = scene.bounds
    a, b = 0.75 * lo + 0.25 * hi, 0.25 * lo + 0.75 * hi
    return np.array([a[0], height, a[2]]), np.array([b[0], height + 4.0, b[2]])


@pytest.fixture(scope="module")
def city_placement():
    scene = _city()
    lo, hi = _view_space(scene)
    return scene, place_primitives(scene, lo, hi, BudgetSettings(primitives=0.3 * scene.triangle_count, max_level=3))


def test_every_triangle_lies_in_its_octree_cell():
    scene = _city()
    cells = octree_cells(scene, depth=4)
    assert cells.total_triangles == scene.triangle_count and cells.count == len(np.unique(cells.key, axis=0))
    for k, obj in enumerate(scene.objects):
        corners = obj.vertices[obj.faces]
        owner = cells.face_cell[k]
        assert np.all(corners.min(axis=1) >= cells.lo[owner]) and np.all(corners.max(axis=1) <= cells.hi[owner])
    faces = cells.faces_of(np.arange(cells.count))
    assert sum(f.size for _, f in faces) == scene.triangle_count
    with pytest.raises(PlacementError, match="octree depth"):
        octree_cells(scene, depth=11)


def _random_boxes(rng, n=300, spread=50.0):
    lo = rng.uniform(-spread, spread, (n, 3))
    return lo, lo + rng.uniform(0.1, 8.0, (n, 3))


def _in_frustum(points, eye, yaw, half):
    d = points - eye
    ahead, side, up = d @ forward(yaw), d @ right(yaw), d[..., 1]
    t = math.tan(half)
    return (ahead > 0) & (np.abs(side) < t * ahead) & (np.abs(up) < t * ahead)


def test_a_range_counts_every_cell_the_frustum_meets_from_any_eye_inside_it():
    """Points sampled inside each box: a box with a point inside an eye's frustum must be drawn there,
    and every cell drawn from an eye inside the apex's frustum must be counted by the apex's range."""
    rng = np.random.default_rng(3)
    lo, hi = _random_boxes(rng)
    samples = lo[:, None] + rng.random((lo.shape[0], 64, 3)) * (hi - lo)[:, None]
    half = math.radians(30)
    for _trial in range(40):
        apex = rng.uniform(-20, 20, 3)
        ranges = YawRanges.of(lo, hi, apex, half)
        yaw = rng.random() * TWO_PI
        counted = ranges.members(ranges.range_of(yaw))
        seen = _in_frustum(samples, apex, yaw, half).any(axis=1)
        assert np.all(counted[seen]) and np.all(drawn_cells(lo, hi, apex, yaw, half)[seen])
        d = rng.random() * 30.0
        u, w = rng.uniform(-0.9, 0.9, 2) * d * math.tan(half)
        eye = apex + d * forward(yaw) + u * right(yaw) + w * np.array([0.0, 1.0, 0.0])
        assert np.all(counted[drawn_cells(lo, hi, eye, yaw, half)])


def test_range_sums_agree_with_their_members():
    rng = np.random.default_rng(4)
    lo, hi = _random_boxes(rng, 200)
    w = rng.integers(1, 100, 200).astype(float)
    ranges = YawRanges.of(lo, hi, np.zeros(3), math.radians(35))
    mask = rng.random(200) < 0.7
    sums = ranges.sums(w, mask)
    assert ranges.count > 50
    for i in range(ranges.count):
        assert sums[i] == pytest.approx(w[ranges.members(i) & mask].sum())
    # the range of a yaw is the one whose half-open interval holds it, across the wrap too
    assert (
        ranges.range_of(ranges.breaks[3]) == 3
        and ranges.range_of(ranges.breaks[0] - 1e-12 + TWO_PI) == ranges.count - 1
    )


def test_a_six_tuple_subset_is_the_cells_inside_its_borders():
    rng = np.random.default_rng(5)
    lo, hi = _random_boxes(rng, 120, spread=10.0)
    lo[:, 2] -= 80.0
    hi[:, 2] -= 80.0  # all ahead of the origin looking down -z
    screen = project_cells(lo, hi, np.zeros(3), 0.0, math.radians(30))
    search = SubsetSearch(screen, np.ones(120), 120.0, 60.0, 100.0)
    for _ in range(50):
        s = tuple(int(rng.integers(0, len(search.lists[k]))) for k in "lrbtn")
        L, R, Bt, T, N = (search.lists[k] for k in "lrbtn")
        brute = (screen["x0"] >= L[s[0]]) & (screen["x1"] <= R[s[1]]) & (screen["y0"] >= Bt[s[2]]) & (screen["y1"] <= T[s[3]]) \
            & (screen["z0"] >= N[s[4]])  # fmt: skip
        assert np.array_equal(search.members(s), brute)


def test_the_cost_benefit_weights_are_the_papers_and_the_search_stops_near_p_opt():
    assert (C, B, B1, B2) == (0.4, 0.6, 0.1, 0.9)
    rng = np.random.default_rng(6)
    lo, hi = _random_boxes(rng, 400, spread=30.0)
    lo[:, 2] -= 100.0
    hi[:, 2] -= 100.0
    tris = rng.integers(10, 200, 400).astype(float)
    total = tris.sum()
    found = place_image(lo, hi, tris, np.zeros(3), 0.0, math.radians(30), total, 0.5 * total, 200.0)
    assert found is not None and found.drawn <= 0.5 * total
    assert found.drawn >= 0.9 * 0.5 * total  # it shrinks the subset until it would no longer cull enough
    assert found.depth == pytest.approx(-hi[found.cells, 2].max(), rel=1e-12)
    assert np.all(found.quad[:, 2] == pytest.approx(-found.depth))
    assert place_image(lo, hi, tris, np.zeros(3), 0.0, math.radians(30), total + 1e9, 0.5 * total, 200.0) is None


@pytest.mark.slow
def test_the_star_radius_holds_every_eye_and_the_papers_sphere_does_not_at_54_degrees():
    """Closest lattice point in the reverse frustum, sampled: within the proved radius at every FOV;
    the paper's 2 r is passed at 54° in 3D (why farfield does not use it)."""
    rng = np.random.default_rng(0)
    g = np.arange(-6, 7)
    lattice = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3).astype(float)
    worst = {}
    for fov in (54.0, 60.0, 90.0):
        half = math.radians(fov / 2)
        far = 0.0
        for _ in range(3000):
            eye, yaw = rng.random(3), rng.random() * TWO_PI
            inside = _in_frustum(eye[None], lattice, yaw, half) | np.all(lattice == eye, axis=1)
            d = eye - lattice
            ok = (d @ forward(yaw) >= 0) & (np.abs(d @ right(yaw)) <= math.tan(half) * (d @ forward(yaw))) \
                & (np.abs(d[:, 1]) <= math.tan(half) * (d @ forward(yaw)))  # fmt: skip
            far = max(far, float(np.linalg.norm(d[ok | inside], axis=1).min()))
        worst[fov] = far
        assert far <= star_radius(1.0, half)
    assert worst[54.0] > 2.0  # the paper's sphere of diameter 4 r
    assert MIN_FOV_DEG == pytest.approx(53.1301, abs=1e-4)


@pytest.mark.slow
def test_the_guarantee_holds_on_ten_thousand_views(city_placement):
    scene, placement = city_placement
    s = placement.summary()
    assert s["images"] > 0 and s["unsolved_points"] == 0
    assert s["points_per_level"][1] > 0  # the dense city forced subdivision
    assert (
        0.9 <= s["image_drawn_over_p_opt"]["median"] <= 1.0
    )  # solutions sit just under p_opt (the paper: within ~2 %)
    check = check_views(placement, 10_000, seed=1)
    assert check["within_p"] == 1.0 and check["max"] <= placement.primitives
    assert check["without_grid_point"] == 0 and check["eye_past_quad"] == 0 and check["in_unsolved_range"] == 0
    assert check["with_image"] > 0
    # the view space's corners, edge middles and face centres (where a grid point is farthest) at 24 yaws
    lo, hi = placement.view_lo, placement.view_hi
    for f in itertools.product((0.0, 0.5, 1.0), repeat=3):
        for yaw in np.linspace(0.0, TWO_PI, 24, endpoint=False):
            view = placement.view(lo + np.asarray(f) * (hi - lo), yaw)
            assert view["point"] >= 0 and not view["past_quad"] and view["primitives"] <= placement.primitives


def test_what_a_view_does_not_draw_lies_outside_its_frustum_or_in_its_image(city_placement):
    """Brute force over triangles: any triangle with a vertex inside the eye's frustum is drawn as
    geometry or is one of the image's cells; and no drawn cell is one the image replaces."""
    scene, placement = city_placement
    rng = np.random.default_rng(2)
    cells = placement.cells
    half = placement.half
    for _ in range(60):
        eye = placement.view_lo + rng.random(3) * (placement.view_hi - placement.view_lo)
        yaw = rng.random() * TWO_PI
        view = placement.view(eye, yaw)
        covered = view["cells"].copy()
        if view["image"] >= 0:
            im = placement.points[view["point"]].images[view["image"]]
            assert not np.any(view["cells"][im["cells"]])
            covered[im["cells"]] = True
        for k, obj in enumerate(scene.objects):
            # points on every triangle: its corners and a lattice of barycentric points inside it
            seen = _in_frustum(np.einsum("sc,fcd->fsd", WEIGHTS, obj.vertices[obj.faces]), eye, yaw, half).any(axis=1)
            assert np.all(covered[cells.face_cell[k][seen]])


@pytest.mark.slow
def test_too_little_subdivision_leaves_unsolved_views_reported():
    scene = _city()
    lo, hi = _view_space(scene)
    placement = place_primitives(scene, lo, hi, BudgetSettings(primitives=0.2 * scene.triangle_count, max_level=0))
    s = placement.summary()
    assert s["unsolved_points"] > 0 and s["points_per_level"] == [s["grid_points"]]
    assert any(UNSOLVED in p.image for p in placement.points if p.failure)
    check = check_views(placement, 2000)
    assert check["in_unsolved_range"] > 0 and check["eye_past_quad"] == 0


def test_bad_inputs_are_clear_errors():
    scene = _city()
    lo, hi = _view_space(scene)
    with pytest.raises(PlacementError, match="star-shape bound"):
        place_primitives(scene, lo, hi, BudgetSettings(primitives=1000, fov_deg=45))
    with pytest.raises(PlacementError, match="meets the view space holds"):
        place_primitives(scene, lo, hi, BudgetSettings(primitives=1))
    with pytest.raises(PlacementError, match="views to check"):
        check_views(place_primitives(scene, lo, hi, BudgetSettings(primitives=scene.triangle_count)), 0)
    # a budget of the whole model needs no image, whatever the cells hold
    assert place_primitives(scene, lo, hi, BudgetSettings(primitives=scene.triangle_count, octree_depth=0)).images == 0
    with pytest.raises(PlacementError, match="empty"):
        place_primitives(scene, hi, lo, BudgetSettings(primitives=1000))
    with pytest.raises(PlacementError, match="p_opt"):
        place_primitives(scene, lo, hi, BudgetSettings(primitives=1000, p_opt=2000))


@pytest.mark.slow
def test_place_command_with_the_primitive_budget(tmp_path):
    _register()
    scene = procedural.city(16, seed=2, detail=8)
    path = write_scene(scene, tmp_path, "glb", "city")
    lo, hi = _view_space(scene)
    out = tmp_path / "grid.json"
    space = ",".join(f"{v:g}" for v in (*lo, *hi))
    args = ["place", str(path), "--view-space", space, "--algorithm", "primitive-budget", "--primitives",
            str(int(0.4 * scene.triangle_count)), "--check-views", "500", "--out", str(out), "--quiet"]  # fmt: skip
    runner = CliRunner()
    result = runner.invoke(cli, args)
    assert result.exit_code == 0, result.output
    assert "100.00 % within P" in result.output and "images:" in result.output
    doc = json.loads(out.read_text())
    assert doc["format"] == "farfield.primitive_placement" and doc["check"]["within_p"] == 1.0
    assert doc["summary"]["images"] == sum(len(p["images"]) for p in doc["points"]) > 0
    as_json = json.loads(runner.invoke(cli, [*args[:-1], "--json"]).output)
    assert as_json["summary"] == doc["summary"]
    narrow = runner.invoke(cli, [*args, "--fov", "45"])
    assert narrow.exit_code == 2 and "star-shape bound" in narrow.output
    mixed = runner.invoke(cli, [*args, "--frame-ms", "10"])
    assert mixed.exit_code == 2 and "--primitives N only" in mixed.output


@pytest.mark.slow
def test_a_baked_database_is_walked_within_the_budget(tmp_path):
    """farfield place --bake writes the grid and an LDI bundle per image; farfield walkthrough reads it
    back against the scene: every view within P, LDIs warped, a few hole pixels at most."""
    _register()
    scene = procedural.city(16, seed=2, detail=8)
    path = write_scene(scene, tmp_path, "glb", "city")
    lo, hi = _view_space(scene)
    space = ",".join(f"{v:g}" for v in (*lo, *hi))
    db = tmp_path / "db"
    runner = CliRunner()
    placed = runner.invoke(cli, ["place", str(path), "--view-space", space, "--algorithm", "primitive-budget", "--primitives",
                                 str(int(0.4 * scene.triangle_count)), "--check-views", "0", "--bake", str(db), "--ldi-resolution", "96", "--quiet"])  # fmt: skip
    assert placed.exit_code == 0, placed.output
    index = json.loads((db / "placement.json").read_text())
    assert len(index["bundles"]) == index["summary"]["images"] > 0
    assert all((db / b / "impostor.glb").is_file() for b in index["bundles"].values())
    walked = runner.invoke(
        cli,
        [
            "walkthrough",
            str(db),
            str(path),
            "--random",
            "12",
            "--repeats",
            "1",
            "--json",
            "--plot",
            str(tmp_path / "walk.png"),
        ],
    )
    assert (tmp_path / "walk.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert walked.exit_code == 0, walked.output
    result = json.loads(walked.output)
    assert all(
        f["drawn_triangles"] == f["primitives"] for f in result["frames"]
    )  # what the GL drew is what was counted
    s = result["summary"]
    assert s["views"] == 12 and s["share_within_p"] == 1.0 and s["eye_past_quad"] == 0
    assert s["views_with_image"] > 0 and s["primitives_max"] <= s["primitives_budget"]
    other = procedural.city(16, seed=3, detail=8)
    wrong = runner.invoke(
        cli, ["walkthrough", str(db), str(write_scene(other, tmp_path, "glb", "other")), "--random", "2"]
    )
    assert wrong.exit_code == 2 and "another scene" in wrong.output
    again = runner.invoke(
        cli,
        [
            "place",
            str(path),
            "--view-space",
            space,
            "--algorithm",
            "primitive-budget",
            "--primitives",
            "5000",
            "--bake",
            str(db),
        ],
    )
    assert again.exit_code == 2 and "not empty" in again.output
