"""Texture atlases (seed 000 §3.6): tiles packed without overlap onto power-of-two pages, painted back exactly."""

from __future__ import annotations

import numpy as np
import pytest

from farfield.core.errors import AtlasOverflowError, LayerPlanError
from farfield.core.layering.atlas import AtlasLayout, bleed_rgb, compose, pack, tile_uv, tile_uvs
from farfield.core.layering.quads import grow_quads


def random_sizes(n: int, seed: int, low: int = 1, high: int = 90) -> np.ndarray:
    return np.random.default_rng(seed).integers(low, high, (n, 2))


def random_tiles(sizes: np.ndarray, seed: int, transparent: float = 0.3) -> list[np.ndarray]:
    """RGBA tiles with random colours, a share of them with alpha 0."""
    rng = np.random.default_rng(seed)
    tiles = []
    for w, h in sizes:
        t = rng.integers(0, 256, (h, w, 4), dtype=np.uint8)
        t[..., 3] = np.where(rng.random((h, w)) < transparent, 0, rng.integers(1, 256, (h, w)))
        tiles.append(t)
    return tiles


def quad_sizes(layers: int, seed: int, cell: int = 8) -> np.ndarray:
    """(n, 2) [w, h] of the quads of ``layers`` blobby 512 x 512 layers: a realistic atlas load."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:512, :512]
    sizes = []
    for _ in range(layers):
        cov = np.zeros((512, 512), dtype=bool)
        for _ in range(25):
            cy, cx = rng.uniform(0, 512, 2)
            ry, rx = rng.uniform(4, 50, 2)
            cov |= ((yy - cy) / ry) ** 2 + ((xx - cx) / rx) ** 2 < 1.0
        r = grow_quads(cov, cell, 0.8)
        sizes.append(r[:, 2:] - r[:, :2])
    return np.concatenate(sizes)


SIZE_SETS = {
    "one": lambda: np.array([[5, 3]]),
    "one_texel": lambda: np.array([[1, 1]]),
    "equal": lambda: np.full((40, 2), 16),
    "wide_and_tall": lambda: np.array([[100, 2], [2, 100], [50, 50], [1, 64], [64, 1]]),
    "random_small": lambda: random_sizes(60, 1),
    "random_mixed": lambda: random_sizes(200, 2, 1, 300),
    "quads": lambda: quad_sizes(3, 3),
}


def check_layout(layout: AtlasLayout, sizes: np.ndarray, padding: int, max_page: int) -> None:
    """Assert every placement guarantee of :func:`pack`."""
    n = len(sizes)
    assert layout.page.shape == layout.x.shape == layout.y.shape == layout.rotated.shape == (n,)
    assert np.array_equal(layout.sizes, sizes)
    assert np.array_equal(layout.rotated, sizes[:, 0] > sizes[:, 1])  # larger side vertical
    p = len(layout.page_sizes)
    assert np.all((layout.page >= 0) & (layout.page < p))
    assert set(layout.page.tolist()) == set(range(p))  # no empty page
    ps = layout.page_sizes
    assert np.all((ps >= 1) & (ps <= max_page) & ((ps & (ps - 1)) == 0)), ps  # powers of two
    ws, hs = layout.stored_sizes.T
    assert np.all(hs >= ws)
    # The padded tile lies inside its page ...
    x0, y0 = layout.x - padding, layout.y - padding
    x1, y1 = layout.x + ws + padding, layout.y + hs + padding
    W, H = ps[layout.page].T
    assert np.all((x0 >= 0) & (y0 >= 0) & (x1 <= W) & (y1 <= H))
    # ... and overlaps no other padded tile.
    for k in range(p):
        count = np.zeros((ps[k, 1], ps[k, 0]), dtype=np.int32)
        for i in np.flatnonzero(layout.page == k):
            count[y0[i] : y1[i], x0[i] : x1[i]] += 1
        assert count.max() <= 1, f"padded tiles overlap on page {k}"


def sample_through_uvs(page: np.ndarray, uv: np.ndarray, h: int, w: int) -> np.ndarray:
    """(h, w, 4) texels of ``page`` at the centres of an original h x w tile mapped by its corner UVs."""
    H, W = page.shape[:2]
    tl, tr, _, bl = uv * [W, H]
    u = (np.arange(w) + 0.5) / w
    v = (np.arange(h) + 0.5) / h
    pts = tl + (tr - tl) * u[None, :, None] + (bl - tl) * v[:, None, None]  # (h, w, 2) page pixels
    return page[np.floor(pts[..., 1]).astype(int), np.floor(pts[..., 0]).astype(int)]


@pytest.mark.parametrize("padding", [0, 1, 2, 4])
@pytest.mark.parametrize("name", sorted(SIZE_SETS))
def test_pack_places_every_tile_without_overlap(name, padding):
    sizes = SIZE_SETS[name]()
    layout = pack(sizes, padding)
    check_layout(layout, sizes, padding, 8192)


@pytest.mark.parametrize("max_page", [64, 128, 256])
def test_small_pages_spill_onto_more_pages(max_page):
    sizes = random_sizes(150, 5, 1, 60)
    layout = pack(sizes, 2, max_page)
    check_layout(layout, sizes, 2, max_page)
    assert len(layout.page_sizes) > 1


def test_sort_order_and_first_page_follow_the_thesis():
    # Heights 8 (padded 10 -> page height 16) then 4; total padded area 2*10*6 + 6*6 = 156 -> 156/16 -> 16.
    layout = pack([[4, 4], [4, 8], [8, 4]], padding=1, min_fill=0.0)
    assert layout.page_sizes.tolist() == [[16, 16]]
    assert layout.rotated.tolist() == [False, False, True]
    # Decreasing height, equal tiles in input order, each at the lowest (here: top-most) free spot.
    assert layout.x.tolist() == [1, 1, 7] and layout.y.tolist() == [11, 1, 1]


@pytest.mark.parametrize("padding", [0, 2])
@pytest.mark.parametrize("name", ["wide_and_tall", "random_small", "quads"])
def test_compose_paints_every_tile_where_its_uvs_say(name, padding):
    sizes = SIZE_SETS[name]()
    tiles = random_tiles(sizes, 7)
    layout = pack(sizes, padding)
    pages = compose(layout, tiles, padding, bleed=0)
    uvs = tile_uvs(layout)
    assert uvs.shape == (len(sizes), 4, 2) and uvs.dtype == np.float64
    for i, tile in enumerate(tiles):
        uv = tile_uv(layout, i)
        assert np.array_equal(uv, uvs[i])
        page = pages[layout.page[i]]
        px = uv * page.shape[1::-1]
        assert np.array_equal(px, np.round(px))  # on texel edges
        assert np.array_equal(sample_through_uvs(page, uv, *tile.shape[:2]), tile)


@pytest.mark.parametrize("padding", [0, 3])
def test_rotation_is_clockwise_at_the_interior_top_left(padding):
    sizes = np.array([[7, 3], [3, 7], [5, 5]])
    tiles = random_tiles(sizes, 8, transparent=0.0)
    layout = pack(sizes, padding)
    pages = compose(layout, tiles, bleed=0)
    for i, tile in enumerate(tiles):
        stored = np.rot90(tile, k=-1) if layout.rotated[i] else tile
        h, w = stored.shape[:2]
        x, y = layout.x[i], layout.y[i]
        assert np.array_equal(pages[layout.page[i]][y : y + h, x : x + w], stored)
    # The wide tile is rotated: its original top-left texel is at the stored top-right.
    assert layout.rotated.tolist() == [True, False, False]
    x, y = layout.x[0], layout.y[0]
    assert np.array_equal(pages[layout.page[0]][y, x + 2], tiles[0][0, 0])
    W, H = layout.page_sizes[layout.page[0]]
    assert tile_uv(layout, 0).tolist() == [
        [(x + 3) / W, y / H],
        [(x + 3) / W, (y + 7) / H],
        [x / W, (y + 7) / H],
        [x / W, y / H],
    ]


@pytest.mark.parametrize("bleed", [0, 4])
@pytest.mark.parametrize("padding", [1, 2, 5])
def test_padding_replicates_border_and_nothing_else_is_painted(padding, bleed):
    sizes = random_sizes(50, 9, 1, 40)
    tiles = random_tiles(sizes, 10)
    layout = pack(sizes, padding)
    pages = compose(layout, tiles, bleed=bleed)
    painted = [np.zeros(pg.shape[:2], dtype=bool) for pg in pages]
    ws, hs = layout.stored_sizes.T
    for i in range(len(tiles)):
        x, y, p = layout.x[i], layout.y[i], padding
        page = pages[layout.page[i]]
        block = page[y - p : y + hs[i] + p, x - p : x + ws[i] + p]
        interior = page[y : y + hs[i], x : x + ws[i]]
        assert np.array_equal(block, np.pad(interior, ((p, p), (p, p), (0, 0)), mode="edge"))
        painted[layout.page[i]][y - p : y + hs[i] + p, x - p : x + ws[i] + p] = True
    for page, mask in zip(pages, painted):
        assert not page[~mask].any()  # (0, 0, 0, 0) outside every padded tile


def test_bleed_keeps_opaque_texels_and_alpha_and_colours_transparent_neighbours():
    sizes = random_sizes(40, 11, 2, 30)
    tiles = random_tiles(sizes, 12, transparent=0.6)
    layout = pack(sizes, 2)
    pages = compose(layout, tiles)  # default bleed
    for i, tile in enumerate(tiles):
        got = sample_through_uvs(pages[layout.page[i]], tile_uv(layout, i), *tile.shape[:2])
        assert np.array_equal(got[..., 3], tile[..., 3])
        opaque = tile[..., 3] > 0
        assert np.array_equal(got[opaque], tile[opaque])

    # One opaque texel in a transparent black tile: its colour spreads `bleed` texels, alpha stays 0.
    tile = np.zeros((11, 11, 4), dtype=np.uint8)
    tile[5, 5] = (200, 40, 90, 255)
    for bleed in (1, 3):
        out = bleed_rgb(tile, bleed)
        yy, xx = np.mgrid[:11, :11]
        near = np.maximum(abs(yy - 5), abs(xx - 5)) <= bleed
        assert np.all(out[near][:, :3] == (200, 40, 90))
        assert not out[~near].any()
        assert np.array_equal(out[..., 3], tile[..., 3])


def test_bleed_is_alpha_weighted_mean():
    tile = np.zeros((1, 3, 4), dtype=np.uint8)
    tile[0, 0] = (255, 0, 0, 255)
    tile[0, 2] = (0, 0, 255, 85)
    out = bleed_rgb(tile, 1)
    assert out[0, 1].tolist() == [191, 0, 64, 0]  # (255*255, 0, 255*85) / 340, rounded


def test_compose_is_deterministic():
    sizes = SIZE_SETS["quads"]()
    tiles = random_tiles(sizes, 13)
    a = compose(pack(sizes), tiles)
    b = compose(pack(sizes), [t.copy() for t in tiles])
    assert len(a) == len(b)
    assert all(x.tobytes() == y.tobytes() for x, y in zip(a, b))
    assert all(x.dtype == np.uint8 and x.shape[2] == 4 for x in a)


def test_realistic_overhead_is_reasonable():
    """Page texels over tile texels for a few hundred quads of blobby layers (seed 000 Fig. 3.17 reports
    5-25 % for large databases; power-of-two pages cost more on small sets)."""
    sizes = quad_sizes(12, 14)
    assert 250 <= len(sizes) <= 600
    layout = pack(sizes, 2)
    check_layout(layout, sizes, 2, 8192)
    padded = int(np.prod(sizes + 4, axis=1).sum())
    assert layout.page_area <= 2 * layout.tile_area, (layout.page_area / layout.tile_area, layout.page_sizes)
    assert layout.page_area <= 1.5 * padded, (layout.page_area / padded, layout.page_sizes)


@pytest.mark.parametrize("seed", range(3))
def test_spilling_beats_a_half_empty_page(seed):
    # 338-369 quads whose padded area just exceeds half of the thesis's 8192 x 256 page.
    sizes = quad_sizes(12, seed)
    thesis = pack(sizes, 2, min_fill=0.0)
    spilled = pack(sizes, 2)
    check_layout(thesis, sizes, 2, 8192)
    check_layout(spilled, sizes, 2, 8192)
    assert len(thesis.page_sizes) == 1 and thesis.page_area > 2 * thesis.tile_area
    assert spilled.page_area <= 1.4 * spilled.tile_area
    # Every page but the last ones is at least min_fill full of padded tiles.
    first = spilled.page == 0
    assert np.prod(sizes[first] + 4, axis=1).sum() >= 0.75 * np.prod(spilled.page_sizes[0])


def test_spilled_pages_compose_exactly():
    sizes = quad_sizes(4, 15)
    tiles = random_tiles(sizes, 16)
    layout = pack(sizes, 2, min_fill=1.0)
    assert len(layout.page_sizes) > 1
    pages = compose(layout, tiles, bleed=0)
    for i, tile in enumerate(tiles):
        assert np.array_equal(sample_through_uvs(pages[layout.page[i]], tile_uv(layout, i), *tile.shape[:2]), tile)


@pytest.mark.parametrize("min_fill", [-0.1, 1.5, float("nan")])
def test_bad_min_fill_is_refused(min_fill):
    with pytest.raises(LayerPlanError, match="min_fill"):
        pack([[4, 4]], min_fill=min_fill)


@pytest.mark.parametrize(("size", "padding"), [([9000, 10], 0), ([10, 8193], 0), ([8192, 8], 1), ([8189, 8189], 2)])
def test_tile_larger_than_a_page_overflows(size, padding):
    with pytest.raises(AtlasOverflowError, match=f"{size[0]}x{size[1]}"):
        pack([[3, 3], size], padding)


def test_tile_as_large_as_a_page_fits():
    layout = pack([[8192, 8]], 0, max_page=8192)
    assert layout.page_sizes.tolist() == [[8, 8192]] and layout.rotated.tolist() == [True]
    with pytest.raises(AtlasOverflowError, match="4096"):  # the portable default refuses it
        pack([[8192, 8]], 0)
    assert pack([[60, 60]], 2, max_page=64).page_sizes.tolist() == [[64, 64]]


def test_empty_input():
    layout = pack(np.zeros((0, 2), dtype=np.int64))
    assert layout.page_sizes.shape == (0, 2) and layout.page.shape == (0,)
    assert compose(layout, []) == ()
    assert tile_uvs(layout).shape == (0, 4, 2)


@pytest.mark.parametrize("sizes", [[[0, 4]], [[4, -1]], [[2.5, 4]], [[1, 2, 3]], [1, 2], [["a", "b"]]])
def test_bad_sizes_are_refused(sizes):
    with pytest.raises(LayerPlanError, match="tile sizes"):
        pack(sizes)


@pytest.mark.parametrize(("padding", "max_page"), [(-1, 8192), (1.5, 8192), (2, 1000), (2, 0)])
def test_bad_parameters_are_refused(padding, max_page):
    with pytest.raises(LayerPlanError, match=repr(padding) if padding in (-1, 1.5) else str(max_page)):
        pack([[4, 4]], padding, max_page)


def test_compose_refuses_mismatched_tiles():
    layout = pack([[4, 3], [2, 2]], 1)
    good = [np.zeros((3, 4, 4), np.uint8), np.zeros((2, 2, 4), np.uint8)]
    compose(layout, good)
    with pytest.raises(LayerPlanError, match="2 tiles"):
        compose(layout, good[:1])
    with pytest.raises(LayerPlanError, match=r"\(4, 3, 4\)"):
        compose(layout, [np.zeros((4, 3, 4), np.uint8), good[1]])
    with pytest.raises(LayerPlanError, match="float32"):
        compose(layout, [good[0].astype(np.float32), good[1]])
    with pytest.raises(LayerPlanError, match="padding 2"):
        compose(layout, good, padding=2)
