"""Simplified geometry (QEM levels of detail) competing with layered impostors in one greedy (issue 57, item 3).

A small statue park (two bumpy statues of 5,120 triangles), a street-level view space beside them
and the builtin llvmpipe model at a third of the plain frame: the levels of detail are measured
(their error bound holds), chosen where they save memory with their error within the pixel budget,
written to a placement database and drawn by the reference runtime with real EGL (fewer triangles,
the image within the budget of the full scene's).  Nothing here asserts a wall-clock time.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
import trimesh
from scipy import ndimage

from farfield.core import procedural
from farfield.core.impostor.database import ImpostorDatabase
from farfield.core.pixel_angles import pixel_angle
from farfield.core.placement.cost_model import LLVMPIPE_MODEL
from farfield.core.placement.database import write_placement_database
from farfield.core.placement.hierarchy import Elements
from farfield.core.placement.lod import LOD_TECHNIQUE, MeshError, level_for, lod_chain, node_mesh
from farfield.core.placement.planner import PlacementSettings, place
from farfield.core.placement.runtime import PlacementRenderer
from farfield.core.placement.view_space import box_gap

VIEW = (np.array([-4.0, 1.7, -1.0]), np.array([4.0, 1.7, 3.0]))  # street level, 6-10 m from the statues
RESOLUTION, FOV = 96, 60.0


def _park():
    return procedural.statue_park(2, 4)


@pytest.fixture(scope="module")
def placed():
    scene = _park()
    plain = place(scene, *VIEW, _settings(1e-6, False)).summary["worst_before"]  # every view a problem view
    t_max = plain / 3.0
    layered = place(scene, *VIEW, _settings(t_max, False))
    mixed = place(scene, *VIEW, _settings(t_max, True))
    return scene, t_max, layered, mixed


def _settings(t_max: float, lod: bool) -> PlacementSettings:
    return PlacementSettings(t_max, LLVMPIPE_MODEL, options={"resolution": RESOLUTION, "fov_deg": FOV}, cpv_size=4.0,
                             vdi_deg=45.0, leaf_size=1, cluster_triangles=10**6, lod=lod)  # fmt: skip


def _farthest_vertex(vertices: np.ndarray, level) -> float:
    """The farthest any of ``vertices`` lies from ``level``'s surface: every triangle against each
    vertex (trimesh's closest points, brute force, no spatial index)."""
    worst = 0.0
    for chunk in np.array_split(vertices, max(1, vertices.shape[0] // 64)):
        corners = np.repeat(level.vertices[level.faces][None], chunk.shape[0], axis=0).reshape(-1, 3, 3)
        at = np.repeat(chunk, level.triangles, axis=0)
        near = trimesh.triangles.closest_point(corners, at)
        worst = max(worst, float(np.linalg.norm(near - at, axis=1).reshape(chunk.shape[0], -1).min(axis=1).max()))
    return worst


def test_levels_shrink_and_their_error_is_the_farthest_vertex():
    scene = procedural.statue_park(1, 4, seed=8)  # a statue where the fan's bound was loose (1.7x, 3.9x)
    vertices, faces, colours = node_mesh(scene)
    chain = lod_chain(vertices, faces, colours)
    assert len(chain) >= 3
    assert [lv.triangles for lv in chain] == sorted((lv.triangles for lv in chain), reverse=True)
    assert chain[0].triangles <= faces.shape[0] // 3
    for level in chain[:3]:
        assert level.memory_bytes == 28 * level.vertices.shape[0] + 12 * level.triangles
        # every full vertex's distance to the simplified surface, the largest, and the level's own
        # vertices and centroids (a sixth) back to the full surface: the error holds both (the pixel budget)
        # and is no loose bound of them (a level's error sets how near it may be drawn)
        forward = _farthest_vertex(vertices, level)
        points = np.concatenate([level.vertices, level.vertices[level.faces].mean(axis=1)])[::6]
        back = _farthest_vertex(points, SimpleNamespace(vertices=vertices, faces=faces, triangles=faces.shape[0]))
        assert level.error >= max(forward, back) * (1 - 1e-9)
        assert level.error <= 1.25 * max(forward, back)


def _grid(n: int, lift: float = 0.0):
    """A flat unit square of ``2 n^2`` triangles in z = 0, its middle vertex (n even) lifted by ``lift``."""
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    vertices = np.column_stack([i.ravel() / n, j.ravel() / n, np.zeros(i.size)])
    vertices[(n // 2) * (n + 1) + n // 2, 2] = lift
    k = (i[:-1, :-1] * (n + 1) + j[:-1, :-1]).ravel()
    faces = np.concatenate([np.column_stack([k, k + n + 1, k + 1]), np.column_stack([k + 1, k + n + 1, k + n + 2])])
    return vertices, faces


def test_error_holds_both_sides():
    # a simplified surface with a spike the full vertices do not see: the spike's height (0.5), not
    # the full middle vertex's distance to the spike's sides (0.5 * 0.5 / sqrt(0.5) = 0.354)
    full, full_faces = _grid(16)
    spike, spike_faces = _grid(2, lift=0.5)
    owner = np.argmin(np.linalg.norm(full[:, None] - spike[None], axis=2), axis=1)
    assert MeshError(full, full_faces).of(owner, spike, spike_faces) == pytest.approx(0.5, rel=1e-9)
    # a full surface with a bump the flat simplified one cuts off: the bump's height
    bumped, _ = _grid(16, lift=0.1)
    flat, flat_faces = _grid(2)
    owner = np.argmin(np.linalg.norm(bumped[:, None] - flat[None], axis=2), axis=1)
    assert MeshError(bumped, full_faces).of(owner, flat, flat_faces) == pytest.approx(0.1, rel=1e-9)


def test_a_spike_moves_onto_the_full_surface():
    # the spike's apex lies 0.5 from the full surface, farther than any full vertex from the spike
    # (0.354): it moves to its nearest full point; the other vertices stay
    full, full_faces = _grid(16)
    spike, spike_faces = _grid(2, lift=0.5)
    owner = np.argmin(np.linalg.norm(full[:, None] - spike[None], axis=2), axis=1)
    errors = MeshError(full, full_faces)
    moved, forward = errors.spikes_moved(owner, spike, spike_faces)
    assert math.isnan(forward)
    assert np.allclose(moved[4], [0.5, 0.5, 0.0], atol=1e-12) and np.array_equal(
        np.delete(moved, 4, 0), np.delete(spike, 4, 0)
    )
    assert errors.of(owner, moved, spike_faces) == pytest.approx(0.0, abs=1e-12)
    # a flat level under a bumped full surface: no vertex lies farther than the bump, none moves
    bumped, _ = _grid(16, lift=0.1)
    flat, flat_faces = _grid(2)
    owner = np.argmin(np.linalg.norm(bumped[:, None] - flat[None], axis=2), axis=1)
    same, forward = MeshError(bumped, full_faces).spikes_moved(owner, flat, flat_faces)
    assert same is flat and forward == pytest.approx(0.1, rel=1e-9)


def test_lod_chosen_where_it_saves_memory_within_the_pixel_budget(placed):
    scene, t_max, layered, mixed = placed
    s, s0 = mixed.summary, layered.summary
    assert s["by_technique"]["lod"]["impostors"] > 0
    assert s["cpvs_solved"] >= s0["cpvs_solved"] and s["cpvs"] == s0["cpvs"]
    assert s["memory_bytes"] < 0.5 * s0["memory_bytes"]
    elements = Elements.of(scene, 10**6)
    index = {name: i for i, name in enumerate(elements.names)}
    budget = pixel_angle(math.radians(FOV), RESOLUTION, "min")  # 1 px: layered's max_error_px default
    lods = [imp for imp in mixed.impostors if imp["technique"] == LOD_TECHNIQUE and imp["cpvs"]]
    for imp in lods:
        ids = [index[name] for name in imp["objects"]]
        level = level_for(elements.scene_of(scene, ids), imp["level"])  # as the runtime draws it
        measured = lod_chain(*node_mesh(elements.scene_of(scene, ids)))[imp["level"] - 1]  # as planned
        assert np.array_equal(level.vertices, measured.vertices) and np.array_equal(level.faces, measured.faces)
        assert level.triangles == imp["triangles"] and imp["kind"] == "lod"
        assert level.memory_bytes == imp["memory_bytes"]
        level = measured
        lo, hi = elements.bounds[ids, 0].min(axis=0), elements.bounds[ids, 1].max(axis=0)
        for cpv in mixed.cpvs:
            if imp["id"] in cpv["impostors"]:
                near = box_gap(np.array([cpv["region"][0]]), np.array([cpv["region"][1]]), lo, hi)[0]
                assert level.error <= budget * near  # its projected error within 1 px from the nearest point


def test_runtime_draws_the_lod_within_the_pixel_budget(placed, tmp_path):
    scene, t_max, _, mixed = placed
    root = write_placement_database(tmp_path / "db", mixed, {})  # levels of detail need no bake
    with ImpostorDatabase(root) as db, PlacementRenderer(scene, db) as runtime:
        lod_cells = set(runtime.lod_cells)
        assert lod_cells and all(db.cell(c).bundle is None for c in lod_cells)
        drawn = 0
        for cpv in mixed.cpvs:
            if not set(cpv["impostors"]) & lod_cells or set(cpv["impostors"]) - lod_cells:
                continue
            lo, hi = np.array(cpv["region"])
            eye = 0.5 * (lo + hi)
            target = np.mean([o.bounds.mean(axis=0) for o in scene.objects], axis=0)
            camera, draws, figures = runtime.prepare(eye, target - eye)
            if not figures.impostors:
                continue
            _, plain_draws, plain = runtime.prepare(eye, target - eye, plain=True, camera=camera)
            assert figures.triangles < plain.triangles
            image, full = runtime.render(camera, draws), runtime.render(camera, plain_draws)
            covered, reference = image[..., 3] > 0, full[..., 3] > 0
            grown = ndimage.binary_dilation  # within 1 px of the full scene's coverage, both ways
            assert not np.any(covered & ~grown(reference)) and not np.any(reference & ~grown(covered))
            inside = ndimage.binary_erosion(covered & reference)
            assert np.abs(image[inside, :3].astype(int) - full[inside, :3]).mean() < 8.0
            drawn += 1
            if drawn == 3:
                break
        assert drawn > 0


def test_lazy_greedy_with_replacement_chooses_what_full_reranking_chooses(placed):
    from farfield.core.placement.greedy import Greedy

    scene, t_max, _, _ = placed
    state = place(scene, *VIEW, _settings(t_max, True), keep_state=True).state
    chosen = []
    for lazy in (True, False):
        greedy = Greedy(state.hierarchy, state.pv, state.cand, t_max)
        greedy.own = 1  # a candidate may replace its node's own drawn level of detail (or impostor)
        greedy.run(lazy=lazy)
        chosen.append([(c.candidate, sorted(c.cpvs)) for c in greedy.chosen])
    assert chosen[0] == chosen[1] and chosen[0]
