"""Shared texture charts of textured depth meshes (core/techniques/tdm/texture.py, seed 003 §7-§8): grouping,
folds, ties on shared edges, the size cap, sampling through the world triangle, their packing as
masks (core/techniques/tdm/mask_atlas.py), and the memory and colour error of a real bake against per-triangle
tiles (the layout before shared charts)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import scenes
from scipy.spatial import cKDTree

from farfield.core.errors import AtlasOverflowError, LayerPlanError
from farfield.core.impostor.impostor import MeshPayload
from farfield.core.layering.plan import plan_layers
from farfield.core.layering.tiles import pack_tiles
from farfield.core.quality.evaluation import evaluate
from farfield.core.stage_clock import StageClock
from farfield.core.techniques.tdm.mask_atlas import BLOCK, WIDTH_SCALES, pack_masks
from farfield.core.techniques.tdm.technique import TdmOptions, bake_tdm, geometry_bytes
from farfield.core.techniques.tdm.texture import (
    MAX_CHART,
    build_charts,
    chart_masks,
    rasterize,
    sample_field,
)
from farfield.core.techniques.tdm.voxel_field import record_voxel_field
from farfield.core.viewcells import BoxCell


def claims(charts, points: np.ndarray, triangles: np.ndarray) -> list[tuple[int, int, int, int]]:
    """(chart, u, v, triangle) of every texel centre a triangle of each chart contains, rasterized
    again from the charts' tile positions (so a fold left in a chart would show as a repeat)."""
    tri, u, v, inside, _ = rasterize(charts.position, 0)
    return sorted(zip(charts.chart[tri[inside]].tolist(), u[inside].tolist(), v[inside].tolist(), tri[inside].tolist()))


def assert_claimed_once(charts, points, triangles) -> None:
    texels = [c[:3] for c in claims(charts, points, triangles)]
    assert len(texels) == len(set(texels)), "a texel centre is claimed by two triangles of one chart"


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_two_coplanar_triangles_forming_a_square_share_one_tile(axis):
    # A 10 x 10 square split along its diagonal, in the plane normal to ``axis`` (layers integral).
    square = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], float)
    points = np.insert(square, axis, 3.0, axis=1)
    triangles = np.array([[0, 1, 2], [0, 2, 3]])
    charts = build_charts(points, triangles, 1)
    assert charts.count == 1 and charts.chart.tolist() == [0, 0]
    # The square plus one margin texel around it (an integer shift may add one row or column),
    # not two 12 x 12 bounding boxes of the two triangles.
    assert charts.sizes[0].tolist() in ([12, 12], [12, 13], [13, 12], [13, 13])
    assert charts.tile_texels <= 13 * 13 < 2 * 12 * 12
    # The diagonal runs through texel centres: each is claimed once, so exactly the square's 100.
    assert int(charts.texel_inside.sum()) == 100
    assert_claimed_once(charts, points, triangles)
    # Shared vertices, shared texture coordinates: one vertex per mesh vertex.
    assert geometry_bytes(triangles, charts.chart) == 4 * 20 + 2 * 3 * 4


def test_a_triangulated_grid_claims_every_texel_centre_once():
    # Vertices on texel centres, so that edges and vertices run through texel centres everywhere.
    n = 6
    g = np.stack(np.meshgrid(np.arange(n + 1) * 2 + 0.5, np.arange(n + 1) * 2 + 0.5, indexing="xy"), -1).reshape(-1, 2)
    rng = np.random.default_rng(5)
    triangles = []
    for j in range(n):
        for i in range(n):
            a, b, c, d = j * (n + 1) + i, j * (n + 1) + i + 1, (j + 1) * (n + 1) + i + 1, (j + 1) * (n + 1) + i
            triangles += [[a, b, c], [a, c, d]] if rng.random() < 0.5 else [[a, b, d], [b, c, d]]
    _, u, v, inside, _ = rasterize(g[np.array(triangles)], 0)
    claimed = sorted(zip(u[inside].tolist(), v[inside].tolist()))
    assert len(claimed) == len(set(claimed)) == (2 * n) ** 2  # half-open: one of each pair of sides


