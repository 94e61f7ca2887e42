"""The layered estimate of one part from many view cells at once: :func:`~farfield.core.techniques.part.estimate_part_cell`
(:func:`farfield.core.layering.plan.estimate_layers`, seed 000 §5.8.1) over arrays.

Candidate generation (seed 000 §5.6) asks every hierarchy node's hundreds of shafts and boxes for
their layers and texels; one cell at a time that was about 0.5 ms each (a view, a frame, an integral
of 24 samples), three quarters of planning a placement.  Here the node's shafts are described by
arrays (one apex, a direction, apex angle and minimum distance each), its boxes by their corners, and the rest (half tangents of the tight
frustum, texture resolution, the pole of one layer, the integral of ``1 / c(t)`` of Eqs. 3.2-3.5)
runs on every cell at once with the same operations in the same order, so each answer is the
scalar function's, bit for bit (``tests/test_placement_part_estimates.py`` compares them).

A cell the scalar estimate refuses (the part touching it, a texture over the limit, too many
layers) is ``ok = False`` here instead of a raised LayerPlanError.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from farfield.core.constants import TOL
from farfield.core.layering.plan import (
    _ESTIMATE_SAMPLES,
    spacing_left_lower,
    spacing_left_upper,
    spacing_right,
    spacing_shaft,
)
from farfield.core.pixel_angles import check_error_px, check_fov, check_resolution, pixel_angle
from farfield.core.techniques.part import layer_budget
from farfield.core.viewcells import _orthonormal_frame, box_corners, length_and_unit

_BOX_PICK = np.array(
    [[(i >> a) & 1 for a in range(3)] for i in range(8)], dtype=bool
)  # 8 corners (order is immaterial here)
_SIGNS = np.array([[-1, -1], [1, -1], [-1, 1], [1, 1]], dtype=np.float64)  # ShaftCell.corners' near cap


@dataclass(frozen=True, slots=True)
class ShaftFrames:
    """Per direction of a shaft grid, what every :class:`~farfield.core.viewcells.ShaftCell` along
    it computes: its unit direction as stored, the frame of its corners, and the frame
    (``u``, ``v``, ``axis = -direction``) its :class:`~farfield.core.layering.plan.PartView` looks along."""

    direction: np.ndarray  # (k, 3)
    corner_u: np.ndarray  # (k, 3)
    corner_v: np.ndarray  # (k, 3)
    frame: np.ndarray  # (k, 3, 3): rows u, v, axis

    @classmethod
    def of(cls, grid: np.ndarray) -> ShaftFrames:
        direction, cu, cv, frame = [], [], [], []
        for d in np.asarray(grid, dtype=np.float64):
            norm, _ = length_and_unit(d)
            unit = d / norm
            u, v = _orthonormal_frame(unit)
            axis = -unit
            fu, fv = _orthonormal_frame(axis)
            direction.append(unit), cu.append(u), cv.append(v), frame.append(np.stack([fu, fv, axis]))
        return cls(np.array(direction), np.array(cu), np.array(cv), np.array(frame))


@dataclass(frozen=True, slots=True)
class Views:
    """The :class:`~farfield.core.layering.plan.PartView` quantities the estimate reads, per cell."""

    shaft: np.ndarray  # (k,) bool
    cell_width: np.ndarray  # (k, 2)
    cell_depth: np.ndarray  # (k,)
    apex_angle: np.ndarray  # (k,) nan for a box
    corners_rel: np.ndarray  # (k, 8, 3)
    ok: np.ndarray  # (k,) False where part_view refuses the cell

    @staticmethod
    def concat(parts: list[Views]) -> Views:
        return Views(*(np.concatenate([getattr(p, f) for p in parts]) for f in Views.__slots__))


def shaft_views(bounds, apex, frames: ShaftFrames, d_index, apex_angle, half_tan, min_distance) -> Views:
    """:func:`~farfield.core.layering.plan.part_view` of the part ``bounds`` from the shafts of apex
    ``apex`` along ``frames``' directions ``d_index`` (k,), apex angles ``apex_angle`` (k,) with
    ``half_tan = math.tan(apex_angle / 2)`` and minimum distances ``min_distance`` (k,), unbounded."""
    b = np.asarray(bounds, dtype=np.float64).reshape(2, 3)
    apex = np.asarray(apex, dtype=np.float64)
    d = frames.direction[d_index]
    dist = np.asarray(min_distance, dtype=np.float64)
    h = dist * np.asarray(half_tan, dtype=np.float64)  # ShaftCell.half_width(min_distance)
    side = (
        _SIGNS[None, :, :1] * frames.corner_u[d_index][:, None, :]
        + _SIGNS[None, :, 1:] * frames.corner_v[d_index][:, None, :]
    )
    near = apex + dist[:, None] * d  # the near cap's centre: ShaftCell.center
    corners = near[:, None, :] + h[:, None, None] * side
    scale = np.maximum(float(np.max(np.abs(b))), np.max(np.abs(corners), axis=(1, 2)))
    touch = TOL.rel_touch * np.maximum(scale, TOL.min_extent)
    rel = box_corners(b)[None, :, :] - near[:, None, :]
    corners_rel = np.matmul(rel, np.swapaxes(frames.frame[d_index], 1, 2))
    t0 = corners_rel[:, :, 2].min(axis=1)
    width = 2.0 * h
    k = dist.size
    return Views(
        np.ones(k, dtype=bool), np.stack([width, width], axis=1), np.full(k, math.inf), np.asarray(apex_angle, dtype=np.float64),
        corners_rel, t0 > touch,
    )  # fmt: skip


def box_views(bounds, lo, hi) -> Views:
    """:func:`~farfield.core.layering.plan.part_view` of the part ``bounds`` from the box cells
    ``lo``..``hi`` (k, 3) (as :class:`~farfield.core.viewcells.BoxCell` stores them): each looks
    along the line from its centre to the part's, the box replaced by its bounds in that frame."""
    b = np.asarray(bounds, dtype=np.float64).reshape(2, 3)
    lo, hi = np.asarray(lo, dtype=np.float64).reshape(-1, 3), np.asarray(hi, dtype=np.float64).reshape(-1, 3)
    k = lo.shape[0]
    scale = np.maximum(float(np.max(np.abs(b))), np.maximum(np.max(np.abs(lo), axis=1), np.max(np.abs(hi), axis=1)))
    touch = TOL.rel_touch * np.maximum(scale, TOL.min_extent)
    centre = 0.5 * (lo + hi)
    towards = 0.5 * (b[0] + b[1]) - centre
    dist, frame = _box_frames(towards)
    ok = dist > touch
    frame_t = np.swapaxes(frame, 1, 2)
    cell_corners = np.where(_BOX_PICK[None, :, :], hi[:, None, :], lo[:, None, :])  # BoxCell.corners
    rel = np.matmul(cell_corners - centre[:, None, :], frame_t)
    rlo, rhi = rel.min(axis=1), rel.max(axis=1)
    near = centre + rhi[:, 2:3] * frame[:, 2, :]
    corners_rel = np.matmul(box_corners(b)[None, :, :] - near[:, None, :], frame_t)
    ok &= corners_rel[:, :, 2].min(axis=1) > touch
    return Views(
        np.zeros(k, dtype=bool), rhi[:, :2] - rlo[:, :2], rhi[:, 2] - rlo[:, 2], np.full(k, math.nan), corners_rel, ok
    )


