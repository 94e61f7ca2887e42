"""The sampling geometry of point-based impostors (seed 001 §3, §5.1): each piece against a brute force.

The plane, polygon, triangle and resolution factors are pure numbers; every check here computes the
same quantity another way (dense sampling, exhaustive search, the circle's closed form) and would
fail if the construction broke.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import ConvexHull, Delaunay

from farfield.core.errors import ViewCellError
from farfield.core.techniques.points.sampling import (
    farthest_from_cameras,
    ldi_resolution,
    min_perimeter_triangle,
    movement_factor,
    plan_point_sampling,
)
from farfield.core.viewcells import BoxCell


def _perimeter(t: np.ndarray) -> float:
    return float(np.sum(np.linalg.norm(t - np.roll(t, -1, axis=0), axis=1)))


def _random_polygon(rng: np.random.Generator, count: int) -> np.ndarray:
    points = rng.normal(size=(count, 2)) * rng.uniform(0.2, 3.0, 2)
    return points[ConvexHull(points).vertices]


def _inside(triangle: np.ndarray, points: np.ndarray, tol: float) -> bool:
    """All ``points`` inside the counter-clockwise ``triangle`` up to ``tol``."""
    for i in range(3):
        a, b = triangle[i], triangle[(i + 1) % 3]
        edge = (b - a) / np.linalg.norm(b - a)
        if np.any(edge[0] * (points[:, 1] - a[1]) - edge[1] * (points[:, 0] - a[0]) < -tol):
            return False
    return True


def test_least_perimeter_triangle_of_a_circle_is_equilateral():
    angles = np.linspace(0.0, 2.0 * math.pi, 256, endpoint=False)
    circle = 2.0 * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    t = min_perimeter_triangle(circle)
    sides = np.linalg.norm(t - np.roll(t, -1, axis=0), axis=1)
    # 6√3 r for the circle; the 256-gon is a hair smaller.
    assert _perimeter(t) == pytest.approx(6.0 * math.sqrt(3.0) * 2.0, rel=2e-4)
    assert np.ptp(sides) < 0.01 * sides.mean()  # the perimeter is flat near its minimum


def _exhaustive_perimeter(polygon: np.ndarray, step_deg: float) -> float:
    """The least perimeter of the triangles bounded by three supporting lines of ``polygon`` whose
    outward normals lie on a ``step_deg`` grid (every triple, written out independently of
    :func:`min_perimeter_triangle`)."""
    grid = np.radians(np.arange(0.0, 360.0, step_deg))
    a, b, c = (x.ravel() for x in np.meshgrid(grid, grid, grid, indexing="ij"))
    gap = math.pi - 1e-9
    ok = (a < math.radians(120.0)) & (a < b) & (b < c) & (b - a < gap) & (c - b < gap) & (a + 2.0 * math.pi - c < gap)
    angles = np.stack([a[ok], b[ok], c[ok]], axis=1)  # (m, 3)
    normals = np.stack([np.cos(angles), np.sin(angles)], axis=-1)  # (m, 3, 2)
    h = np.max(normals @ polygon.T, axis=-1)  # (m, 3) support values
    vertices = []
    for i in range(3):  # the corner where line i meets line i+1 (Cramer's rule)
        j = (i + 1) % 3
        n1, n2, h1, h2 = normals[:, i], normals[:, j], h[:, i], h[:, j]
        det = n1[:, 0] * n2[:, 1] - n1[:, 1] * n2[:, 0]
        vertices.append(
            np.stack([(h1 * n2[:, 1] - h2 * n1[:, 1]) / det, (n1[:, 0] * h2 - n2[:, 0] * h1) / det], axis=1)
        )
    v = np.stack(vertices, axis=1)
    return float(np.min(np.sum(np.linalg.norm(v - np.roll(v, -1, axis=1), axis=2), axis=1)))


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.slow
def test_least_perimeter_triangle_encloses_touches_and_beats_an_exhaustive_search(seed):
    rng = np.random.default_rng(seed)
    polygon = _random_polygon(rng, int(rng.integers(3, 12)))
    t = min_perimeter_triangle(polygon)
    scale = float(np.ptp(polygon, axis=0).max())
    assert _inside(t, polygon, 1e-9 * scale)
    for i in range(3):  # every side touches the polygon
        a, b = t[i], t[(i + 1) % 3]
        edge = (b - a) / np.linalg.norm(b - a)
        gaps = edge[0] * (polygon[:, 1] - a[1]) - edge[1] * (polygon[:, 0] - a[0])
        assert gaps.min() < 1e-7 * scale
    best = _exhaustive_perimeter(polygon, 2.0)
    assert _perimeter(t) <= best * (1.0 + 1e-9)
    assert _perimeter(t) >= best * 0.97  # and the grid comes close: the search is not fooling itself


def _sample_polygon(rng: np.random.Generator, polygon: np.ndarray, count: int) -> np.ndarray:
    """Points inside the convex ``polygon`` and on its boundary."""
    fan = Delaunay(polygon)
    lo, hi = polygon.min(axis=0), polygon.max(axis=0)
    inner = rng.uniform(lo, hi, (count, 2))
    inner = inner[fan.find_simplex(inner) >= 0]
    t = rng.uniform(0.0, 1.0, count)
    k = rng.integers(0, len(polygon), count)
    edge = polygon[k] + t[:, None] * (np.roll(polygon, -1, axis=0)[k] - polygon[k])
    return np.concatenate([inner, edge, polygon])


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.slow
def test_farthest_point_from_the_cameras_matches_dense_sampling(seed):
    rng = np.random.default_rng(10 + seed)
    polygon = _random_polygon(rng, 9)
    cameras = min_perimeter_triangle(polygon) if seed % 2 == 0 else rng.normal(size=(3, 2)) * 3.0
    samples = _sample_polygon(rng, polygon, 200_000)
    nearest = np.min(np.linalg.norm(samples[:, None, :] - cameras[None], axis=2), axis=1)
    on_edges = samples[len(samples) - len(polygon) - 200_000 : len(samples) - len(polygon)]
    edge_nearest = np.min(np.linalg.norm(on_edges[:, None, :] - cameras[None], axis=2), axis=1)
    reach, where = farthest_from_cameras(polygon, cameras)
    boundary, _ = farthest_from_cameras(polygon, cameras, boundary=True)
    scale = float(np.ptp(polygon, axis=0).max())
    assert nearest.max() <= reach + 1e-9 * scale and reach - nearest.max() < 0.01 * scale
    assert np.min(np.linalg.norm(where - cameras, axis=1)) == pytest.approx(reach)
    assert (
        max(edge_nearest.max(), np.min(np.linalg.norm(polygon[:, None] - cameras[None], axis=2), axis=1).max())
        <= boundary + 1e-9 * scale
    )
    assert boundary - edge_nearest.max() < 0.01 * scale and boundary <= reach + 1e-12


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.slow
def test_movement_factor_bounds_the_worst_viewer_and_sample(seed):
    # Samples anywhere above the plane at height >= D (also far outside the polygon), viewers
    # anywhere on the polygon: the spacing seen from the nearest viewer over the spacing at the
    # nearest camera never exceeds F_move, and the worst case found comes within reach of it.
    rng = np.random.default_rng(20 + seed)
    polygon = _random_polygon(rng, 8)
    cameras = min_perimeter_triangle(polygon)
    scale = float(np.ptp(polygon, axis=0).max())
    depth = scale * float(rng.choice([0.3, 1.0, 5.0]))
    reach, _ = farthest_from_cameras(polygon, cameras)
    boundary, _ = farthest_from_cameras(polygon, cameras, boundary=True)
    bound = movement_factor(reach, depth, boundary)
    viewers = _sample_polygon(rng, polygon, 4000)
    feet = np.concatenate(
        [_sample_polygon(rng, polygon, 3000), polygon.mean(axis=0) + rng.normal(size=(3000, 2)) * 3.0 * (scale + depth)]
    )
    heights = depth * (1.0 + rng.exponential(0.2, len(feet)))
    heights[: len(feet) // 3] = depth
    camera_distance = np.sqrt(heights**2 + np.min(np.sum((feet[:, None] - cameras[None]) ** 2, axis=2), axis=1))
    lateral = np.min(np.sum((feet[:, None] - viewers[None]) ** 2, axis=2), axis=1)
    worst = float(np.max(camera_distance / np.sqrt(heights**2 + lateral)))
    assert worst <= bound * (1.0 + 1e-9)
    # The bound is conservative (the triangle inequality outside the polygon) but not by much.
    assert bound <= 1.2 * worst


def test_rays_from_any_viewer_to_any_point_of_the_part_cross_the_plane_inside_the_polygon():
    rng = np.random.default_rng(3)
    cell = BoxCell(np.array([-1.0, 0.0, -2.0]), np.array([1.0, 3.0, 1.0]))
    bounds = np.array([[4.0, -2.0, 3.0], [9.0, 5.0, 6.0]])
    s = plan_point_sampling(cell, bounds, 60.0, 128)
    viewers = cell.sample_random(2000, 1)
    targets = bounds[0] + rng.uniform(0.0, 1.0, (2000, 3)) * (bounds[1] - bounds[0])
    t = (s.offset - viewers @ s.normal) / ((targets - viewers) @ s.normal)
    assert np.all((t >= 0.0) & (t < 1.0))
    crossing = viewers + t[:, None] * (targets - viewers)
    plane = np.stack([crossing @ s.u, crossing @ s.v], axis=1)
    assert np.all(Delaunay(s.polygon).find_simplex(plane, tol=1e-9) >= 0)
    # The cameras stand on the plane, at the triangle's vertices, which enclose the polygon.
    for camera, vertex in zip(s.cameras, s.triangle):
        assert camera.position @ s.normal == pytest.approx(s.offset)
        assert np.allclose([camera.position @ s.u, camera.position @ s.v], vertex)
    assert _inside(s.triangle, s.polygon, 1e-9)


def test_every_ldi_window_holds_the_whole_part_tightly():
    cell = BoxCell.from_center([0.0, 0.0, 0.0], 2.0)
    bounds = np.array([[3.0, -1.0, -3.0], [6.0, 5.0, 3.0]])  # wide, close, off to one side
    s = plan_point_sampling(cell, bounds, 45.0, 256)
    corners = np.array([[x, y, z] for x in bounds[:, 0] for y in bounds[:, 1] for z in bounds[:, 2]])
    for ldi in s.cameras:
        camera = ldi.camera()
        pixels = camera.project(corners)
        n = ldi.resolution
        assert np.all(pixels >= -1e-6 * n) and np.all(pixels <= n * (1.0 + 1e-6))
        assert np.max(np.ptp(pixels, axis=0)) == pytest.approx(n)  # the square is as small as it can be
        depth = (corners - ldi.position) @ ldi.forward
        assert np.all(depth >= ldi.near) and np.all(depth <= ldi.far) and ldi.near > 0.0


def test_ldi_resolution_follows_the_output_and_the_distance():
    cell = BoxCell.from_center([0.0, 0.0, 0.0], 1.0)
    part = lambda z: np.array([[-1.0, -1.0, z], [1.0, 1.0, z + 2.0]])  # noqa: E731
    near, far = plan_point_sampling(cell, part(4.0), 45.0, 256), plan_point_sampling(cell, part(40.0), 45.0, 256)
    twice = plan_point_sampling(cell, part(4.0), 45.0, 512)
    # Doubling the output doubles every LDI; the same part ten times farther needs far fewer samples.
    assert all(abs(b.resolution - 2 * a.resolution) <= 1 for a, b in zip(near.cameras, twice.cameras))
    assert all(f.resolution < 0.5 * n.resolution for n, f in zip(near.cameras, far.cameras))
    assert near.factors["movement"] > far.factors["movement"] > 1.0
    # N = 2 tan(φ/2) √2 F_move F_persp / β, β the centre pixel of the output.
    camera = near.cameras[0]
    beta = 2.0 * math.tan(math.radians(22.5)) / 256
    expected = (
        2.0
        * camera.half_size
        * math.sqrt(2.0)
        * near.factors["movement"]
        * (1.0 + 2.0 * math.tan(math.radians(22.5)) ** 2)
        / beta
    )
    assert camera.resolution == math.ceil(expected)
    assert ldi_resolution(camera.half_size, math.radians(45.0), 256, near.factors["movement"]) == camera.resolution


@pytest.mark.parametrize(
    "lo, hi, match",
    [
        ((0.5, -1.0, -1.0), (3.0, 1.0, 1.0), "reaches the view cell"),  # touching the cell's +x face
        ((-0.2, -0.2, -0.2), (0.2, 0.2, 0.2), "centre is the view cell's centre"),
        ((-2.0, -2.0, -2.0), (2.0, 2.0, 2.0), "centre is the view cell's centre"),  # around the cell
        ((0.6, -500.0, -500.0), (0.7, 500.0, 500.0), "too wide or too close"),  # a huge wall right at the cell
    ],
)
def test_parts_a_point_impostor_cannot_serve_are_clear_errors(lo, hi, match):
    cell = BoxCell.from_center([0.0, 0.0, 0.0], 1.0)
    with pytest.raises(ViewCellError, match=match):
        plan_point_sampling(cell, np.array([lo, hi]), 45.0, 256)