def test_a_fold_goes_into_separate_charts():
    # B shares A's edge (10,0)-(0,10) but its third vertex lies on A's side of it, three layers
    # deeper: the two overlap in the (x, y) projection.
    a = [[0, 0, 0], [10, 0, 0], [0, 10, 0]]
    for third in ([1, 1, 3], [4, 4, 1]):
        points = np.array(a + [third], float)
        for b in ([1, 2, 3], [2, 1, 3]):  # both windings: the same or the opposite normal sign
            triangles = np.array([[0, 1, 2], b])
            charts = build_charts(points, triangles, 1)
            assert charts.chart[0] != charts.chart[1]
            assert_claimed_once(charts, points, triangles)
            inside = np.bincount(charts.texel_triangle[charts.texel_inside], minlength=2)
            assert np.all(inside > 0)


def test_a_folded_strip_keeps_its_unfolded_part_together():
    # A fan of four triangles around (0, 0) over 450 degrees: the fifth quarter overlaps the first.
    ring = [[10, 0], [0, 10], [-10, 0], [0, -10], [10, 0.5], [0.5, 10]]
    points = np.array([[0, 0, 5]] + [[x, y, 5 + i] for i, (x, y) in enumerate(ring)], float)
    triangles = np.array([[0, i, i + 1] for i in range(1, 6)])
    charts = build_charts(points, triangles, 1)
    assert_claimed_once(charts, points, triangles)
    assert charts.chart[0] == charts.chart[1] == charts.chart[2] == charts.chart[3]
    assert charts.chart[4] != charts.chart[0]


def test_a_lone_triangle_folded_back_is_unfolded_beside_its_neighbour():
    # A 4 x 4 square facing the layers, and a triangle on its right edge folded back over it one
    # layer deeper: it faces another way, so it would be a chart of its own; unfolded, it lies
    # right of the square in the square's chart, at its true distance from the shared edge.
    points = np.array([[0, 0, 0], [4, 0, 0], [4, 4, 0], [0, 4, 0], [2, 2, 1]], float)
    triangles = np.array([[0, 1, 2], [0, 2, 3], [1, 4, 2]])
    charts = build_charts(points, triangles, 1)
    assert charts.chart.tolist() == [0, 0, 0]
    assert_claimed_once(charts, points, triangles)
    p = charts.position
    assert np.allclose(p[2, 0], p[0, 1]) and np.allclose(p[2, 2], p[0, 2])  # the shared edge
    assert p[2, 1, 0] == pytest.approx(p[0, 1, 0] + math.sqrt(5))  # (2, 2, 1) is sqrt(5) off the edge
    inside = np.bincount(charts.texel_triangle[charts.texel_inside], minlength=3)
    assert inside[2] > 0 and inside.sum() == 16 + inside[2]
    assert geometry_bytes(triangles, charts.chart) == 5 * 20 + 3 * 3 * 4  # one position per vertex


def test_an_unfolding_that_would_give_a_vertex_two_positions_is_refused():
    # The lone triangle facing away spans the square's diagonal corners: across either shared edge
    # its third vertex is already in the square's chart, where it has a position of its own.
    points = np.array([[0, 0, 0], [4, 0, 0], [4, 4, 0], [0, 4, 0]], float)
    triangles = np.array([[0, 1, 2], [0, 2, 3], [1, 3, 2]])
    charts = build_charts(points, triangles, 1)
    assert charts.chart[0] == charts.chart[1] != charts.chart[2]
    assert_claimed_once(charts, points, triangles)