def _box_frames(towards: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(k,) lengths and (k, 3, 3) frames (rows u, v, axis; zeros where the length is 0) of the
    vectors ``towards`` (k, 3): :func:`~farfield.core.viewcells.length_and_unit` and
    :func:`~farfield.core.viewcells._orthonormal_frame` of each, bit for bit.  The squared length is
    each row's own ``dot`` (what ``np.linalg.norm`` of one vector computes: BLAS, whose rounding a
    reduction over an axis does not share); the rest is the scalar arithmetic, elementwise."""
    k = towards.shape[0]
    with np.errstate(over="ignore", under="ignore", divide="ignore", invalid="ignore"):
        dist = np.sqrt(np.array([row.dot(row) for row in towards], dtype=np.float64).reshape(k))
        unit = towards / dist[:, None]
    plain = np.isfinite(dist) & (dist > 0.0)
    for i in np.flatnonzero(~plain):  # squares that overflow or underflow, or a zero vector: the scalar way
        dist[i], unit[i] = length_and_unit(towards[i])
    frame = np.zeros((k, 3, 3))
    some = dist > 0.0
    x, y, z = unit[some, 0], unit[some, 1], unit[some, 2]
    level = np.abs(z) < 0.9  # helper (0, 0, 1), else (1, 0, 0)
    ux, uy, uz = np.where(level, -y, 0.0), np.where(level, x, -z), np.where(level, 0.0, y)
    norm = np.sqrt(ux * ux + uy * uy + uz * uz)
    u0, u1, u2 = ux / norm, uy / norm, uz / norm
    frame[some, 0] = np.stack([u0, u1, u2], axis=1)
    frame[some, 1] = np.stack([y * u2 - z * u1, z * u0 - x * u2, x * u1 - y * u0], axis=1)
    frame[some, 2] = unit[some]
    return dist, frame


def estimate_views(views: Views, options) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(layers, texels per layer, ok) of :func:`~farfield.core.techniques.part.estimate_part_cell`
    for every view (see the module docstring); layers and texels are 0 where ``ok`` is False."""
    budget = layer_budget(options)
    fov, resolution = check_fov(math.radians(options.fov_deg)), check_resolution(options.resolution)
    texel_share = budget["texel_share"]
    alpha = check_error_px(budget["max_error_px"]) * pixel_angle(fov, resolution, budget["pixel_model"])
    k = views.ok.size
    layers, texels, ok = np.zeros(k), np.zeros(k), views.ok.copy()
    if not ok.any():
        return layers, texels, ok
    idx = np.flatnonzero(ok)
    rel, width, shaft = views.corners_rel[idx], views.cell_width[idx], views.shaft[idx]
    depth_cell = views.cell_depth[idx]
    z_all = rel[:, :, 2]
    t0 = z_all.min(axis=1)
    depth = z_all.max(axis=1) - t0
    # reference_offset_candidates(view)[0]: min(n / 2, m) on a shaft, 0 on a box
    s = np.where(shaft, np.minimum(0.5 * width[:, 0], depth_cell), 0.0)
    z = z_all + s[:, None]
    half_tan = np.maximum(np.max(np.abs(rel[:, :, :2]) / z[:, :, None], axis=1), 0.5 * alpha)
    texel = alpha if texel_share is None else texel_share * alpha
    widths = 2.0 * half_tan * (t0 + s)[:, None]
    shrunk = widths / (t0[:, None] * texel) * (1.0 - TOL.rel_round)  # pixel_angles.texture_resolution
    fits = np.all(shrunk <= TOL.max_texture_resolution, axis=1)
    res = np.maximum(1.0, np.ceil(np.where(fits[:, None], shrunk, 1.0)))
    fits &= np.all(res <= TOL.drawable_texture_resolution, axis=1)  # as estimate_part_cell refuses it
    parallax = alpha if texel_share is None else (1.0 - texel_share) * alpha
    r = np.hypot(0.5 * width[:, 0], 0.5 * width[:, 1])
    pole = (r * np.cos(parallax) + np.hypot(r, s)) / (2.0 * np.sin(parallax)) - 0.5 * s  # single_layer_distance
    count = np.ones(idx.size)
    many = fits & ~((depth <= 0.0) | (t0 >= pole))
    if many.any():
        m = np.flatnonzero(many)
        count[m] = _integral(
            t0[m], depth[m], s[m], width[m], depth_cell[m], views.apex_angle[idx][m], shaft[m], half_tan[m], res[m]
        )
    good = fits & (count <= TOL.max_layers)
    ok[idx] = good
    layers[idx] = np.where(good, count, 0.0)
    texels[idx] = np.where(good, res[:, 0] * res[:, 1], 0.0)
    return layers, texels, ok


