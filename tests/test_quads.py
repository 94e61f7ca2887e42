"""Layer quads (seed 000 §3.5): every covered texel is covered, quads are disjoint, grid-aligned, and honour the fill threshold."""

from __future__ import annotations

import time

import numpy as np
import pytest

from farfield.core.errors import LayerPlanError
from farfield.core.layering.quads import filled_cells, full_quad, grow_quads, quads_for_layers, rect_areas, single_quad


def blobs(h: int, w: int, n: int, seed: int) -> np.ndarray:
    """(h, w) bool union of ``n`` random ellipses, radii 2..h/10 texels."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:h, :w]
    cov = np.zeros((h, w), dtype=bool)
    rmax = max(3.0, min(h, w) / 10)
    for _ in range(n):
        cy, cx = rng.uniform(0, h), rng.uniform(0, w)
        ry, rx = rng.uniform(2, rmax, 2)
        cov |= ((yy - cy) / ry) ** 2 + ((xx - cx) / rx) ** 2 < 1.0
    return cov


def noise(h: int, w: int, density: float, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).random((h, w)) < density


def lines(h: int, w: int) -> np.ndarray:
    """One-texel-thin diagonal, horizontal and vertical lines."""
    cov = np.zeros((h, w), dtype=bool)
    d = np.arange(min(h, w))
    cov[d, d] = True
    cov[h // 3, :] = True
    cov[:, (2 * w) // 3] = True
    return cov


COVERAGES = {
    "empty": lambda: np.zeros((40, 56), dtype=bool),
    "full": lambda: np.ones((40, 56), dtype=bool),
    "one_true": lambda: np.ones((1, 1), dtype=bool),
    "one_false": lambda: np.zeros((1, 1), dtype=bool),
    "single_texel": lambda: np.pad(np.ones((1, 1), dtype=bool), ((17, 5), (3, 29))),
    "corner_texel": lambda: np.pad(np.ones((1, 1), dtype=bool), ((36, 0), (52, 0))),
    "noise_sparse": lambda: noise(64, 64, 0.02, 1),
    "noise_dense": lambda: noise(50, 70, 0.5, 2),
    "noise_odd": lambda: noise(37, 53, 0.1, 3),
    "blobs": lambda: blobs(128, 128, 12, 4),
    "blobs_odd": lambda: blobs(101, 77, 8, 5),
    "lines": lambda: lines(61, 45),
    "thin_row": lambda: np.ones((1, 83), dtype=bool),
    "thin_col": lambda: np.ones((83, 1), dtype=bool),
}


def check_quads(cov: np.ndarray, rects: np.ndarray, cell: int, threshold: float) -> None:
    """Assert every guarantee of :func:`grow_quads` for one result."""
    h, w = cov.shape
    assert rects.dtype == np.int64 and rects.ndim == 2 and rects.shape[1] == 4
    x0, y0, x1, y1 = rects.T
    # Inside the image, non-empty.
    assert np.all((0 <= x0) & (x0 < x1) & (x1 <= w)), rects
    assert np.all((0 <= y0) & (y0 < y1) & (y1 <= h)), rects
    # Aligned to the cell grid, except where clipped at the image border.
    assert np.all(x0 % cell == 0) and np.all(y0 % cell == 0)
    assert np.all((x1 % cell == 0) | (x1 == w)) and np.all((y1 % cell == 0) | (y1 == h))
    # Disjoint (in texels, hence in grid cells since aligned) and covering every covered texel.
    count = np.zeros((h, w), dtype=np.int64)
    for a, b, c, d in rects:
        count[b:d, a:c] += 1
    assert count.max(initial=0) <= 1, "quads overlap"
    assert not np.any(cov & (count == 0)), f"{int(np.sum(cov & (count == 0)))} covered texels outside every quad"
    # Fill ratio of every quad, in grid cells, is at least the threshold; every quad holds content.
    filled = filled_cells(cov, cell)
    for a, b, c, d in rects:
        sub = filled[b // cell : -(-d // cell), a // cell : -(-c // cell)]
        assert sub.any()
        assert sub.mean() >= threshold - 1e-12, (sub.mean(), threshold)
    # Never outside the cell-aligned bounding box of the content.
    if rects.size:
        ((bx0, by0, bx1, by1),) = single_quad(cov)
        assert x0.min() >= bx0 // cell * cell and y0.min() >= by0 // cell * cell
        assert x1.max() <= min(w, -(-bx1 // cell) * cell) and y1.max() <= min(h, -(-by1 // cell) * cell)


@pytest.mark.parametrize("threshold", [0.3, 0.8, 1.0])
@pytest.mark.parametrize("cell", [1, 3, 8, 16])
@pytest.mark.parametrize("name", sorted(COVERAGES))
def test_quads_cover_every_texel(name, cell, threshold):
    cov = COVERAGES[name]()
    rects = grow_quads(cov, cell, threshold)
    check_quads(cov, rects, cell, threshold)
    if not cov.any():
        assert rects.shape == (0, 4)


@pytest.mark.parametrize("seed", range(6))
def test_random_blobs_at_default_parameters(seed):
    cov = blobs(256, 192, 20, seed)
    check_quads(cov, grow_quads(cov), 8, 0.8)


@pytest.mark.parametrize("name", ["blobs", "blobs_odd", "noise_dense", "lines"])
@pytest.mark.parametrize("cell", [2, 4, 8])
def test_threshold_one_keeps_only_filled_cells(name, cell):
    cov = COVERAGES[name]()
    rects = grow_quads(cov, cell, 1.0)
    filled = filled_cells(cov, cell)
    covered = np.zeros_like(filled)
    for a, b, c, d in rects:
        cells = filled[b // cell : -(-d // cell), a // cell : -(-c // cell)]
        assert cells.all()
        covered[b // cell : -(-d // cell), a // cell : -(-c // cell)] = True
    assert np.array_equal(covered, filled)  # exactly the filled cells, no waste


def test_lower_threshold_never_gives_more_quads_on_blob_set():
    # The greedy is not monotone layer by layer (a different early choice can split a later
    # region: seed 104 gives 11 quads at 0.6 but 10 at 0.7), so the documented behaviour is tested
    # on a fixed set of layers: in total, a lower threshold gives fewer quads and more texels, the
    # trade-off of seed 000 §3.5; per layer, the extremes of the range are ordered.
    thresholds = [0.2, 0.4, 0.6, 0.7, 0.8, 0.9, 1.0]
    counts = np.zeros(len(thresholds), dtype=np.int64)
    areas = np.zeros(len(thresholds), dtype=np.int64)
    for seed in range(8):
        cov = blobs(192, 192, 15, 100 + seed)
        results = [grow_quads(cov, 8, t) for t in thresholds]
        c = [len(r) for r in results]
        a = [int(rect_areas(r).sum()) for r in results]
        assert c[0] <= c[-1] and a[0] >= a[-1], (seed, c, a)
        counts += c
        areas += a
    assert np.all(np.diff(counts) >= 0), counts
    assert np.all(np.diff(areas) <= 0), areas
    assert counts[0] < counts[-1] and areas[0] > areas[-1]


def test_smaller_cells_waste_fewer_texels_but_need_more_quads():
    # Seed 000 Table 3.1's trend, in total over a set of layers (single layers can deviate by a
    # quad between neighbouring cell sizes).
    cells = [1, 2, 4, 8, 16, 32, 64]
    counts = np.zeros(len(cells), dtype=np.int64)
    areas = np.zeros(len(cells), dtype=np.int64)
    for seed in range(4):
        cov = blobs(256, 256, 20, 7 + seed)
        results = [grow_quads(cov, c, 0.8) for c in cells]
        counts += [len(r) for r in results]
        areas += [int(rect_areas(r).sum()) for r in results]
        assert int(rect_areas(results[-1]).sum()) <= int(rect_areas(full_quad(256, 256)).sum())
        assert int(rect_areas(results[0]).sum()) <= int(rect_areas(single_quad(cov)).sum())
    assert np.all(np.diff(counts) <= 0), counts
    assert np.all(np.diff(areas) >= 0), areas


@pytest.mark.parametrize("shape", [(8, 8), (37, 53), (64, 20)])
@pytest.mark.parametrize("name", ["noise", "blob", "texel"])
def test_cell_as_large_as_image_gives_one_full_quad(shape, name):
    h, w = shape
    cov = {"noise": noise(h, w, 0.05, 9), "blob": blobs(h, w, 2, 9), "texel": np.zeros((h, w), bool)}[name]
    cov[h // 2, w // 3] = True
    for cell in (max(h, w), 10 * max(h, w)):
        assert grow_quads(cov, cell).tolist() == full_quad(h, w).tolist()
    assert grow_quads(np.zeros((h, w), bool), max(h, w)).shape == (0, 4)


def test_separate_squares_at_threshold_one_give_one_quad_each():
    cov = np.zeros((64, 64), dtype=bool)
    cov[0:16, 8:24] = True
    cov[32:40, 40:64] = True
    assert grow_quads(cov, 8, 1.0).tolist() == [[8, 0, 24, 16], [40, 32, 64, 40]]


def test_deterministic_and_accepts_alpha_channel():
    cov = blobs(128, 96, 10, 11)
    alpha = np.where(cov, 255, 0).astype(np.uint8)
    a = grow_quads(cov, 4, 0.7)
    assert np.array_equal(a, grow_quads(cov, 4, 0.7))
    assert np.array_equal(a, grow_quads(alpha, 4, 0.7))


def test_quads_for_layers_matches_per_layer():
    stack = np.stack([blobs(64, 80, 5, s) for s in range(4)] + [np.zeros((64, 80), bool)])
    out = quads_for_layers(stack, 4, 0.9)
    assert len(out) == 5
    for layer, rects in zip(stack, out):
        assert np.array_equal(rects, grow_quads(layer, 4, 0.9))
    assert out[-1].shape == (0, 4)


@pytest.mark.parametrize("name", sorted(COVERAGES))
def test_single_quad_is_the_tight_bounding_rect(name):
    cov = COVERAGES[name]()
    rects = single_quad(cov)
    if not cov.any():
        assert rects.shape == (0, 4)
        return
    check_quads(cov, rects, 1, 0.0)
    ((x0, y0, x1, y1),) = rects
    assert cov[y0].any() and cov[y1 - 1].any() and cov[:, x0].any() and cov[:, x1 - 1].any()


def test_full_quad_and_areas():
    assert full_quad(7, 9).tolist() == [[0, 0, 9, 7]]
    assert rect_areas(full_quad(7, 9)).tolist() == [63]
    assert rect_areas(np.zeros((0, 4), dtype=np.int64)).shape == (0,)
    with pytest.raises(LayerPlanError, match="-1"):
        full_quad(-1, 3)


@pytest.mark.parametrize("cell", [0, -8, 2.5, True, "8"])
def test_bad_cell_is_refused(cell):
    with pytest.raises(LayerPlanError, match=repr(cell).replace(".", r"\.")):
        grow_quads(np.ones((4, 4), bool), cell)


@pytest.mark.parametrize("threshold", [0.0, -0.5, 1.01, float("nan"), float("inf")])
def test_bad_threshold_is_refused(threshold):
    with pytest.raises(LayerPlanError, match="fill threshold"):
        grow_quads(np.ones((4, 4), bool), 2, threshold)


def test_bad_coverage_shape_is_refused():
    with pytest.raises(LayerPlanError, match=r"\(2, 4, 4\)"):
        grow_quads(np.ones((2, 4, 4), bool))
    with pytest.raises(LayerPlanError, match=r"\(4, 4\)"):
        quads_for_layers(np.ones((4, 4), bool))


def test_speed_512():
    """A blobby 512 x 512 layer at cell 8 (64 x 64 grid): < 10 ms typical; the bound leaves CI slack."""
    cov = blobs(512, 512, 40, 21)
    grow_quads(cov, 8, 0.8)  # warm
    times = []
    for _ in range(5):
        t = time.perf_counter()
        rects = grow_quads(cov, 8, 0.8)
        times.append(time.perf_counter() - t)
    check_quads(cov, rects, 8, 0.8)
    assert min(times) < 0.05, f"grow_quads took {min(times) * 1e3:.1f} ms"