@pytest.mark.parametrize("wall_first", [False, True])
def test_a_lone_triangle_on_an_edge_of_two_charts_goes_to_the_first_neighbour(wall_first):
    # The square's right edge (vertices 1, 2) is also the top edge of a wall facing x and an edge
    # of a triangle folded back over the square (a non-manifold edge): the triangle unfolds into
    # the chart of the neighbour of lower index, across the edge from it, sqrt(5) off the edge.
    points = np.array([[0, 0, 0], [4, 0, 0], [4, 4, 0], [0, 4, 0], [2, 2, 1], [4, 4, -3], [4, 0, -3]], float)
    square, wall = [[0, 1, 2], [0, 2, 3]], [[2, 1, 5], [1, 6, 5]]
    triangles = np.array((wall + square if wall_first else square + wall) + [[1, 4, 2]])
    charts = build_charts(points, triangles, 1)
    assert charts.count == 2 and charts.chart[4] == charts.chart[0] != charts.chart[2]
    assert_claimed_once(charts, points, triangles)
    at = dict(zip(triangles[0].tolist(), charts.position[0]))  # the neighbour's vertices
    a, apex, b = charts.position[4]
    assert np.allclose(a, at[1]) and np.allclose(b, at[2])

    def side(p):
        return (b - a)[0] * (p - a)[1] - (b - a)[1] * (p - a)[0]

    (third,) = set(at) - {1, 2}
    assert abs(side(apex)) / np.linalg.norm(b - a) == pytest.approx(math.sqrt(5))
    assert side(apex) * side(at[third]) < 0


def test_charts_wider_than_the_cap_are_cut():
    length = 5000
    xs = np.linspace(0, length, 51)
    points = np.concatenate(
        [
            np.stack([xs, np.zeros_like(xs), np.zeros_like(xs)], 1),
            np.stack([xs, np.full_like(xs, 10), np.zeros_like(xs)], 1),
        ]
    )
    triangles = np.concatenate([[[i, i + 1, 51 + i + 1], [i, 51 + i + 1, 51 + i]] for i in range(50)])
    charts = build_charts(points, triangles, 1)
    assert charts.count >= 3
    assert charts.sizes.max() <= MAX_CHART
    assert int(charts.texel_inside.sum()) == length * 10
    assert_claimed_once(charts, points, triangles)


# --- on a real recording ---------------------------------------------------------------------


def cell_before(scene, distance: float, size: float = 100.0) -> BoxCell:
    """As benchmarks/bench_tdm.py: a cubic cell centred on the part's x and y, ``distance`` in front of it."""
    lo, hi = scene.bounds
    c = 0.5 * (lo + hi)
    return BoxCell(
        np.array([c[0] - size / 2, c[1] - size / 2, lo[2] - distance - size]),
        np.array([c[0] + size / 2, c[1] + size / 2, lo[2] - distance]),
    )


@pytest.fixture(scope="module", params=[90.0, 140.0])
def house_tdm(request):
    """The benchmark's house at 128 pixels from 90 and 140 units, its TDM and its voxel field."""
    scene = scenes.house()
    cell = cell_before(scene, request.param)
    options = TdmOptions(resolution=128)
    impostor = bake_tdm(scene, cell, options)
    plan = plan_layers(cell, scene.bounds, math.radians(options.fov_deg), options.resolution, options.pixel_model)
    field = record_voxel_field(scene, plan, options.culling, StageClock())
    return scene, cell, impostor, field


def per_triangle_tiles(field, world: np.ndarray, margin: int) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """The layout before shared charts (commit 82c6668): each triangle its own tile in its own plane,
    one texel per voxel unit, grown by ``margin``, sampled through the world triangle.  Returns
    (tiles, chart positions (t, 3, 2), sizes (t, 2))."""
    points = field.from_world(world.reshape(-1, 3)).reshape(-1, 3, 3)
    a, b, c = points[:, 0], points[:, 1], points[:, 2]
    ab, ac = b - a, c - a
    length = np.linalg.norm(ab, axis=1)
    e1 = ab / length[:, None]
    cx = np.einsum("ij,ij->i", ac, e1)
    cy = np.linalg.norm(ac - cx[:, None] * e1, axis=1)
    xs = np.stack([np.zeros_like(cx), length, cx], 1)
    xs = xs - xs.min(axis=1, keepdims=True) + margin
    ys = np.stack([np.zeros_like(cy), np.zeros_like(cy), cy], 1) + margin
    sizes = np.stack([np.ceil(xs.max(1) + margin - 1e-9), np.ceil(ys.max(1) + margin - 1e-9)], 1).astype(np.int64)
    chart = np.stack([xs, ys], 2)
    tiles = []
    for i in range(len(points)):
        w, h = sizes[i]
        col, row = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
        p0, d1, d2 = chart[i, 0], chart[i, 1] - chart[i, 0], chart[i, 2] - chart[i, 0]
        det = d1[0] * d2[1] - d1[1] * d2[0]
        qx, qy = col.ravel() - p0[0], row.ravel() - p0[1]
        b1, b2 = (qx * d2[1] - qy * d2[0]) / det, (d1[0] * qy - d1[1] * qx) / det
        bary = np.clip(np.stack([1 - b1 - b2, b1, b2], 1), 0, None)
        bary /= bary.sum(1, keepdims=True)
        tiles.append(sample_field(field, field.from_world(bary @ world[i]), 1).reshape(h, w, 4))
    return tiles, chart, sizes


