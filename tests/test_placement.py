"""The placement planner (seed 000 ch. 5): enclosing frusta, the greedy against brute force and
full re-ranking, extremes (no impostor needed, unsolvable, inside an object, scale, one mesh),
determinism, and ``farfield place``."""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner
from scenes import box_object, write_scene

from farfield.cli.main import _register, cli
from farfield.core import procedural
from farfield.core.placement.candidates import Candidates
from farfield.core.placement.cost_model import CostModel, primitive_model
from farfield.core.placement.greedy import Greedy
from farfield.core.placement.hierarchy import Elements, Hierarchy, PlacementError
from farfield.core.placement.planner import PlacementSettings, place
from farfield.core.placement.view_space import VDI, ProblemViews, RegionSight, frame_half_diagonal
from farfield.core.scene import Scene, SceneObject

FOV = math.radians(45.0)


# --------------------------------------------------------------------------------------------
# Enclosing frusta (§5.5.2, Fig. 5.2): never miss what a view sees
# --------------------------------------------------------------------------------------------


def _view_sees(eye, forward, roll, points, fov) -> bool:
    """Whether the square frame at ``eye`` looking along ``forward`` (rolled by ``roll``) holds any of ``points``."""
    helper = np.array([0.0, 1.0, 0.0]) if abs(forward[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    right = np.cross(forward, helper)
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    right, up = math.cos(roll) * right + math.sin(roll) * up, -math.sin(roll) * right + math.cos(roll) * up
    q = points - eye
    z = q @ forward
    t = math.tan(0.5 * fov)
    ok = (z > 0) & (np.abs(q @ right) <= t * z) & (np.abs(q @ up) <= t * z)
    return bool(ok.any())


@pytest.mark.slow
def test_enclosing_frusta_never_miss_an_element_a_view_sees():
    """Random boxes, regions, VDIs and views inside them: every element some view sees is in the
    VDI's enclosing frustum (the test is conservative by construction; this checks the code)."""
    rng = np.random.default_rng(25)
    widen = frame_half_diagonal(FOV)
    seen_checked = 0
    for _ in range(60):
        lo = rng.uniform(-50, 50, (40, 3))
        boxes = np.stack([lo, lo + rng.uniform(0.1, 8, (40, 3))], axis=1)
        r_lo = rng.uniform(-10, 0, 3)
        r_hi = r_lo + rng.uniform(0, 6, 3)
        level = int(rng.integers(0, 4))
        vdi = VDI(int(rng.integers(0, 6)), level, int(rng.integers(0, 1 << level)), int(rng.integers(0, 1 << level)))
        axis, half = vdi.cone()
        mask = RegionSight.of(boxes[:, 0], boxes[:, 1], r_lo, r_hi).seen(axis[None, :], np.array([half + widen]))[0]
        x0, x1, y0, y1 = vdi.ranges()
        for _ in range(30):
            eye = r_lo + rng.random(3) * (r_hi - r_lo)
            forward = vdi.directions([rng.uniform(x0, x1)], [rng.uniform(y0, y1)])[0]
            roll = rng.uniform(0, 2 * math.pi)
            for k in np.flatnonzero(~mask):
                pts = boxes[k, 0] + rng.random((200, 3)) * (boxes[k, 1] - boxes[k, 0])
                corners = np.array(
                    [[boxes[k, i >> 2 & 1, 0], boxes[k, i >> 1 & 1, 1], boxes[k, i & 1, 2]] for i in range(8)]
                )
                assert not _view_sees(eye, forward, roll, np.concatenate([pts, corners]), FOV), (vdi, k)
            seen_checked += int(mask.sum())
    assert seen_checked > 0


def _edge_case(seed: int, flat: bool):
    """A region (flat like a street-level one, or not), a VDI, and tiny boxes each seen by one view
    sampled in the region: direction the VDI's farthest corner, rolled so that its frame's corner
    ray points away from the cone's axis, the box just inside that corner.  Half the eyes are random
    points of random 4 x 4 x 4 sub-boxes of the region; the other half the region's corner from
    which the ray points farthest from the axis, so that no eye in the region sees that box at a
    smaller angle to the axis: those boxes (``edge``) lie on the enclosing cone's edge."""
    rng = np.random.default_rng(seed)
    r_lo = rng.uniform(-20, 0, 3)
    size = rng.uniform(5, 40, 3)
    if flat:
        size[1] = 1.0
    r_hi = r_lo + size
    level = int(rng.integers(0, 4))
    vdi = VDI(int(rng.integers(0, 6)), level, int(rng.integers(0, 1 << level)), int(rng.integers(0, 1 << level)))
    axis, half = vdi.cone()
    x0, x1, y0, y1 = vdi.ranges()
    corners = vdi.directions([x0, x1, x0, x1], [y0, y0, y1, y1])
    forward = corners[int(np.argmin(corners @ axis))]  # at ``half`` from the axis
    out = forward * float(forward @ axis) - axis  # tangent at ``forward``, away from the axis
    out /= np.linalg.norm(out)
    helper = np.array([0.0, 1.0, 0.0]) if abs(forward[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    right0 = np.cross(forward, helper)
    right0 /= np.linalg.norm(right0)
    up0 = np.cross(right0, forward)
    roll = math.atan2(out @ up0, out @ right0) - 0.25 * math.pi  # the frame's (+1, +1) corner along ``out``
    ray = forward + (1.0 - 1e-7) * math.tan(0.5 * FOV) * math.sqrt(2.0) * out
    ray /= np.linalg.norm(ray)
    toward = axis - ray * float(axis @ ray)  # in the plane of ray and axis, toward the axis
    far_corner = np.where(toward > 0.0, r_lo, r_hi)  # the eye minimising eye . toward
    boxes, edge = [], []
    for k in range(100):
        cell = rng.integers(0, 4, 3)
        eye = far_corner if k % 2 else r_lo + (cell + rng.random(3)) / 4.0 * (r_hi - r_lo)
        p = eye + rng.uniform(20, 200) * ray
        assert _view_sees(eye, forward, roll, p[None, :], FOV)
        boxes.append([p, p + 1e-6])
        edge.append(bool(k % 2))
    return np.array(boxes), np.array(edge), r_lo, r_hi, vdi


@pytest.mark.parametrize("flat", [True, False])
def test_enclosing_frusta_keep_elements_at_the_frame_edge_of_views_in_any_sub_box(flat):
    """Tiny elements each seen by a sampled view (eye in some sub-box of the region or at its
    corner, direction at the VDI's corner, rolled) just inside its frame's corner: the exact
    cone-against-box test keeps every one, and a cone narrower by 1e-4 rad drops those on the
    enclosing cone's edge (so the test is as tight as these views)."""
    widen = frame_half_diagonal(FOV)
    for seed in range(12):
        boxes, edge, r_lo, r_hi, vdi = _edge_case(seed, flat)
        sight = RegionSight.of(boxes[:, 0], boxes[:, 1], r_lo, r_hi)
        axis, half = vdi.cone()
        assert sight.seen(axis[None, :], np.array([half + widen]))[0].all(), seed
        tighter = sight.seen(axis[None, :], np.array([half + widen - 1e-4]))[0]
        assert not tighter[edge].any(), seed


def test_the_exact_cone_test_drops_what_the_sphere_keeps_over_a_flat_region():
    """A street-level region (37.5 x 1 x 37.5) looking straight up: ground-level boxes beside it lie
    within the bounding sphere of ``box - region`` as seen from the cone, but no view sees them
    (checked on sampled views) and the exact test drops them."""
    r_lo, r_hi = np.array([0.0, 0.0, 0.0]), np.array([37.5, 1.0, 37.5])
    lo = np.array([[-30.0, 0.0, 10.0], [50.0, 0.0, 10.0], [10.0, 0.0, -30.0], [10.0, 0.0, 50.0]])
    boxes = np.stack([lo, lo + [8.0, 3.0, 8.0]], axis=1)
    up = VDI(2, 3, 3, 3)  # face +y, a level-3 interval at its centre
    axis, half = up.cone()
    sight = RegionSight.of(boxes[:, 0], boxes[:, 1], r_lo, r_hi)
    h = np.array([half + frame_half_diagonal(FOV)])
    assert sight.seen_by_sphere(axis[None, :], h)[0].all()
    assert not sight.seen(axis[None, :], h)[0].any()
    rng = np.random.default_rng(5)
    x0, x1, y0, y1 = up.ranges()
    corners = np.array(
        [[boxes[k, i >> 2 & 1, 0], boxes[k, i >> 1 & 1, 1], boxes[k, i & 1, 2]] for k in range(4) for i in range(8)]
    )
    points = np.concatenate(
        [corners] + [boxes[k, 0] + rng.random((200, 3)) * (boxes[k, 1] - boxes[k, 0]) for k in range(4)]
    )
    for _ in range(300):
        eye = r_lo + rng.random(3) * (r_hi - r_lo)
        forward = up.directions([rng.uniform(x0, x1)], [rng.uniform(y0, y1)])[0]
        assert not _view_sees(eye, forward, rng.uniform(0, 2 * math.pi), points, FOV)


def test_vdi_quadtree_covers_the_sphere_once():
    rng = np.random.default_rng(3)
    d = rng.normal(size=(2000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    leaves = [VDI(f, 2, i, j) for f in range(6) for i in range(4) for j in range(4)]
    hits = np.sum([v.contains(d) for v in leaves], axis=0)
    assert hits.min() >= 1 and np.mean(hits == 1) > 0.99


# --------------------------------------------------------------------------------------------
# The greedy (§5.7): valid, near the optimum, lazy == full re-ranking
# --------------------------------------------------------------------------------------------


def _instance(seed: int, candidates: int = 8, cpvs: int = 5):
    """A random small instance: a hierarchy over 6 unit boxes (leaves of one), CPVs whose elements
    have random times, candidates on random nodes serving random CPVs with random impostor times
    and memory."""
    rng = np.random.default_rng(seed)
    objects = [box_object(f"b{i}", (3.0 * i, 0, 0), (3.0 * i + 1, 1, 1)) for i in range(6)]
    elements = Elements.of(Scene.from_objects(objects, "synthetic"))
    h = Hierarchy.build(elements, leaf_size=1)
    e = elements.count
    entry = rng.uniform(0.5, 3.0, (cpvs, e))  # every CPV sees every element
    time = 1.0 + entry.sum(axis=1)
    t_max = float(rng.uniform(0.45, 0.8) * time.min())
    pv = ProblemViews(
        region_lo=np.zeros((1, 3)), region_hi=np.ones((1, 3)), tree_lo=np.zeros((1, 3)), tree_hi=np.ones((1, 3)),
        tree_first=np.array([0]), tree_last=np.array([1]), tree_parent=np.array([-1]),
        cpv_region=np.zeros(cpvs, dtype=np.int64), cpv_vdi=tuple(VDI(0, 0, 0, 0) for _ in range(cpvs)),
        time=time, fixed_time=np.ones(cpvs), offsets=np.arange(cpvs + 1) * e,
        positions=np.tile(np.arange(e), cpvs), entry_time=entry[:, h.order].reshape(-1), entry_pixels=np.zeros(cpvs * e),
        entry_fixed=np.zeros(cpvs * e, dtype=bool),
        stats={"t_max": t_max},
    )  # fmt: skip
    cum = np.concatenate([np.zeros((cpvs, 1)), np.cumsum(entry[:, h.order], axis=1)], axis=1)
    # impostor time as the cost model gives it: per impostor plus per pixel, pixels adding up over
    # the elements (so a cluster's impostor is faster than its parts' impostors together)
    pixels = rng.uniform(0.0, 1.0, (cpvs, e))
    pix_cum = np.concatenate([np.zeros((cpvs, 1)), np.cumsum(pixels[:, h.order], axis=1)], axis=1)
    nodes = rng.integers(0, h.count, candidates)
    served, g, ti = [], [], []
    for n in nodes:
        s = np.flatnonzero(rng.random(cpvs) < 0.7)
        gn = cum[s, h.end[n]] - cum[s, h.start[n]]
        tn = 0.3 + 0.5 * (pix_cum[s, h.end[n]] - pix_cum[s, h.start[n]])
        s, gn, tn = (
            s[gn > tn],
            gn[gn > tn],
            tn[gn > tn],
        )  # served only where it saves (as generate_candidates keeps them)
        served.append(s), g.append(gn), ti.append(tn)
    cand = Candidates(
        node=nodes, kind=np.zeros(candidates, dtype=np.int64), cells=tuple([None] * candidates),
        memory=rng.uniform(1.0, 10.0, candidates), layers=np.ones(candidates), texels=np.ones(candidates), quads=np.ones(candidates),
        served_offsets=np.concatenate([[0], np.cumsum([s.size for s in served])]), served=np.concatenate(served),
        g=np.concatenate(g), ti=np.concatenate(ti), stats={},
    )  # fmt: skip
    return h, pv, cand, t_max


def _best_time(h, pv, cand, subset, p) -> float:
    """The fastest CPV ``p`` can be drawn with impostors of ``subset`` serving it (no two on one
    path of the hierarchy): a min over the tree."""
    start = pv.offsets[p]
    cum = np.concatenate([[0.0], np.cumsum(pv.entry_time[start : pv.offsets[p + 1]])])
    imp = {}
    for i in subset:
        rows = np.flatnonzero(cand.served[cand.served_offsets[i] : cand.served_offsets[i + 1]] == p)
        if rows.size:
            t = float(cand.ti[cand.served_offsets[i] + rows[0]])
            imp[int(cand.node[i])] = min(imp.get(int(cand.node[i]), np.inf), t)

    def best(n: int) -> float:
        own = cum[h.end[n]] - cum[h.start[n]]
        if not h.leaf[n]:
            own = min(own, sum(best(c) for c in range(n + 1, n + int(h.size[n])) if h.parent[c] == n))
        return min(own, imp.get(n, np.inf))

    return float(pv.time[p] - (cum[-1] - best(0)))


def _valid(h, pv, cand, subset, t_max) -> bool:
    return all(_best_time(h, pv, cand, subset, p) <= t_max * (1 + 1e-12) for p in range(pv.count))


@pytest.mark.parametrize("seed", range(40))
def test_lazy_re_ranking_chooses_what_full_re_ranking_chooses(seed):
    h, pv, cand, t_max = _instance(seed, candidates=14, cpvs=7)
    lazy, full = Greedy(h, pv, cand, t_max), Greedy(h, pv, cand, t_max)
    lazy.run(lazy=True)
    full.run(lazy=False)
    assert [c.candidate for c in lazy.chosen] == [c.candidate for c in full.chosen]
    assert np.array_equal(lazy.t, full.t)


def _with_twins(cand: Candidates) -> Candidates:
    """``cand`` and, after it, a copy of each of its candidates (the same rows and memory)."""
    lengths = np.diff(cand.served_offsets)
    twice = lambda a: np.concatenate([a, a])  # noqa: E731
    return replace(
        cand, node=twice(cand.node), kind=twice(cand.kind), cells=tuple(cand.cells) * 2, memory=twice(cand.memory),
        layers=twice(cand.layers), texels=twice(cand.texels), quads=twice(cand.quads),
        served_offsets=np.concatenate([[0], np.cumsum(twice(lengths))]), served=twice(cand.served), g=twice(cand.g),
        ti=twice(cand.ti),
    )  # fmt: skip


@pytest.mark.parametrize("seed", range(6))
def test_the_greedy_kernels_equal_numpy_re_ranking_on_larger_instances(seed):
    """The lazy heap and re-scoring in numba (:func:`~farfield.core.placement.greedy._settle`: rows
    of solved CPVs skipped, drawn impostors looked up per CPV) choose what re-ranking every item by
    numpy at every step chooses, on instances with candidates of more than 128 rows (numpy's
    pairwise sum in blocks) and many impostors drawn per CPV; and each candidate's kernel gain
    equals numpy's sum of its rows' gains at every step, to the bit."""
    h, pv, cand, t_max = _instance(500 + seed, candidates=40, cpvs=400)
    cand = _with_twins(cand)  # equal scores: ties go to the smaller index
    assert np.diff(cand.served_offsets).max() > 128
    lazy, full = Greedy(h, pv, cand, t_max), Greedy(h, pv, cand, t_max)
    lazy.run(lazy=True)
    full.run(lazy=False)
    assert len(lazy.chosen) >= 3
    assert [c.candidate for c in lazy.chosen] == [c.candidate for c in full.chosen]
    assert np.array_equal(lazy.t, full.t)
    # the kernel's gain beside numpy's, after each choice of the lazy greedy's order
    step = Greedy(h, pv, cand, t_max)
    for c in lazy.chosen:
        for i in range(cand.count):
            assert step.rank(i) == step.rank(i, reference=True)
        step.choose(c.candidate)
    assert np.array_equal(step.t, lazy.t)


@pytest.mark.slow
def test_greedy_is_valid_and_near_the_brute_force_optimum():
    """On 60 random instances small enough to enumerate (8 candidates, 256 subsets): whenever a
    valid placement exists, the greedy's is valid, and its memory stays within 1.5x of the optimum.
    Measured (2026-12-02): 33 instances had a valid placement; the greedy found the optimum in 26,
    its memory was 1.037x the optimum on average and 1.42x at worst."""
    ratios, solvable = [], 0
    for seed in range(60):
        h, pv, cand, t_max = _instance(1000 + seed)
        optimum = min(
            (float(cand.memory[list(s)].sum()) for r in range(cand.count + 1) for s in itertools.combinations(range(cand.count), r)
             if _valid(h, pv, cand, s, t_max)),
            default=None,
        )  # fmt: skip
        g = Greedy(h, pv, cand, t_max)
        g.run()
        kept = [c.candidate for k, c in enumerate(g.chosen) if k not in g.deleted]
        # the greedy's own bookkeeping matches the drawing it describes
        for p in range(pv.count):
            drawn = [g.chosen[k] for k in g.drawn[p]]
            nodes = [c.node for c in drawn]
            assert not any(h.is_ancestor_or_self(a, b) for a in nodes for b in nodes if a != b)
        if optimum is None:
            continue
        solvable += 1
        assert np.all(g.t <= t_max * (1 + 1e-9)), (
            f"instance {seed}: a valid placement exists but the greedy left {g.t.max()} > {t_max}"
        )
        ratios.append(float(cand.memory[kept].sum()) / optimum)
    assert solvable >= 20
    assert max(ratios) <= 1.5, f"greedy / optimum memory: mean {np.mean(ratios):.3f}, worst {max(ratios):.3f}"


# --------------------------------------------------------------------------------------------
# place(): extremes, scale, one huge mesh, determinism
# --------------------------------------------------------------------------------------------


def _small_city(scale: float = 1.0) -> Scene:
    city = procedural.city(36, seed=5, detail=6)
    if scale == 1.0:
        return city
    return Scene.from_objects(
        [SceneObject(o.name, o.vertices * scale, o.faces, base_color=o.base_color) for o in city.objects], "scaled"
    )


def _settings(t_max: float, **kw) -> PlacementSettings:
    base = {"vdi_deg": 45.0, "options": {"resolution": 128}, "cpv_size": 20.0, "cells": "both"}
    base.update(kw)
    return PlacementSettings(t_max=t_max, model=primitive_model(), **base)


VIEW = ([20.0, 110.0, 20.0], [100.0, 115.0, 100.0])  # above the roofs of the small city


def test_a_generous_budget_needs_no_impostor():
    city = _small_city()
    result = place(city, *VIEW, _settings(t_max=2.0 * city.triangle_count))
    assert result.summary["cpvs"] == 0 and result.impostors == [] and result.message() is None


@pytest.mark.slow
def test_a_tight_budget_is_met_with_impostors_and_every_cpv_stays_within_it():
    city = _small_city()
    result = place(city, *VIEW, _settings(t_max=0.5 * city.triangle_count))
    s = result.summary
    assert s["cpvs"] > 0 and s["impostors"] > 0 and s["memory_bytes"] > 0
    assert s["cpvs_solved"] == s["cpvs"], result.message()
    assert s["worst_after"] <= s["t_max"] < s["worst_before"]
    served = {i for c in result.cpvs for i in c["impostors"]}
    assert served == {imp["id"] for imp in result.impostors}  # no impostor drawn nowhere
    for imp in result.impostors:
        assert imp["cell"]["kind"] in ("shaft", "box") and imp["objects"]


@pytest.mark.slow
def test_memory_grows_as_the_budget_falls():
    city = _small_city()
    runs = [place(city, *VIEW, _settings(t_max=f * city.triangle_count)) for f in (0.8, 0.5)]
    assert runs[1].memory_bytes > runs[0].memory_bytes and runs[1].summary["impostors"] > runs[0].summary["impostors"]
    assert all(r.summary["cpvs_solved"] == r.summary["cpvs"] for r in runs)


@pytest.mark.slow
def test_impostors_over_the_largest_size_are_never_candidates():
    city = _small_city()
    free = place(city, *VIEW, _settings(t_max=0.5 * city.triangle_count))
    largest = max(imp["memory_bytes_estimated"] for imp in free.impostors)
    capped = place(city, *VIEW, _settings(t_max=0.5 * city.triangle_count, max_impostor_bytes=0.5 * largest))
    assert free.summary["candidates_refused_by_memory"] == 0 < capped.summary["candidates_refused_by_memory"]
    assert all(imp["memory_bytes_estimated"] <= 0.5 * largest for imp in capped.impostors)
    assert capped.parameters["max_impostor_bytes"] == 0.5 * largest
    with pytest.raises(PlacementError, match="largest impostor"):
        place(city, *VIEW, _settings(t_max=100.0, max_impostor_bytes=0))


def test_a_view_space_inside_a_heavy_object_is_unsolvable_and_named():
    city = _small_city()
    v, f = procedural.subdivided_box([30.0, 100.0, 30.0], [60.0, 130.0, 60.0], 40)  # 19200 triangles around the viewer
    heavy = SceneObject("shell", v, f[:, ::-1])
    scene = Scene.from_objects([*city.objects, heavy], "city+shell")
    result = place(
        scene,
        [40.0, 110.0, 40.0],
        [50.0, 115.0, 50.0],
        _settings(t_max=5000.0, cpv_size=10.0, cluster_triangles=100_000),
    )
    s = result.summary
    assert s["cpvs_unsolvable"] > 0 and result.unsolvable
    assert any("shell" in r["elements"] for r in result.unsolvable)
    assert "unsolvable" in result.message() and "shell" in result.message()


@pytest.mark.parametrize("scale", [2.0**-10, 2.0**17])
@pytest.mark.slow
def test_placement_is_the_same_up_to_scale(scale):
    """At about 1e-3 and 1e5 times the size, the same placement scaled.  Powers of two keep every
    product exact, so equality is exact; a scale like 1e-3 moves elements lying exactly on a
    frustum's or a region's border to the other side by rounding (the counts then differ by a
    few in a thousand)."""
    base = place(_small_city(), *VIEW, _settings(t_max=0.5 * _small_city().triangle_count))
    scaled_view = ([c * scale for c in VIEW[0]], [c * scale for c in VIEW[1]])
    other = place(
        _small_city(scale), *scaled_view, _settings(t_max=0.5 * _small_city().triangle_count, cpv_size=20.0 * scale)
    )
    for key in ("cpvs", "candidates", "impostors", "cpvs_solved"):
        assert other.summary[key] == base.summary[key], key
    assert [i["node"] for i in other.impostors] == [i["node"] for i in base.impostors]
    for a, b in zip(base.impostors, other.impostors):
        if a["cell"]["kind"] == "shaft":
            assert b["cell"]["min_distance"] == pytest.approx(a["cell"]["min_distance"] * scale, rel=1e-6)
    assert other.memory_bytes == pytest.approx(base.memory_bytes, rel=1e-6)


def test_a_single_huge_object_is_split_and_placed():
    city = _small_city()
    vertices, faces, offset = [], [], 0
    for o in city.objects:
        vertices.append(o.vertices), faces.append(o.faces + offset)
        offset += len(o.vertices)
    one = Scene.from_objects([SceneObject("everything", np.concatenate(vertices), np.concatenate(faces))], "one mesh")
    result = place(one, *VIEW, _settings(t_max=0.5 * one.triangle_count))
    assert result.elements["split"] == {"everything": result.elements["count"]} and result.elements["count"] > 8
    assert result.summary["impostors"] > 0
    assert all(name.startswith("everything#") for imp in result.impostors for name in imp["objects"])


@pytest.mark.slow
def test_two_runs_give_identical_json():
    city = _small_city()
    a = place(city, *VIEW, _settings(t_max=0.5 * city.triangle_count))
    b = place(city, *VIEW, _settings(t_max=0.5 * city.triangle_count))
    assert json.dumps(a.to_dict()) == json.dumps(b.to_dict())
    assert a.summary["impostors"] > 0


def test_bad_inputs_are_placement_errors():
    city = _small_city()
    with pytest.raises(PlacementError, match="t_max|budget"):
        place(city, *VIEW, _settings(t_max=0.0))
    with pytest.raises(PlacementError, match="lo <= hi"):
        place(city, VIEW[1], VIEW[0], _settings(t_max=100.0))
    with pytest.raises(PlacementError, match="cannot be placed"):
        place(city, *VIEW, _settings(t_max=100.0, technique="envmap", options={}))
    # part techniques without an estimate: not envmap's reason (points and ldi replace a part too)
    with pytest.raises(
        PlacementError,
        match=r"technique 'points' has no memory and frame-time estimate for the frame-time planner; for a frame budget",
    ):
        place(city, *VIEW, _settings(t_max=100.0, technique="points", options={}))
    with pytest.raises(PlacementError, match=r"technique 'ldi' has no .* placed by the primitive-budget algorithm"):
        place(city, *VIEW, _settings(t_max=100.0, technique="ldi", options={}))


def test_a_frame_time_model_with_a_per_frame_cost_above_the_budget_is_unsolvable():
    model = CostModel("frame_ms", (0.01, 1e-5, 0.0, 5.0), (0.0, 1e-4, 0.01), (100.0, 0.0, 1.3))
    result = place(
        _small_city(),
        *VIEW,
        PlacementSettings(t_max=4.0, model=model, vdi_deg=90.0, options={"resolution": 128}, cpv_size=80.0),
    )
    assert result.summary["cpvs"] == result.summary["cpvs_unsolvable"] > 0


# --------------------------------------------------------------------------------------------
# farfield place
# --------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_place_command_writes_a_placement_and_refuses_bad_input(tmp_path):
    _register()
    path = write_scene(_small_city(), tmp_path, "glb", "city")
    out = tmp_path / "placement.json"
    runner = CliRunner()
    args = ["place", str(path), "--view-space", "20,110,20,100,115,100", "--primitives", str(0.5 * _small_city().triangle_count),
            "--resolution", "128", "--vdi-deg", "45", "--cpv-size", "20", "--cells", "both", "--out", str(out), "--quiet"]  # fmt: skip
    result = runner.invoke(cli, args)
    assert result.exit_code == 0, result.output
    assert "impostors:" in result.output and "placement written to" in result.output
    doc = json.loads(out.read_text())
    assert doc["format"] == "farfield-placement" and doc["summary"]["impostors"] > 0
    as_json = runner.invoke(cli, [*args[:-1], "--json"])
    assert json.loads(as_json.output)["summary"] == doc["summary"]
    bad = runner.invoke(cli, ["place", str(path), "--view-space", "1,2,3", "--primitives", "10"])
    assert bad.exit_code == 2 and "--view-space" in bad.output
    both = runner.invoke(cli, ["place", str(path), "--view-space", "0,0,0,1,1,1"])
    assert both.exit_code == 2 and "budget" in both.output
    capped = runner.invoke(cli, [*args[:-1], "--json", "--max-impostor-mb", "0.001"])
    assert (
        json.loads(capped.output)["summary"]["candidates_refused_by_memory"]
        > 0
        == doc["summary"]["candidates_refused_by_memory"]
    )
    zero = runner.invoke(cli, [*args[:-1], "--max-impostor-mb", "0"])
    assert zero.exit_code == 2 and "--max-impostor-mb must be > 0, got 0.0" in zero.output


def test_cluster_names_never_clash_with_object_names():
    v, f = procedural.subdivided_box([0.0, 0.0, 0.0], [1.0, 1.0, 1.0], 8)  # 768 triangles
    small_v, small_f = procedural.subdivided_box([5.0, 5.0, 5.0], [6.0, 6.0, 6.0], 1)
    clash = SceneObject("a#0", small_v, small_f)  # an object named like the first cluster of "a"
    scene = Scene.from_objects([SceneObject("a", v, f), clash], "clash")
    elements = Elements.of(scene, cluster_triangles=300)
    assert len(set(elements.names)) == elements.count and "a#0" in elements.names
    assert elements.split_counts(scene) == {"a": elements.count - 1}
    assert elements.scene_of(scene, range(elements.count)).object_count == elements.count


def test_an_absurd_view_space_is_a_placement_error():
    with pytest.raises(PlacementError, match="finite"):
        place(_small_city(), [-1e308, 0, 0], [1e308, 1, 1], _settings(t_max=100.0, cpv_size=None))
    with pytest.raises(PlacementError, match="regions"):
        place(_small_city(), [0, 100, 0], [100, 110, 100], _settings(t_max=100.0, cpv_size=1e-3))
