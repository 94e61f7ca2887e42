"""A box's pixels in a known frame (issue 57 item 4): its projection clipped by the near plane and
the frame, against the pixels the GL covers drawing the box alone."""

from __future__ import annotations

import math

import numpy as np
from scenes import box_object

from farfield.core.placement.frame_pixels import box_frame_pixels
from farfield.core.render.raster import Camera, MeshRenderer

FOV = math.radians(45.0)
RES = 256  # fine enough that the raster's edge pixels are a few per cent of a box's
BOXES = [
    ((20.0, 0.0, -2.0), (24.0, 20.0, 2.0)),  # a tower
    ((30.0, -1.0, -8.0), (46.0, 0.0, 8.0)),  # a slab
    ((-3.0, -2.0, -18.0), (3.0, 6.0, -17.8)),  # a thin wall
    ((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0)),  # a cube
]


def _views(lo: np.ndarray, hi: np.ndarray, rng) -> list[Camera]:
    """Cameras of four kinds per box: from around it looking at a point of it (the box in frame), at
    a point near it (partly out of frame, or not in it), from inside it, and from just outside a
    face with a near plane deep enough to cut the box (corners behind the eye, behind the near
    plane and in front of it)."""
    ext, centre = hi - lo, 0.5 * (lo + hi)
    cams = []
    for _ in range(4):
        cams.append(Camera.look_at(rng.uniform(-5, 5, 3), rng.uniform(lo, hi), FOV, RES, 0.05, 500.0))
        cams.append(Camera.look_at(rng.uniform(-5, 5, 3), rng.uniform(lo - ext, hi + ext), FOV, RES, 0.05, 500.0))
        eye = rng.uniform(lo, hi)
        cams.append(Camera.look_at(eye, eye + rng.normal(size=3), FOV, RES, 0.05, 500.0))
        axis = int(rng.integers(3))
        eye = centre + rng.uniform(-0.4, 0.4, 3) * ext * (np.arange(3) != axis)
        eye[axis] = hi[axis] + 0.3
        near = min(1.0, 0.5 * float(ext.min()) + 0.3)
        cams.append(Camera.look_at(eye, eye + rng.normal(size=3), FOV, RES, near, 500.0))
    return cams


def test_a_boxs_clipped_projection_is_the_pixels_the_gl_covers():
    """Each box drawn alone from every view: the estimate is the covered pixel count up to the
    raster's edge pixels, views where the near plane cuts the box, where the box leaves the frame,
    where it lies behind the eye or out of frame, and eyes inside it included."""
    rng = np.random.default_rng(11)
    cut, partial, empty, inside = 0, 0, 0, 0
    for lo, hi in BOXES:
        lo, hi = np.array(lo), np.array(hi)
        with MeshRenderer([box_object("box", lo, hi)]) as gpu:
            for camera in _views(lo, hi, rng):
                covered = int(np.count_nonzero(gpu.render(camera)[..., 3]))
                estimate = float(box_frame_pixels(camera, lo[None], hi[None])[0])
                assert abs(estimate - covered) <= 0.03 * max(estimate, covered) + RES / 4, (
                    lo,
                    camera.eye,
                    estimate,
                    covered,
                )
                corners = np.array([[a, b, c] for a in (lo[0], hi[0]) for b in (lo[1], hi[1]) for c in (lo[2], hi[2])])
                z = (corners - camera.eye) @ camera.forward
                xy = camera.project(corners[z > 0]) if np.any(z > 0) else np.zeros((0, 2))
                cut += bool(covered > 0 and np.any(z < camera.near) and np.any(z >= camera.near) and np.any(z < 0))
                partial += bool(0 < covered < RES * RES and (np.any(z <= 0) or np.any((xy < 0) | (xy > RES))))
                empty += covered == 0
                inside += bool(np.all((camera.eye > lo) & (camera.eye < hi)))
    # Every case the clipping handles was drawn (the sample is fixed: a guard against a changed one).
    assert cut >= 3 and partial >= 8 and empty >= 2 and inside == 4 * len(BOXES), (cut, partial, empty, inside)


def test_boxes_behind_or_beside_the_frame_count_nothing_and_a_surrounding_box_the_whole_frame():
    camera = Camera.look_at(np.zeros(3), [0.0, 0.0, 1.0], FOV, RES, 0.1, 100.0)
    lo = np.array([[-1.0, -1.0, -5.0], [20.0, -1.0, 2.0], [-1.0, -1.0, 0.0], [-50.0, -50.0, -50.0]])
    hi = np.array([[1.0, 1.0, -2.0], [22.0, 1.0, 4.0], [1.0, 1.0, 0.05], [50.0, 50.0, 50.0]])
    assert box_frame_pixels(camera, lo, hi).round(6).tolist() == [0.0, 0.0, 0.0, RES * RES]
    # Off-axis cameras (a window of another's image) see their own part of the box.
    box = np.array([[-1.0, -1.0, 3.0]]), np.array([[1.0, 1.0, 4.0]])
    whole = float(box_frame_pixels(camera, *box)[0])
    quarters = [
        float(box_frame_pixels(camera.window(x, y, RES / 2, RES), *box)[0]) / 4
        for x in (0, RES / 2)
        for y in (0, RES / 2)
    ]
    assert math.isclose(sum(quarters), whole, rel_tol=1e-9) and math.isclose(max(quarters), min(quarters), rel_tol=1e-9)


def test_a_continental_ground_seen_with_a_tiny_near_plane_fills_half_the_frame_at_any_roll():
    """A 2,000-km ground slab under an eye 1.7 m up, looking level: below the horizon, half the
    frame whatever the roll (a line through the centre halves the square) and the near plane (all
    of it lies under the eye's feet).  Near 1e-9 m puts the near-plane section's projection 1e15
    tangents wide: clipped to the frame after the division it lost up to 2,545 of 32,768 pixels."""
    lo, hi = np.array([[-1e6, -1e6, -1.0]]), np.array([[1e6, 1e6, 0.0]])
    for near in (1e-1, 1e-5, 1e-7, 1e-9):
        for roll in np.linspace(0.0, math.pi, 7):
            for eye in ([0.0, 0.0, 1.7], [3e5, -2e5, 1.7]):
                level = Camera.look_at(eye, np.array(eye) + [1.0, 0.3, 0.0], FOV, RES, near, 1e7)
                c, s = math.cos(roll), math.sin(roll)
                camera = Camera(
                    level.eye, c * level.right + s * level.up, c * level.up - s * level.right, level.forward,
                    FOV, RES, near, 1e7,
                )  # fmt: skip
                pixels = float(box_frame_pixels(camera, lo, hi)[0])
                assert abs(pixels - RES * RES / 2) <= 1.0, (near, roll, eye, pixels)