def tile_corner_uvs(chart: np.ndarray, sizes: np.ndarray, corner_uv: np.ndarray) -> np.ndarray:
    """(t, 3, 2) page UVs of triangles at tile positions ``chart`` (t, 3, 2) in tiles of ``sizes``
    (t, 2) whose corners TL, TR, BR, BL :func:`farfield.core.layering.tiles.pack_tiles` put at ``corner_uv`` (t, 4, 2)."""
    fx = chart[..., 0] / sizes[:, None, 0]
    fy = chart[..., 1] / sizes[:, None, 1]
    tl, tr, bl = corner_uv[:, None, 0], corner_uv[:, None, 1], corner_uv[:, None, 3]
    return tl + fx[..., None] * (tr - tl) + fy[..., None] * (bl - tl)


def test_every_texel_inside_a_triangle_samples_its_world_point(house_tdm):
    """Each page texel whose centre lies inside a triangle's UV triangle has the colour of the voxel
    field at the world point with the same barycentric coordinates (the module docstring's rule,
    which makes the GLB right under perspective-correct interpolation)."""
    _, _, impostor, field = house_tdm
    tree = cKDTree(field.centres)
    mesh = impostor.payload
    world = mesh.triangle_corners()
    uv = mesh.triangle_uv()
    checked = same = 0
    for i in range(mesh.triangle_count):
        page = impostor.pages[mesh.page[i]]
        h, w = page.shape[:2]
        corner = uv[i] * [w, h]  # texel units of the page
        lo, hi = np.floor(corner.min(0)).astype(int), np.ceil(corner.max(0)).astype(int)
        x, y = np.meshgrid(np.arange(lo[0], hi[0]) + 0.5, np.arange(lo[1], hi[1]) + 0.5)
        p = np.stack([x.ravel(), y.ravel()], 1)
        d1, d2 = corner[1] - corner[0], corner[2] - corner[0]
        det = d1[0] * d2[1] - d1[1] * d2[0]
        q = p - corner[0]
        b1, b2 = (q[:, 0] * d2[1] - q[:, 1] * d2[0]) / det, (d1[0] * q[:, 1] - d1[1] * q[:, 0]) / det
        bary = np.stack([1 - b1 - b2, b1, b2], 1)
        inside = np.all(bary > 1e-6, axis=1)
        if not inside.any():
            continue
        # The nearest voxel, or any voxel tied with it (a triangle crossing an empty voxel cell has
        # its texel centres one voxel from two or more voxels).
        distance, index = tree.query(field.from_world(bary[inside] @ world[i]), k=4)
        tied = distance <= distance[:, :1] + 1e-6
        texel = p[inside].astype(int)
        got = page[texel[:, 1], texel[:, 0]]
        match = np.all(field.rgba[index, :3] == got[:, None, :3], axis=2) & tied
        checked += int(inside.sum())
        same += int(match.any(axis=1).sum())
    assert checked > 500
    # Exact but where rounding the page position moves a texel centre across a Voronoi edge.
    print(f"{same} of {checked} texels exact")
    assert same >= 0.995 * checked


