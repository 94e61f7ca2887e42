"""Layer mathematics of layered impostors: scalar or (n,) float64 distances in scene units, angles in radians.

Everything here follows seed 000 (Jeschke's dissertation) §3.3.1, Fig. 3.3, in its own variables:

``t``   distance of a layer plane from the view cell's near border, measured along the view axis;
``t0``  distance from that border to the represented part's near plane;
``s``   distance from the reference viewpoint back to the near border (s >= 0);
``n``   view-cell width across the axis; ``m`` its depth along the axis (boxes);
``beta`` the apex angle (shafts);
``w``   width of the recording frustum at the part's near plane (distance ``t0 + s`` from the
        reference viewpoint);
``res`` impostor texture resolution (texels across ``w``);
``r``   lateral distance from the reference viewpoint to the view-cell corner nearest the part
        (the 3D corner of Fig. 3.7);
``alpha`` the parallax angle, one output pixel.

The free functions accept numpy arrays and broadcast; :func:`plan_layers` turns a view cell and the
bounds of a part into a :class:`LayerPlan`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from farfield.core.constants import TOL
from farfield.core.errors import LayerPlanError, PlanBudgetError
from farfield.core.pixel_angles import (
    PixelModel,
    check_error_px,
    check_fov,
    check_resolution,
    pixel_angle,
    texture_resolution,
)
from farfield.core.viewcells import BoxCell, ShaftCell, ViewCell, _orthonormal_frame, box_corners, length_and_unit

# ---------------------------------------------------------------------------------------------
# The equations
# ---------------------------------------------------------------------------------------------


def texel_size(t, s, w, t0, res):
    """Texel size p at layer distance ``t`` (seed 000 §3.3.1): ``p = w (t + s) / (res (t0 + s))``."""
    return w * (t + s) / (res * (t0 + s))


def _spacing(a, denominator):
    """``a / denominator`` where a non-positive denominator means "the boundary line never meets
    the view cell", i.e. unbounded spacing (the texel is wider than what it could uncover)."""
    a = np.asarray(a, dtype=np.float64)
    den = np.asarray(denominator, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(den > 0.0, a / np.where(den > 0.0, den, 1.0), np.inf)
    return out[()] if out.ndim == 0 else out


def spacing_right(t, s, n, w, t0, res):
    """Distance c_r to the next layer from the right boundary line (seed 000 Eq. 3.2).

    Holds for box and shaft view cells alike.

    >>> round(float(spacing_right(95, 0, 100, 30, 90, 300)), 5)
    0.20098
    """
    return _spacing(t, res / (2.0 * (t + s)) * (n * (t0 + s) / w + s) - 1.0)


def spacing_left_lower(t, s, n, m, w, t0, res):
    """c_l: left boundary line touching the *far* (lower) view-cell corner (seed 000 Eq. 3.3).

    Applies when the layer reaches beyond the view cell's side (Fig. 3.3 (b)).
    """
    return _spacing(t + m, res / (2.0 * (t + s)) * (n * (t0 + s) / w + (m - s) * (1.0 - 2.0 / res)) - 1.0)


def spacing_left_upper(t, s, n, w, t0, res):
    """c_h: left boundary line touching the *near* (upper) view-cell corner (seed 000 Eq. 3.4).

    Equal to :func:`spacing_right` at ``s = 0``.
    """
    return _spacing(t, res / (2.0 * (t + s)) * (n * (t0 + s) / w + s * (2.0 / res - 1.0)) - 1.0)


def spacing_shaft(t, s, w, t0, res, beta):
    """c_s: left boundary line parallel to the shaft's side (seed 000 Eq. 3.5)."""
    return _spacing(t + s, res * (0.5 + (t0 + s) / w * np.tan(0.5 * beta)) - 1.0)


def border_offset(t_near, t_far, s):
    """Distance d from the near layer to the border between two layers (seed 000 Eq. 3.6).

    The printed form ``(-tn² - tn s + sqrt(tf tn (tf+s)(tn+s))) / (tn + tf + s)`` subtracts two
    nearly equal numbers of size ``tn²``; at continental distances in float32 it loses every digit.
    Multiplying by the conjugate and cancelling ``(tf + tn + s)`` gives the equivalent, cancellation
    free form used here::

        d = sqrt(tn (tn+s)) (tf - tn) / (sqrt(tf (tf+s)) + sqrt(tn (tn+s)))

    >>> round(float(border_offset(100, 110, 0)), 5), round(float(border_offset(100, 110, 50)), 5)
    (4.7619, 4.8003)
    """
    g_near = np.sqrt(t_near * (t_near + s))
    g_far = np.sqrt(t_far * (t_far + s))
    return g_near * (t_far - t_near) / (g_far + g_near)


def depth_range(t, s, r, alpha, phi):
    """Depth range e behind a plane at ``t`` for view direction ``phi`` (seed 000 Eq. 3.7).

    Non-positive denominators (the two rays never meet) give ``inf``.
    """
    den = r * (np.cos(2.0 * phi) + np.cos(alpha)) + s * (np.sin(2.0 * phi) - np.sin(alpha)) - 2.0 * t * np.sin(alpha)
    return _spacing(2.0 * t * np.sin(alpha) * (t + s), den)


def depth_range_min(t, s, r, alpha):
    """e_min: the smallest depth range behind (or in front of) a plane at ``t`` (seed 000 §3.3.1).

    Eq. 3.7 at ``phi_min = atan(s / r) / 2``.  Past the pole :func:`single_layer_distance` the
    denominator is no longer positive: every point behind the plane is seen within ``alpha``, so the
    range is unbounded (``inf``), never negative.

    >>> round(float(depth_range_min(1000, 50, 70.71, 1.618e-3)), 4)
    22.0643
    """
    den = r * np.cos(alpha) - (2.0 * t + s) * np.sin(alpha) + np.hypot(r, s)
    return _spacing(2.0 * t * np.sin(alpha) * (t + s), den)


def single_layer_distance(s, r, alpha):
    """Pole t* of e_min: from this distance on one layer represents everything behind it.

    ``t* = (r cos α + sqrt(r² + s²)) / (2 sin α) - s / 2`` (the zero of e_min's denominator).
    """
    return (r * np.cos(alpha) + np.hypot(r, s)) / (2.0 * np.sin(alpha)) - 0.5 * s


# ---------------------------------------------------------------------------------------------
# The geometry of a part seen from a view cell
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class PartView:
    """The per-axis quantities of seed 000 Fig. 3.3 for one part seen from one view cell.

    Lengths are scene units; ``axis``, ``u``, ``v`` are (3,) float64 unit vectors, ``near_center``
    (3,) float64 the centre of the view cell's near border on the axis.
    """

    kind: str  # "box" or "shaft"
    axis: np.ndarray  # (3,) from the view cell towards the part
    u: np.ndarray  # (3,) image x
    v: np.ndarray  # (3,) image y
    near_center: np.ndarray  # (3,)
    cell_width: np.ndarray  # (2,) n along u and v
    cell_depth: float  # m (box); max - min distance for a shaft (inf if unbounded)
    apex_angle: float  # beta (shaft); nan for a box
    t0: float
    depth: float
    corners_rel: np.ndarray  # (8, 3) part bounding-box corners relative to near_center, in (u, v, axis)
    viewpoints_rel: np.ndarray  # (m, 3) viewpoints of the cell that bound parallax, same frame


def part_view(cell: ViewCell, bounds, viewpoints: bool = True) -> PartView:
    """Describe the part with axis-aligned ``bounds`` (2, 3) as seen from ``cell``.

    A box cell looks along the line from its centre to the part's centre; the cell is replaced by
    its bounding box in that frame (exact when the axis is a coordinate axis, conservative
    otherwise).  A shaft looks along ``-direction``.  Raises LayerPlanError when the part touches
    or overlaps the view cell along the axis (the layer mathematics has no answer there).
    ``viewpoints=False`` leaves ``viewpoints_rel`` empty (estimates that need no parallax in 3D).
    """
    b = np.asarray(bounds, dtype=np.float64).reshape(2, 3)
    if not np.all(np.isfinite(b)) or np.any(b[1] < b[0]):
        raise LayerPlanError(f"part bounds must be finite with lo <= hi, got {b.tolist()}")
    part_corners = box_corners(b)
    scale = float(np.max(np.abs(np.concatenate([b.ravel(), cell.corners().ravel()]))))
    touch = TOL.rel_touch * max(scale, TOL.min_extent)
    if isinstance(cell, BoxCell):
        towards = 0.5 * (b[0] + b[1]) - cell.center
        dist, axis = length_and_unit(towards)  # coordinates near 1e300: their squares overflow
        if dist <= touch:
            raise LayerPlanError("the part is centred inside the view cell; a layered impostor needs it in front")
        u, v = _orthonormal_frame(axis)
        frame = np.stack([u, v, axis])
        rel = (cell.corners() - cell.center) @ frame.T
        lo, hi = rel.min(axis=0), rel.max(axis=0)
        near_center = cell.center + hi[2] * axis
        cell_width = hi[:2] - lo[:2]
        cell_depth, apex = float(hi[2] - lo[2]), math.nan
    elif isinstance(cell, ShaftCell):
        axis = -cell.direction
        u, v = _orthonormal_frame(axis)
        frame = np.stack([u, v, axis])
        near_center = cell.center
        width = 2.0 * cell.half_width(cell.min_distance)
        cell_width = np.array([width, width])
        cell_depth, apex = cell.max_distance - cell.min_distance, cell.apex_angle
    else:  # pragma: no cover - typing guard
        raise LayerPlanError(f"unknown view cell {cell!r}")
    corners_rel = (part_corners - near_center) @ frame.T
    viewpoints_rel = (_parallax_viewpoints(cell) - near_center) @ frame.T if viewpoints else np.empty((0, 3))
    t0 = float(corners_rel[:, 2].min())
    depth = float(corners_rel[:, 2].max()) - t0
    if t0 <= touch:
        raise LayerPlanError(
            f"the part touches or overlaps the view cell along the view axis (distance {t0:.6g}); "
            "layered impostors need the part strictly in front of the cell"
        )
    return PartView(
        cell.kind, axis, u, v, near_center, cell_width, cell_depth, apex, t0, depth, corners_rel, viewpoints_rel
    )


def _parallax_viewpoints(cell: ViewCell) -> np.ndarray:
    """(m, 3) world points of ``cell`` over which parallax is maximised (:class:`RayPairs`): a
    box's 8 corners; a shaft's cap corners at its near cap and at 2, 4, 8 and 16 times its
    distance (and its far cap, if bounded), parallax falling with distance along a shaft.

    The largest parallax over a box lay at a corner in all of 724 random part/cell
    configurations tried against its corners, edge midpoints and face centres.
    """
    if isinstance(cell, BoxCell):
        return cell.corners()
    u, v, d = cell.frame()
    square = np.array([(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)])
    caps = sorted(
        {min(cell.min_distance * f, cell.max_distance) for f in (1.0, 2.0, 4.0, 8.0, 16.0)}
        | ({cell.max_distance} if cell.bounded else set())
    )
    out = [cell.apex + dist * d + cell.half_width(dist) * (square[:, :1] * u + square[:, 1:] * v) for dist in caps]
    return np.concatenate(out, axis=0)


def reference_offset_candidates(view: PartView) -> tuple[float, ...]:
    """Candidate distances s of the reference viewpoint behind the near border (seed 000 §3.3.1).

    Box: ``s = 0`` is optimal while no layer is wider than the view cell (Fig. 3.4 (d)); otherwise
    "no general optimum can be found" and the thesis used ``s = m / 2`` in practice.  Both are
    offered and :func:`plan_layers` keeps the one needing fewer layers (ties: ``s = 0``), which
    also keeps the layer count monotone in view-cell size and distance, where switching by the
    width rule alone would not be.  Shaft: ``s = n / 2`` (the thesis's choice).
    """
    if view.kind == "shaft":
        return (min(0.5 * float(view.cell_width[0]), view.cell_depth),)
    return (0.0, 0.5 * view.cell_depth)


def _half_tangents(view: PartView, s: float) -> np.ndarray:
    """(2,) tangents of the half-angles of the symmetric frustum from the reference viewpoint that
    encloses the part's bounding box (the "tight" frustum of seed 000 Fig. 3.1 (a))."""
    z = view.corners_rel[:, 2] + s
    return np.max(np.abs(view.corners_rel[:, :2]) / z[:, None], axis=0)


# ---------------------------------------------------------------------------------------------
# Parallax in 3D, from every viewpoint of the cell (farfield's one-pixel budget)
# ---------------------------------------------------------------------------------------------


def parallax_angles(points: np.ndarray, viewpoints: np.ndarray, plane: float) -> np.ndarray:
    """(m, n) angles (radians) between eye-frame ``points`` (n, 3) and their images on the layer
    plane at eye depth ``plane``, seen from eye-frame ``viewpoints`` (m, 3).

    The eye frame has the reference viewpoint at the origin and the view axis along z; a point X
    is recorded where its ray from the reference viewpoint meets the plane, ``kX`` with
    ``k = plane / z``.  From a viewpoint V, ``kX - V = k (X - V) + (k - 1) V``, so
    ``(X - V) x (kX - V) = (k - 1) (X x V)`` and the angle is
    ``atan2(|k - 1| |X x V|, (X - V) . (kX - V))``, exact near the plane where both vectors are
    nearly equal.

    >>> x = np.array([[0.0, 0.0, 110.0]]); v = np.array([[1.0, 0.0, 0.0]])
    >>> round(float(parallax_angles(x, v, 100.0)[0, 0]), 8)  # ~ 1 * 10 / (100 * 110)
    0.00090901
    """
    x = np.asarray(points, dtype=np.float64)[None, :, :]
    v = np.asarray(viewpoints, dtype=np.float64)[:, None, :]
    k = plane / x[..., 2:]
    a = x - v
    b = k * x - v
    sine = np.abs(k[..., 0] - 1.0) * np.linalg.norm(np.cross(x, v), axis=-1)
    return np.arctan2(sine, np.sum(a * b, axis=-1))


def _section_grid(n: int = 33, edge: int = 129) -> np.ndarray:
    """(m, 2) normalised points of a frustum cross-section, [-1, 1]^2: an n x n grid and ``edge``
    points along each side (a viewpoint behind the reference viewpoint sees the largest parallax
    at the frustum's edge: its depth times the frustum's half tangent adds to its lateral offset)."""
    g = np.linspace(-1.0, 1.0, n)
    e = np.linspace(-1.0, 1.0, edge)
    one = np.ones_like(e)
    sides = np.concatenate(
        [np.stack([e, -one], 1), np.stack([e, one], 1), np.stack([-one, e], 1), np.stack([one, e], 1)]
    )
    return np.unique(np.concatenate([np.stack(np.meshgrid(g, g), -1).reshape(-1, 2), sides]), axis=0)


_SECTION = _section_grid()


@dataclass(frozen=True, slots=True)
class RayPairs:
    """Parallax geometry of every (viewpoint, ray) pair of a plan, independent of depth.

    A ray leaves the reference viewpoint through a point of the frustum's cross-section; a point
    at eye depth w on it lies ``w * length`` along it.  A viewpoint lies ``dist`` from the ray,
    its foot ``foot`` along it, so it sees that point at the angle ``atan((w length - foot) / dist)``
    within their common plane, and a point and its image on a layer plane (the same ray) at the
    difference of two such angles, exactly.
    """

    length: np.ndarray  # (n,)
    foot: np.ndarray  # (n,)
    dist: np.ndarray  # (n,) > 0

    @classmethod
    def of(cls, view: PartView, s: float, half_tan: np.ndarray) -> RayPairs:
        """The pairs of the cell's viewpoints (:func:`_parallax_viewpoints`) and rays through
        :data:`_SECTION` plus, per viewpoint, the rays through the points straight ahead of it
        (its lateral offset) at 33 depths across the part, where a viewpoint on the near border
        sees the largest parallax (seed 000 Fig. 3.6) and a grid would pass between."""
        eye_v = view.viewpoints_rel + np.array([0.0, 0.0, s])
        depths = np.geomspace(view.t0 + s, view.t0 + view.depth + s, 33) if view.depth > 0 else np.array([view.t0 + s])
        ahead = (eye_v[:, None, :2] / (half_tan * depths[None, :, None])).reshape(-1, 2)
        ahead = ahead[np.all(np.abs(ahead) <= 1.0, axis=1)]
        section = np.concatenate([_SECTION, ahead])
        rays = np.column_stack([section * half_tan, np.ones(section.shape[0])])  # eye depth 1
        length = np.linalg.norm(rays, axis=1)
        unit = rays / length[:, None]
        foot = eye_v @ unit.T  # (m, n)
        dist = np.linalg.norm(np.cross(eye_v[:, None, :], unit[None, :, :]), axis=-1)
        scale = float(np.max(np.abs(eye_v))) + 1.0
        keep = dist > 1e-12 * scale  # a viewpoint on the ray sees no parallax along it
        length = np.broadcast_to(length, foot.shape)
        return cls(length[keep], foot[keep], dist[keep])

    def angle(self, w: float) -> np.ndarray:
        """(n,) the angle at which each viewpoint sees the point at eye depth ``w`` on its ray."""
        return np.arctan2(w * self.length - self.foot, self.dist)

    def worst(self, plane: float, depth: float) -> float:
        """Largest parallax (radians) between points at eye depth ``depth`` and their images on
        the plane at eye depth ``plane``."""
        return float(np.max(np.abs(self.angle(plane) - self.angle(depth))))

    def farthest(self, w: float, budget: float) -> float:
        """The farthest eye depth whose points (or layer plane) every viewpoint sees within
        ``budget`` radians of those at ``w`` (``inf`` where no ray limits it)."""
        turned = self.angle(w) + budget
        with np.errstate(over="ignore"):
            depth = np.where(
                turned < 0.5 * math.pi,
                (self.foot + self.dist * np.tan(np.minimum(turned, 0.5 * math.pi - 1e-12))) / self.length,
                np.inf,
            )
        return float(depth.min())

    def nearest(self, w: float, budget: float) -> float:
        """The nearest eye depth whose points every viewpoint sees within ``budget`` radians of
        their images on the plane at eye depth ``w`` (``-inf`` where no ray limits it)."""
        turned = self.angle(w) - budget
        depth = np.where(
            turned > -0.5 * math.pi,
            (self.foot + self.dist * np.tan(np.maximum(turned, -0.5 * math.pi + 1e-12))) / self.length,
            -np.inf,
        )
        return float(depth.max())


def worst_parallax(view: PartView, s: float, half_tan: np.ndarray, plane: float, depth: float) -> float:
    """Largest angle (radians) from any of the cell's viewpoints between a point of the part's
    frustum at distance ``depth`` from the near border and its image on the layer plane at
    distance ``plane`` (both the thesis's t; the reference viewpoint lies ``s`` behind the border).

    Unlike Eq. 3.7 of seed 000, which puts the viewer on the near border in the plane of the
    diagonal (§3.3.1, "Parallax Errors"), this takes every viewpoint of
    :func:`_parallax_viewpoints` and the whole cross-section: a viewpoint deeper in the cell sees
    the frustum's edge with a larger parallax than Eq. 3.7 assumes (1.2 alpha for the scrub pine's
    first layer at 512 px).
    """
    return RayPairs.of(view, s, half_tan).worst(plane + s, depth + s)


# ---------------------------------------------------------------------------------------------
# The plan
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class LayerPlan:
    """Where the layers of one layered impostor lie and what depth each represents.

    Distances are scene units along ``axis`` from the view cell's near border (the thesis's t); add
    ``reference_offset`` for the distance from the reference viewpoint.
    """

    distances: np.ndarray  # (k,) float64 layer planes, ascending
    borders: np.ndarray  # (k + 1,) float64; layer i represents [borders[i], borders[i+1]]
    reference_viewpoint: np.ndarray  # (3,) float64 world
    axis: np.ndarray  # (3,) float64 world, towards the part
    u: np.ndarray  # (3,) float64 world, image x
    v: np.ndarray  # (3,) float64 world, image y
    reference_offset: float  # s
    frustum_half_tangents: np.ndarray  # (2,) float64, along u and v
    texture_resolution: np.ndarray  # (2,) int64 texels along u and v
    alpha: float  # one output pixel, radians
    pixel_model: str
    t0: float
    depth: float
    cell_width: np.ndarray  # (2,) float64
    cell_depth: float  # m; for shafts max - min distance (inf if unbounded)
    corner_offset: float  # r
    front_range: float  # e_min in front of the first layer's plane (may be inf)
    back_limit: float  # last layer plane + e_min behind it (inf past the pole)
    single_layer_distance: float  # t*, beyond which one layer represents everything behind it
    # The error budget: texels subtend at most texel_angle, and parallax stays within
    # parallax_angle.  The thesis gives both the whole pixel alpha (texel_share None); a share f
    # gives texels f alpha and parallax (1 - f) alpha, so that a silhouette grown by one texel
    # (conservative recording, §3.3.2) and moved by parallax stays within one pixel.
    texel_share: float | None = None
    texel_angle: float = math.nan
    parallax_angle: float = math.nan
    max_error_px: float = 1.0  # the budget in output pixels: alpha is this many pixel angles

    @property
    def count(self) -> int:
        return int(self.distances.shape[0])

    def to_dict(self) -> dict:
        """JSON-ready form (``inf`` becomes ``None``)."""

        def num(x):
            return None if not math.isfinite(x) else float(x)

        return {
            "arrangement": "part",
            "layers": self.count,
            "distances": self.distances.tolist(),
            "borders": self.borders.tolist(),
            "depth_ranges": [[float(a), float(b)] for a, b in zip(self.borders[:-1], self.borders[1:])],
            "reference_viewpoint": self.reference_viewpoint.tolist(),
            "axis": self.axis.tolist(),
            "reference_offset": self.reference_offset,
            "texture_resolution": self.texture_resolution.tolist(),
            "alpha_rad": self.alpha,
            "pixel_model": self.pixel_model,
            **({} if self.max_error_px == 1.0 else {"max_error_px": self.max_error_px}),
            **(
                {}
                if self.texel_share is None
                else {
                    "texel_share": self.texel_share,
                    "texel_angle_rad": self.texel_angle,
                    "parallax_angle_rad": self.parallax_angle,
                }
            ),
            "part_distance": self.t0,
            "part_depth": self.depth,
            "cell_width": self.cell_width.tolist(),
            "cell_depth": num(self.cell_depth),
            "front_range": num(self.front_range),
            "back_limit": num(self.back_limit),
            "single_layer_distance": num(self.single_layer_distance),
        }


def layer_spacing(t, s, view: PartView, half_tan: np.ndarray, res: np.ndarray):
    """Smallest one-texel spacing c(t) over both image axes and both boundary lines (seed 000 §3.3.1).

    ``t`` may be an array; returns float64 of the same shape, ``inf`` where unconstrained.
    """
    t = np.asarray(t, dtype=np.float64)
    best = np.full(t.shape, np.inf)
    for axis in range(2):
        n = float(view.cell_width[axis])
        w = 2.0 * float(half_tan[axis]) * (view.t0 + s)
        rs = float(res[axis])
        c = spacing_right(t, s, n, w, view.t0, rs)
        if view.kind == "shaft":
            c_left = spacing_shaft(t, s, w, view.t0, rs, view.apex_angle)
        else:
            # Fig. 3.3 (b) vs (c): does the layer end beyond the view cell's side?
            wider = half_tan[axis] * (t + s) > 0.5 * n
            c_left = np.where(
                wider,
                spacing_left_lower(t, s, n, view.cell_depth, w, view.t0, rs),
                spacing_left_upper(t, s, n, w, view.t0, rs),
            )
        best = np.minimum(best, np.minimum(c, c_left))
    return best[()] if best.ndim == 0 else best


def plan_layers(
    cell: ViewCell,
    bounds,
    fov: float,
    resolution: int,
    pixel_model: PixelModel = "min",
    reference_offset: float | None = None,
    texel_share: float | None = None,
    max_texels: int | None = None,
    max_error_px: float = 1.0,
) -> LayerPlan:
    """Plan the layers of a layered impostor for the part in ``bounds`` seen from ``cell``.

    Parameters
    ----------
    cell : BoxCell or ShaftCell
    bounds : (2, 3) float64, world units
        Axis-aligned bounds of the represented part.
    fov : float
        Output field of view, radians, in (0, π).
    resolution : int
        Output image resolution (pixels per side), >= 1.
    pixel_model : {"min", "center"}
        Which pixel angle bounds the error (see :mod:`farfield.core.pixel_angles`); ``"center"`` is the thesis's.
    reference_offset : float, optional
        s; by default the candidate of :func:`reference_offset_candidates` with fewest layers.
    texel_share : float in (0, 1), optional
        None: the thesis's budget, texels and parallax each bounded by the pixel angle alpha.
        A share f: texels subtend at most f alpha and parallax, measured in 3D from the cell's
        viewpoints (:func:`worst_parallax`), at most (1 - f) alpha, so that a silhouette, grown
        by up to one texel by the conservative recording (§3.3.2) and moved by parallax, stays
        within one pixel of the geometry.
    max_texels : int, optional
        A budget of texels (layers x texture resolution): planning stops with
        :class:`~farfield.core.errors.PlanBudgetError` (the layers planned so far, one past the
        budget, and the texture) as soon as every candidate plan has passed it, so refusing a costly
        plan costs no more than the budget's layers.  None: no budget (only ``TOL.max_layers``).

    Thesis budget: layers start at ``t0 + e_min(t0)`` (clamped into the part) and follow at the
    one-texel spacing of Eqs. 3.2–3.5 until a layer's back range ``e_min`` reaches the far end of
    the part; borders between layers come from Eq. 3.6.  With a share, the first layer is the
    farthest whose parallax at the part's near plane is within budget, each next one the nearer
    of the one-texel spacing and the farthest whose Eq. 3.6 border keeps both layers within
    budget, until the last one's parallax at the far end is.  Work is O(layers).
    """
    fov = check_fov(float(fov))
    resolution = check_resolution(resolution)
    view = part_view(cell, bounds)
    alpha = check_error_px(max_error_px) * pixel_angle(fov, resolution, pixel_model)
    if texel_share is not None and not (math.isfinite(texel_share) and 0.0 < texel_share < 1.0):
        raise LayerPlanError(f"texel share must lie in (0, 1), got {texel_share!r}")
    if reference_offset is not None:
        s = float(reference_offset)
        if not (math.isfinite(s) and 0.0 <= s <= view.cell_depth):
            raise LayerPlanError(f"reference offset s must lie in [0, cell depth {view.cell_depth:.6g}], got {s!r}")
        return replace(_plan_at_offset(view, s, alpha, pixel_model, texel_share, max_texels), max_error_px=max_error_px)
    best, over = None, None
    for s in reference_offset_candidates(view):
        try:
            plan = _plan_at_offset(view, s, alpha, pixel_model, texel_share, max_texels)
        except PlanBudgetError as error:  # this candidate is over the budget; another may not be
            if over is None or error.texels < over.texels:
                over = error
            continue
        if best is None or plan.count < best.count:
            best = plan
    if best is None:
        raise over
    return best if max_error_px == 1.0 else replace(best, max_error_px=float(max_error_px))


def _layer_cap(res: np.ndarray, max_texels: int | None) -> int:
    """The most layers of texture ``res`` within ``max_texels`` (Python integers: no overflow),
    at most ``TOL.max_layers``."""
    if max_texels is None:
        return TOL.max_layers
    return min(TOL.max_layers, int(max_texels) // (int(res[0]) * int(res[1])))


def _over_budget(count: int, res: np.ndarray, cap: int) -> None:
    """Raise when ``count`` layers are more than ``cap`` allows (the texel budget, or ``TOL.max_layers``)."""
    if count > cap and cap < TOL.max_layers:
        raise PlanBudgetError(count, (int(res[0]), int(res[1])))


def _plan_at_offset(
    view: PartView,
    s: float,
    alpha: float,
    pixel_model: str,
    texel_share: float | None = None,
    max_texels: int | None = None,
) -> LayerPlan:
    """The layer plan of ``view`` with the reference viewpoint ``s`` behind the near border."""
    half_tan = _half_tangents(view, s)
    # A flat part seen edge-on has no lateral extent: give it a pixel's worth of frustum so the
    # spacing stays finite (a one-texel-wide layer).
    half_tan = np.maximum(half_tan, 0.5 * alpha)
    texel = alpha if texel_share is None else texel_share * alpha
    widths = 2.0 * half_tan * (view.t0 + s)
    res = np.array([texture_resolution(float(wd), view.t0, texel) for wd in widths], dtype=np.int64)
    r = float(np.hypot(*(0.5 * view.cell_width)))

    t0, t_end = view.t0, view.t0 + view.depth
    cap = _layer_cap(res, max_texels)
    _over_budget(1, res, cap)
    if texel_share is not None:
        return _shared_budget_plan(view, s, alpha, pixel_model, texel_share, half_tan, res, r, cap)
    front = float(depth_range_min(t0, s, r, alpha))
    t = t0 + min(front, view.depth)
    distances = [t]
    while t + float(depth_range_min(t, s, r, alpha)) < t_end:
        c = float(layer_spacing(t, s, view, half_tan, res))
        if not c > 0.0:
            raise LayerPlanError(f"layer spacing collapsed to {c!r} at distance {t:.6g}")
        t = min(t + c, t_end)
        distances.append(t)
        _over_budget(len(distances), res, cap)
        if len(distances) > TOL.max_layers:
            raise LayerPlanError(
                f"more than {TOL.max_layers} layers needed for a part {view.depth:.6g} deep at "
                f"distance {t0:.6g}; use a smaller view cell or a lower resolution"
            )
    d = np.asarray(distances, dtype=np.float64)
    inner = d[:-1] + border_offset(d[:-1], d[1:], s)
    borders = np.concatenate([[t0], inner, [t_end]])
    back = float(d[-1] + depth_range_min(d[-1], s, r, alpha))
    return LayerPlan(
        distances=d,
        borders=borders,
        reference_viewpoint=view.near_center - s * view.axis,
        axis=view.axis,
        u=view.u,
        v=view.v,
        reference_offset=s,
        frustum_half_tangents=half_tan,
        texture_resolution=res,
        alpha=alpha,
        pixel_model=pixel_model,
        t0=t0,
        depth=view.depth,
        cell_width=view.cell_width,
        cell_depth=view.cell_depth,
        corner_offset=r,
        front_range=front,
        back_limit=back,
        single_layer_distance=float(single_layer_distance(s, r, alpha)),
        texel_angle=alpha,
        parallax_angle=alpha,
    )


def _shared_budget_plan(
    view: PartView,
    s: float,
    alpha: float,
    pixel_model: str,
    share: float,
    half_tan,
    res,
    r: float,
    cap: int = TOL.max_layers,
) -> LayerPlan:
    """:func:`_plan_at_offset` with texels of ``share * alpha`` and parallax within ``(1 - share) * alpha``
    from every viewpoint (:class:`RayPairs`; see :func:`plan_layers`).

    Greedy and closed-form: in eye depths, the first plane is the farthest whose parallax reaches
    the part's near plane, ``F(t0)``.  Behind a plane T, a border may lie up to ``F(T)`` and the
    next plane up to ``F(F(T))`` (a plane reaches forward to a border exactly when the border
    reaches back to it), so the next plane is the nearer of that and the one-texel spacing, and
    its border is the one of Eq. 3.6 where that lies within both planes' reach, else the nearest
    such.  Layers follow until one reaches the far end of the part.
    """
    budget = (1.0 - share) * alpha * (1.0 - TOL.parallax_grid)
    pairs = RayPairs.of(view, s, half_tan)
    t0, t_end = view.t0, view.t0 + view.depth
    far = t_end + s  # eye depths from here on
    plane = min(pairs.farthest(t0 + s, budget), far)
    planes, borders = [plane], [t0 + s]
    while pairs.farthest(plane, budget) < far:
        c = float(layer_spacing(plane - s, s, view, half_tan, res))
        if not c > 0.0:
            raise LayerPlanError(f"layer spacing collapsed to {c!r} at distance {plane - s:.6g}")
        reach = pairs.farthest(plane, budget)
        nxt = min(plane + c, pairs.farthest(reach, budget), far)
        thesis = plane + float(border_offset(plane - s, nxt - s, s))
        borders.append(min(max(thesis, pairs.nearest(nxt, budget), plane), reach, nxt))
        planes.append(nxt)
        plane = nxt
        _over_budget(len(planes), res, cap)
        if len(planes) > TOL.max_layers:
            raise LayerPlanError(
                f"more than {TOL.max_layers} layers needed for a part {view.depth:.6g} deep at "
                f"distance {t0:.6g}; use a smaller view cell or a lower resolution"
            )
    d = np.asarray(planes, dtype=np.float64) - s
    borders = np.concatenate([np.asarray(borders, dtype=np.float64) - s, [t_end]])
    borders[0] = t0
    # What the first and last layers may represent in front and behind, within budget (reported).
    front = float(planes[0] - max(pairs.nearest(planes[0], budget), 0.0))
    back = pairs.farthest(planes[-1], budget) - s
    return LayerPlan(
        distances=d,
        borders=borders,
        reference_viewpoint=view.near_center - s * view.axis,
        axis=view.axis,
        u=view.u,
        v=view.v,
        reference_offset=s,
        frustum_half_tangents=half_tan,
        texture_resolution=res,
        alpha=alpha,
        pixel_model=pixel_model,
        t0=t0,
        depth=view.depth,
        cell_width=view.cell_width,
        cell_depth=view.cell_depth,
        corner_offset=r,
        front_range=front,
        back_limit=back,
        single_layer_distance=float(single_layer_distance(s, r, alpha)),
        texel_share=share,
        texel_angle=share * alpha,
        parallax_angle=budget,
    )


# ---------------------------------------------------------------------------------------------
# A cheap estimate for ranking (seed 000 §5.8.1: layers x texture resolution)
# ---------------------------------------------------------------------------------------------

_ESTIMATE_SAMPLES = 24  # geometric samples of the part's depth for the integral of 1 / c(t)


def estimate_layers(
    cell: ViewCell,
    bounds,
    fov: float,
    resolution: int,
    pixel_model: PixelModel = "min",
    texel_share: float | None = None,
    max_error_px: float = 1.0,
) -> tuple[float, np.ndarray]:
    """Estimated layer count (float) and the exact texture resolution (2,) of :func:`plan_layers`'s
    plan, at a small fixed cost (no layer loop): what a placement ranks its candidates by
    (seed 000 §5.8.1, "the resolution of the texture used for recording every impostor layer and
    the number of layers ... can be used to obtain an estimation that is sufficiently correct
    for the candidate ranking").

    The count is ``1 + integral over the part's depth of dt / c(t)`` with ``c`` the one-texel
    spacing of Eqs. 3.2-3.5 (:func:`layer_spacing`) at the plan's texel angle, sampled at
    geometric distances; the reference offset is the first candidate's.  With ``texel_share`` the
    plan's parallax limit adds layers the one-texel spacing does not see: the estimate is not the
    plan, its ratio to the plan is what ``farfield calibrate`` measures and the memory model's
    ``h`` absorbs.  Raises LayerPlanError where :func:`plan_layers` would (part touching the cell).

    >>> from farfield.core.viewcells import ShaftCell
    >>> part = np.array([[-5.0, -5.0, 0.0], [5.0, 5.0, 20.0]])
    >>> near, far = (estimate_layers(ShaftCell([0, 0, 10.0], [1.0, 0.3, 0.1], math.radians(45), m), part, math.radians(45), 512) for m in (80.0, 320.0))
    >>> near[0] > far[0] >= 1.0, near[1].tolist(), far[1].tolist()
    (True, [128, 219], [31, 52])
    """
    check_fov(fov)
    check_resolution(resolution)
    view = part_view(cell, bounds, viewpoints=False)
    alpha = check_error_px(max_error_px) * pixel_angle(fov, resolution, pixel_model)
    s = reference_offset_candidates(view)[0]
    half_tan = np.maximum(_half_tangents(view, s), 0.5 * alpha)
    texel = alpha if texel_share is None else texel_share * alpha
    widths = 2.0 * half_tan * (view.t0 + s)
    res = np.array([texture_resolution(float(wd), view.t0, texel) for wd in widths], dtype=np.int64)
    parallax = alpha if texel_share is None else (1.0 - texel_share) * alpha
    if view.depth <= 0.0 or view.t0 >= float(
        single_layer_distance(s, float(np.hypot(*(0.5 * view.cell_width))), parallax)
    ):
        return 1.0, res  # past the pole one layer holds everything behind it (§3.3.1)
    t = np.geomspace(view.t0, view.t0 + view.depth, _ESTIMATE_SAMPLES)
    inverse = 1.0 / np.asarray(layer_spacing(t, s, view, half_tan, res), dtype=np.float64)
    count = 1.0 + float(np.sum(0.5 * (inverse[1:] + inverse[:-1]) * np.diff(t)))
    if not count <= TOL.max_layers:  # plan_layers refuses these; so does the estimate
        raise LayerPlanError(
            f"about {count:.3g} layers needed for a part {view.depth:.6g} deep at distance {view.t0:.6g}, "
            f"over {TOL.max_layers}; use a smaller view cell or a lower resolution"
        )
    return count, res


# ---------------------------------------------------------------------------------------------
# A lower bound for admission: the first layer's texels, for many cells at once
# ---------------------------------------------------------------------------------------------


def first_layer_texels(
    cell: ViewCell,
    bounds,
    fov: float,
    resolution: int,
    pixel_model: PixelModel = "min",
    texel_share: float | None = None,
    max_error_px: float = 1.0,
) -> int:
    """A lower bound of the texels of :func:`plan_layers`'s plan: one layer (every plan has at
    least one) of the smaller texture of the reference-offset candidates
    (:func:`reference_offset_candidates`; the texture is the plan's, exactly, for each).  Raises
    LayerPlanError where :func:`plan_layers` would for the part's geometry (touching the cell,
    texture over ``TOL.max_texture_resolution``).

    Not :func:`estimate_layers`: its integral runs over the part's whole depth where the plan
    skips what its first and last layers reach in front and behind, so it can exceed the plan, and
    a refusal by it could refuse a cell that the plan admits.

    >>> from farfield.core.viewcells import BoxCell
    >>> cell, part = BoxCell([-1.0, 0.0, -1.0], [1.0, 2.0, 1.0]), np.array([[-5.0, 0.0, 20.0], [5.0, 10.0, 30.0]])
    >>> plan = plan_layers(cell, part, math.radians(60), 256, "center")
    >>> first_layer_texels(cell, part, math.radians(60), 256, "center"), plan.count * int(np.prod(plan.texture_resolution))
    (15367, 92928)
    """
    check_fov(fov)
    check_resolution(resolution)
    view = part_view(cell, bounds, viewpoints=False)
    alpha = check_error_px(max_error_px) * pixel_angle(fov, resolution, pixel_model)
    texel = alpha if texel_share is None else texel_share * alpha
    least = None
    for s in reference_offset_candidates(view):
        half_tan = np.maximum(_half_tangents(view, s), 0.5 * alpha)
        widths = 2.0 * half_tan * (view.t0 + s)
        x, y = (texture_resolution(float(wd), view.t0, texel) for wd in widths)
        least = x * y if least is None else min(least, x * y)
    return least


def first_layer_texels_of_boxes(
    lo: np.ndarray,
    hi: np.ndarray,
    bounds,
    fov: float,
    resolution: int,
    pixel_model: PixelModel = "min",
    texel_share: float | None = None,
    max_error_px: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`first_layer_texels` of the box cells ``lo``, ``hi`` (n, 3) at once, in numpy:
    (texels (n,) int64, trouble (n,) bool).  A cell marked in ``trouble`` got no bound here (the
    part touches it, its texture passes ``TOL.max_texture_resolution``, a coordinate so large its
    squares overflow): ask :func:`first_layer_texels` for it, which raises or answers exactly.

    The same arithmetic as :func:`part_view` and :func:`_plan_at_offset`'s texture, per cell; the
    texture's ceiling is taken of the quotient shrunk by a further 1e-9 so that a last-bit
    difference of the vectorised sums can only lower it: the result is never above the scalar one.
    """
    check_fov(fov)
    check_resolution(resolution)
    lo = np.asarray(lo, dtype=np.float64).reshape(-1, 3)
    hi = np.asarray(hi, dtype=np.float64).reshape(-1, 3)
    b = np.asarray(bounds, dtype=np.float64).reshape(2, 3)
    if not np.all(np.isfinite(b)) or np.any(b[1] < b[0]):
        raise LayerPlanError(f"part bounds must be finite with lo <= hi, got {b.tolist()}")
    alpha = check_error_px(max_error_px) * pixel_angle(fov, resolution, pixel_model)
    texel = alpha if texel_share is None else texel_share * alpha
    corners = np.where(_CELL_CORNER_PICK[None], hi[:, None, :], lo[:, None, :])  # (n, 8, 3)
    center = 0.5 * (lo + hi)
    with np.errstate(all="ignore"):
        scale = np.maximum(np.max(np.abs(b)), np.max(np.abs(corners), axis=(1, 2)))
        touch = TOL.rel_touch * np.maximum(scale, TOL.min_extent)
        towards = 0.5 * (b[0] + b[1]) - center
        dist = np.sqrt(np.sum(towards * towards, axis=1))
        axis = towards / np.where(dist > 0.0, dist, 1.0)[:, None]
        x, y, z = axis.T
        vertical = np.abs(z) >= 0.9  # _orthonormal_frame's helper axis
        u = np.stack([np.where(vertical, 0.0, -y), np.where(vertical, -z, x), np.where(vertical, y, 0.0)], axis=1)
        u /= np.sqrt(np.sum(u * u, axis=1))[:, None]
        v = np.stack([y * u[:, 2] - z * u[:, 1], z * u[:, 0] - x * u[:, 2], x * u[:, 1] - y * u[:, 0]], axis=1)
        frame = np.stack([u, v, axis], axis=1)  # (n, 3, 3)
        rel = np.einsum("nkj,nij->nki", corners - center[:, None, :], frame)
        lo_rel, hi_rel = rel.min(axis=1), rel.max(axis=1)
        near_center = center + hi_rel[:, 2:3] * axis
        depth = hi_rel[:, 2] - lo_rel[:, 2]
        part = np.einsum("nkj,nij->nki", box_corners(b)[None] - near_center[:, None, :], frame)  # (n, 8, 3)
        t0 = part[..., 2].min(axis=1)
        trouble = ~np.isfinite(dist) | ~np.isfinite(scale) | (dist <= touch) | ~(t0 > touch)
        least = None
        for s in (np.zeros_like(depth), 0.5 * depth):  # reference_offset_candidates of a box
            half_tan = np.max(np.abs(part[..., :2]) / (part[..., 2:] + s[:, None, None]), axis=1)
            half_tan = np.maximum(half_tan, 0.5 * alpha)
            exact = 2.0 * half_tan * (t0 + s)[:, None] / (t0[:, None] * texel)
            shrunk = exact * (1.0 - TOL.rel_round) * (1.0 - 1e-9)
            trouble |= ~np.all(shrunk <= TOL.max_texture_resolution, axis=1)
            res = np.maximum(1, np.ceil(np.where(np.isfinite(shrunk), shrunk, 1.0))).astype(np.int64)
            texels = res[:, 0] * res[:, 1]
            least = texels if least is None else np.minimum(least, texels)
    return np.where(trouble, 0, least), trouble


_CELL_CORNER_PICK = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], dtype=bool)