def _integral(t0, depth, s, width, cell_depth, beta, shaft, half_tan, res) -> np.ndarray:
    """``1 + integral of dt / c(t)`` over the part's depth (:func:`~farfield.core.layering.plan.estimate_layers`)."""
    t = np.ascontiguousarray(np.geomspace(t0, t0 + depth, _ESTIMATE_SAMPLES).T)  # (k, samples)
    s_, t0_ = s[:, None], t0[:, None]
    best = np.full(t.shape, np.inf)
    for axis in range(2):  # layer_spacing, both image axes
        n = width[:, axis : axis + 1]
        w = 2.0 * half_tan[:, axis : axis + 1] * (t0 + s)[:, None]
        rs = res[:, axis : axis + 1]
        c = spacing_right(t, s_, n, w, t0_, rs)
        c_left = np.empty(t.shape)
        if shaft.any():
            c_left[shaft] = spacing_shaft(t[shaft], s_[shaft], w[shaft], t0_[shaft], rs[shaft], beta[shaft][:, None])
        box = ~shaft
        if box.any():
            tb, sb, nb, wb, rb = t[box], s_[box], n[box], w[box], rs[box]
            wider = half_tan[box, axis : axis + 1] * (tb + sb) > 0.5 * nb
            c_left[box] = np.where(
                wider,
                spacing_left_lower(tb, sb, nb, cell_depth[box][:, None], wb, t0_[box], rb),
                spacing_left_upper(tb, sb, nb, wb, t0_[box], rb),
            )
        best = np.minimum(best, np.minimum(c, c_left))
    inverse = 1.0 / best
    return 1.0 + np.sum(0.5 * (inverse[:, 1:] + inverse[:, :-1]) * np.diff(t, axis=1), axis=1)