def test_house_pages_hold_every_chart_texel_once_and_are_opaque(house_tdm):
    """The charts of the bake again: their needed texels, packed as masks, are all on the pages,
    no two charts' texels are within the padding of each other, and every page texel is opaque."""
    _, _, impostor, field = house_tdm
    world = impostor.payload.triangle_corners()
    # The mesh again: a shared vertex has bit-identical world corners in all its triangles.
    unique, triangles = np.unique(world.reshape(-1, 3), axis=0, return_inverse=True)
    points = field.from_world(unique)
    points = np.rint(points * 64) / 64  # back on the exact voxel-space values (sixteenths, whole layers)
    charts = build_charts(points, triangles.reshape(-1, 3), TdmOptions().texel_margin)
    assert charts.count == impostor.stats["texture_charts"]
    masks = chart_masks(charts)
    assert sum(int(m.sum()) for m in masks) == charts.texel_chart.size
    assert impostor.stats["texture_bytes_tile_area"] == 4 * charts.texel_chart.size < 4 * charts.tile_texels
    layout = pack_masks(masks, TdmOptions().padding)
    assert [p.shape[:2] for p in impostor.pages] == [(h, w) for w, h in layout.page_sizes.tolist()]
    assert impostor.stats["texture_bytes"] == 4 * layout.page_area
    assert all(np.all(p[..., 3] == 255) for p in impostor.pages)
    assert_packed_apart(masks, layout, TdmOptions().padding)


def test_house_charts_hold_each_vertex_at_one_position_and_few_lone_triangles(house_tdm):
    """Rebuilt from the bake: a mesh vertex has one tile position in each chart it is in (the
    indexed GLB shares it), and lone triangles went into their neighbours' charts."""
    _, _, impostor, field = house_tdm
    world = impostor.payload.triangle_corners()
    unique, triangles = np.unique(world.reshape(-1, 3), axis=0, return_inverse=True)
    points = np.rint(field.from_world(unique) * 64) / 64
    triangles = triangles.reshape(-1, 3)
    charts = build_charts(points, triangles, TdmOptions().texel_margin)
    rows = np.column_stack([np.repeat(charts.chart, 3), triangles.reshape(-1), charts.position.reshape(-1, 2)])
    assert len(np.unique(rows, axis=0)) == len(np.unique(rows[:, :2], axis=0))
    lone = int((np.bincount(charts.chart) == 1).sum())
    # Measured at 128 px: 45 / 9 charts at 90 / 140 units (78 / 30 before lone triangles were
    # unfolded into their neighbours' charts).
    print(f"{charts.count} charts, {lone} of one triangle, for {len(triangles)} triangles")
    assert lone <= 0.1 * charts.count
    assert charts.count < 0.3 * len(triangles)


def assert_packed_apart(masks, layout, padding: int) -> None:
    """Every mask lies inside its page and no two masks' texels are within ``padding`` texels."""
    owner = [np.full(tuple(int(v) for v in size[::-1]), -1) for size in layout.page_sizes]
    for i, mask in enumerate(masks):
        r, c = np.nonzero(mask)
        page = owner[layout.page[i]]
        r, c = r + layout.y[i], c + layout.x[i]
        assert (
            r.min(initial=0) >= 0
            and c.min(initial=0) >= 0
            and r.max(initial=0) < page.shape[0]
            and c.max(initial=0) < page.shape[1]
        )
        assert np.all(page[r, c] == -1), f"mask {i} overlaps another"
        page[r, c] = i
    for page in owner:
        for dy in range(-padding, padding + 1):
            for dx in range(-padding, padding + 1):
                a = page[max(dy, 0) : page.shape[0] + min(dy, 0), max(dx, 0) : page.shape[1] + min(dx, 0)]
                b = page[max(-dy, 0) : page.shape[0] + min(-dy, 0), max(-dx, 0) : page.shape[1] + min(-dx, 0)]
                assert not np.any((a >= 0) & (b >= 0) & (a != b)), "two charts closer than the padding"


