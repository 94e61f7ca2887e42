"""A view's estimated pixels (issue 57 item 4): at most one frame by default, as the cost model's
per-pixel term is calibrated on covered pixels, and still at least the pixels a frame covers."""

from __future__ import annotations

import math

import numpy as np
from scenes import box_object

from farfield.core.placement.cost_model import CostModel
from farfield.core.placement.hierarchy import Elements, Hierarchy
from farfield.core.placement.planner import PlacementSettings
from farfield.core.placement.runtime import plain_estimate
from farfield.core.placement.view_space import element_pixels, problem_view_space
from farfield.core.render.raster import Camera, MeshRenderer
from farfield.core.scene import Scene

FOV = math.radians(45.0)
RES = 64
# Time = covered pixels: what the pixel term alone estimates.
PIXELS_ONLY = CostModel("frame_ms", (0.0, 0.0, 1.0, 0.0), (0.0, 0.0, 0.0), (1.0, 0.0, 1.0))


def _street() -> tuple[Scene, np.ndarray, np.ndarray]:
    """Two rows of boxes along a street (x 0..40), the view space a box in the street between them:
    from it the boxes' discs sum to several frames."""
    objects = []
    for k in range(8):
        x = 5.0 * k
        objects.append(box_object(f"north_{k}", (x, 0.0, 3.0), (x + 4.0, 6.0, 7.0), (0.8, 0.2, 0.2, 1.0)))
        objects.append(box_object(f"south_{k}", (x, 0.0, -7.0), (x + 4.0, 6.0, -3.0), (0.2, 0.2, 0.8, 1.0)))
    return Scene.from_objects(objects, source="street"), np.array([10.0, 1.0, -1.0]), np.array([14.0, 2.0, 1.0])


def test_a_views_estimated_pixels_are_at_most_one_frame_by_default():
    scene, lo, hi = _street()
    elements = Elements.of(scene)
    assert element_pixels(elements, lo, hi, FOV, RES).sum() > 3.0 * RES * RES  # the discs alone: over 3 frames
    pv = problem_view_space(elements, Hierarchy.build(elements), lo, hi, PIXELS_ONLY, 1.0, FOV, RES, 4.0, 45.0)
    assert pv.count > 0
    assert pv.time.max() == RES * RES  # capped at one frame
    assert plain_estimate(PIXELS_ONLY, elements, np.arange(elements.count), 0.5 * (lo + hi), FOV, RES) == RES * RES
    assert PlacementSettings(t_max=1.0, model=PIXELS_ONLY).depth_complexity == 1.0
    # An explicit cap still applies (the earlier default of 4 frames, and no cap).
    four = problem_view_space(elements, Hierarchy.build(elements), lo, hi, PIXELS_ONLY, 1.0, FOV, RES, 4.0, 45.0, 4.0)
    assert RES * RES < four.time.max() <= 4 * RES * RES


def test_the_capped_estimate_still_bounds_the_pixels_a_frame_covers():
    """From random eyes in the view space looking anywhere, the estimate over every element is at
    least the pixels the frame covers (the discs over-count each element's projection; a frame
    covers at most a frame)."""
    scene, lo, hi = _street()
    elements = Elements.of(scene)
    rng = np.random.default_rng(4)
    covered = []
    with MeshRenderer(list(scene.objects)) as gpu:
        for _ in range(12):
            eye = rng.uniform(lo, hi)
            forward = rng.normal(size=3)
            forward /= np.linalg.norm(forward)
            camera = Camera.look_at(eye, eye + forward, FOV, RES, 0.05, 200.0)
            pixels = int(np.count_nonzero(gpu.render(camera)[..., 3]))
            estimate = plain_estimate(PIXELS_ONLY, elements, np.arange(elements.count), eye, FOV, RES)
            assert estimate >= pixels
            covered.append(pixels)
    assert max(covered) > 0.9 * RES * RES  # some frames are (nearly) full: the bound is met closely