@pytest.mark.parametrize("padding", [0, 1, 2, 3])
def test_masks_pack_apart_and_tighter_than_their_rectangles(padding):
    """Random blobs and L shapes: placed inside their pages, ``padding`` apart, and (concave ones
    nesting) on less page area than their bounding rectangles grown by the padding."""
    rng = np.random.default_rng(padding)
    masks = []
    for _ in range(60):
        h, w = rng.integers(1, 24, size=2)
        ell = np.zeros((h, w), bool)
        ell[:, : max(1, w // 3)] = True
        ell[-max(1, h // 3) :, :] = True
        masks.append(ell if rng.random() < 0.5 else ell[::-1, ::-1])
    layout = pack_masks(masks, padding)
    assert_packed_apart(masks, layout, padding)
    rectangles = sum((m.shape[0] + padding) * (m.shape[1] + padding) for m in masks)
    print(f"padding {padding}: pages {layout.page_area} texels, rectangles {rectangles}")
    assert layout.page_area < rectangles


def _plain_first_fit(masks, padding, width, max_page):
    """The first fit :func:`farfield.core.techniques.tdm.mask_atlas.pack_masks` promises, written plainly (every position of
    every page in row-major order, a mask's texels against the blocked cells): (page, y, x) per mask."""
    shapes = np.array([m.shape for m in masks])
    order = np.lexsort((-np.array([m.sum() for m in masks]), -shapes[:, 0]))
    pages, placed = [], {}
    for i in order:
        mask = masks[i]
        rows, cols = np.nonzero(mask)
        h, w = mask.shape
        for index in range(len(pages) + 1):
            if index == len(pages):
                pages.append(np.zeros((max_page, width), bool))
            at = next(
                (
                    (y, x)
                    for y in range(max_page - h + 1)
                    for x in range(width - w + 1)
                    if not pages[index][y + rows, x + cols].any()
                ),
                None,
            )
            if at is not None:
                break
        y, x = at
        for r, c in zip(rows, cols):  # block the texel's (2 padding + 1)^2 square
            pages[index][
                max(y + r - padding, 0) : y + r + padding + 1, max(x + c - padding, 0) : x + c + padding + 1
            ] = True
        placed[int(i)] = (index, y, x)
    return [placed[i] for i in range(len(masks))]


@pytest.mark.parametrize("padding", [0, 2])
@pytest.mark.slow
def test_mask_packing_is_the_plain_first_fit(padding):
    """The packer's row skips, run tests and column jumps (``_first_fit``) and its searches resumed
    where the same mask went last change its speed, not its answer: on random blobs with holes, some of them
    repeated, at the width it keeps, every mask lies where the plain row-major first fit puts it."""
    rng = np.random.default_rng(7 + padding)
    masks = []
    for _ in range(80):
        h, w = rng.integers(1, 12, size=2)
        blob = rng.random((h, w)) < 0.7
        blob[0, rng.integers(w)] = blob[rng.integers(h), 0] = blob[-1, rng.integers(w)] = blob[rng.integers(h), -1] = (
            True
        )
        masks.append(blob)
    masks += [masks[i].copy() for i in rng.integers(0, 10, size=40)]  # repeats, across pages too
    masks += [np.ones((1, 1), bool), np.array([[False, True]])]  # one mask's last run ends where the next's starts
    layout = pack_masks(masks, padding, max_page=48)
    assert len(layout.page_sizes) > 1  # a page filled up: the search went through blocked rows
    width = int(layout.page_sizes[0, 0])
    got = list(zip(layout.page.tolist(), layout.y.tolist(), layout.x.tolist()))
    assert got == _plain_first_fit(masks, padding, width, 48)
    assert len(WIDTH_SCALES) > 1


@pytest.mark.parametrize("padding", [0, 2])
def test_many_pages_are_the_plain_first_fit_too(padding):
    """The pages' arrays grow as pages open (twice the room each time): 5 and 10 pages of small
    blobs, every mask where the plain first fit puts it."""
    rng = np.random.default_rng(3)
    masks = []
    for _ in range(150):
        h, w = rng.integers(1, 9, size=2)
        blob = rng.random((h, w)) < 0.7
        blob[0, rng.integers(w)] = blob[rng.integers(h), 0] = True
        masks.append(blob)
    layout = pack_masks(masks, padding, max_page=24)
    assert len(layout.page_sizes) >= 5
    got = list(zip(layout.page.tolist(), layout.y.tolist(), layout.x.tolist()))
    assert got == _plain_first_fit(masks, padding, int(layout.page_sizes[0, 0]), 24)


def test_wide_pages_skip_blocks_of_short_runs_and_stay_the_plain_first_fit():
    """Pages several :data:`BLOCK` columns wide, crossed by combs of short free runs (thin teeth
    with gaps from 1 to 9 texels) and by masks whose longest run (up to 40 texels) needs a long
    one: the search that passes a block of short runs at a time (``_long_enough``) puts every mask
    where the plain first fit does."""
    rng = np.random.default_rng(11)
    masks = []
    for _ in range(14):  # combs: tall, many teeth, gaps of random widths
        gaps = rng.integers(1, 10, size=rng.integers(3, 8))
        comb = np.zeros((int(rng.integers(6, 12)), int(gaps.sum() + len(gaps) + 1)), bool)
        comb[:, np.concatenate([[0], np.cumsum(gaps + 1)])] = True
        masks.append(comb)
    for _ in range(40):  # bars and blobs of every width, shorter than the combs
        h, w = int(rng.integers(1, 5)), int(rng.integers(1, 41))
        blob = rng.random((h, w)) < 0.8
        blob[0, :] = True  # a run as wide as the mask
        masks.append(blob)
    layout = pack_masks(masks, 1, max_page=96)
    width = int(layout.page_sizes[0, 0])
    assert width > 2 * BLOCK
    got = list(zip(layout.page.tolist(), layout.y.tolist(), layout.x.tolist()))
    assert got == _plain_first_fit(masks, 1, width, 96)


def test_masks_that_fill_a_page_open_another_and_oversized_ones_are_refused():
    layout = pack_masks([np.ones((30, 30), bool)] * 5, padding=2, max_page=64)
    assert layout.page.tolist() == [0, 0, 0, 0, 1] and layout.page_sizes.tolist() == [[64, 64], [64, 32]]
    with pytest.raises(AtlasOverflowError, match="does not fit a page of at most 64x64"):
        pack_masks([np.ones((65, 3), bool)], padding=0, max_page=64)
    with pytest.raises(LayerPlanError, match="padding"):
        pack_masks([np.ones((2, 2), bool)], padding=-1)
    assert pack_masks([], 2).page_area == 0


def test_house_tiles_are_smaller_and_the_colours_as_good(house_tdm):
    scene, cell, impostor, field = house_tdm
    margin = TdmOptions().texel_margin
    world = impostor.payload.triangle_corners()
    tiles, chart, sizes = per_triangle_tiles(field, world, margin)
    pages, corner_uv, tile_page, old_bytes = pack_tiles(tiles, TdmOptions().padding)
    per_triangle = MeshPayload.from_triangle_corners(
        world, tile_corner_uvs(chart, sizes, corner_uv), page=tile_page, mesh=impostor.payload.mesh
    )
    old = dataclasses.replace(impostor, payload=per_triangle, pages=pages)
    old_pages = sum(p.nbytes for p in pages)
    new_bytes, new_pages = impostor.stats["texture_bytes_tile_area"], impostor.stats["texture_bytes"]
    # Measured at 90 / 140 units: tiles per triangle 48,656 / 18,816 bytes on pages of 131,072 / 41,728;
    # shared charts 17,504 / 6,428 bytes of needed texels on pages of 28,288 / 12,288.
    print(
        f"bytes per triangle: {old_bytes} of tiles on {old_pages} of pages; shared charts: {new_bytes} needed on {new_pages} of pages"
    )
    assert new_bytes < 0.75 * old_bytes
    assert new_pages < 0.75 * old_pages
    assert impostor.stats["geometry_bytes"] < impostor.stats["triangles"] * 72  # 72: unshared vertices
    ev_new = evaluate(scene, impostor, cell, random_count=4, seed=3).totals
    ev_old = evaluate(scene, old, cell, random_count=4, seed=3).totals
    assert ev_new["hole_pixels"] == ev_old["hole_pixels"] == 0
    # Measured at 90 / 140 units: 6.00 / 9.38 per triangle, 4.89 / 9.98 shared.  These are means
    # over 13 views of a few hundred pixels each, with one voxel per texel: moving the texel grid by
    # half a voxel alone moves the 140-unit value between 9.5 and 10.7, and with 4 voxels averaged
    # per texel the two layouts agree (10.37 / 10.40).
    print(f"colour error: {ev_old['colour_error_mean']:.3f} per triangle, {ev_new['colour_error_mean']:.3f} shared")
    assert ev_new["colour_error_mean"] <= 1.1 * ev_old["colour_error_mean"]
