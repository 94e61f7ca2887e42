"""View cells: axis-aligned boxes ``(2, 3)`` float64 and square shafts, with (n, 3) float64 viewpoint queries.

A view cell is the region a viewer may be in while an impostor is valid (seed 000 §1.3, Fig. 1.2):

* :class:`BoxCell` — an axis-aligned box ``[lo, hi]`` in world units.
* :class:`ShaftCell` — a shaft whose apex lies in the represented part.  It opens along
  ``direction`` (from the part towards the viewer) with full apex angle ``apex_angle`` and starts at
  ``min_distance`` from the apex.  In 3D farfield uses a *square* cross-section (a pyramid with the
  apex angle on both image axes), so the 2D shaft of the thesis holds on each axis independently,
  exactly as the layer spacing of §3.3.1 treats the x and y axes.  ``max_distance`` may be infinite.
* :class:`SphereOutsideCell` — everything at least ``radius`` from a centre (optionally only above
  its horizon): the cell of an impostor that serves every direction from far enough away.

All geometry is float64; points are ``(n, 3)`` arrays in world units.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field

import numpy as np

from farfield.core.constants import TOL
from farfield.core.errors import ViewCellError


def _vec3(value, what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.shape != (3,):
        raise ViewCellError(f"{what} must have 3 components, got {np.asarray(value).tolist()!r}")
    if not np.all(np.isfinite(arr)):
        raise ViewCellError(f"{what} must be finite, got {arr.tolist()!r}")
    return arr


def within_range(values, what: str) -> None:
    """Refuse (:class:`ViewCellError`) a view cell's coordinates or distances past
    ``TOL.max_coordinate`` (1e12), the bound a scene's coordinates have: an impostor's output is
    written in float32 relative to its viewpoint, and a cell at 1e300 planned, then failed as an
    internal error when its GLB was written (issue 59's campaign).

    >>> within_range([1e300, 0.0, 0.0], "box lo")
    Traceback (most recent call last):
    ...
    farfield.core.errors.ViewCellError: box lo: coordinate magnitude 1e+300 exceeds the limit 1e+12 (scene coordinates are bounded alike)
    """
    arr = np.abs(np.asarray(values, dtype=np.float64).reshape(-1))
    arr = arr[np.isfinite(arr)]  # infinities (an unbounded shaft) are each kind's own to judge
    if arr.size and float(arr.max()) > TOL.max_coordinate:
        raise ViewCellError(
            f"{what}: coordinate magnitude {float(arr.max()):.6g} exceeds the limit {TOL.max_coordinate:.6g} "
            "(scene coordinates are bounded alike)"
        )


def _checked(cell):
    """``cell`` once its coordinates are within range (:func:`within_range`); what a request or a
    command line gives passes here."""
    for name in ("lo", "hi", "apex", "centre", "min_distance", "max_distance", "radius"):
        value = getattr(cell, name, None)
        if value is not None:
            within_range(value, f"view cell {name}")
    return cell


def _points(points) -> np.ndarray:
    arr = np.asarray(points, dtype=np.float64)
    return arr.reshape(-1, 3)


_CORNER_PICK = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], dtype=bool)


def box_corners(bounds) -> np.ndarray:
    """(8, 3) float64 corners of axis-aligned ``bounds`` (2, 3), x varying fastest then y then z."""
    b = np.asarray(bounds, dtype=np.float64).reshape(2, 3)
    return np.where(_CORNER_PICK, b[1], b[0])


def box_distance(lo_a: np.ndarray, hi_a: np.ndarray, lo_b: np.ndarray, hi_b: np.ndarray) -> float:
    """Euclidean distance between two axis-aligned boxes; 0 where they touch or overlap.

    >>> box_distance(np.zeros(3), np.ones(3), np.array([4., 1., 1.]), np.array([5., 2., 2.]))
    3.0
    """
    gap = np.maximum(0.0, np.maximum(lo_a - hi_b, lo_b - hi_a))
    return float(math.hypot(*gap))


@dataclass(frozen=True, slots=True)
class BoxCell:
    """An axis-aligned box view cell.

    Parameters
    ----------
    lo, hi : (3,) float64, world units
        Opposite corners with ``lo < hi`` on every axis.
    """

    lo: np.ndarray  # (3,) float64
    hi: np.ndarray  # (3,) float64
    kind: str = field(default="box", init=False)

    def __post_init__(self) -> None:
        lo = _vec3(self.lo, "box view cell lo")
        hi = _vec3(self.hi, "box view cell hi")
        size = hi - lo
        scale = max(float(np.max(np.abs(np.concatenate([lo, hi])))), 1.0)
        least = max(TOL.min_extent, scale * 1e-15)
        if np.any(size <= least):
            if np.all(size > 0):  # lo < hi holds: the box is too thin for float64 at coordinates this large
                axes = ", ".join(f"{a} {float(d):.3g}" for a, d in zip("xyz", size) if d <= least)
                raise ViewCellError(f"box view cell is too thin for coordinates up to {scale:.3g}: its size on {axes} must exceed {least:.3g} "
                                    f"(float64 resolves 1e-15 of the largest coordinate), got lo={lo.tolist()}, hi={hi.tolist()}")  # fmt: skip
            raise ViewCellError(
                f"box view cell needs lo < hi on every axis with a positive size, got lo={lo.tolist()}, hi={hi.tolist()}"
            )
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)

    @classmethod
    def from_center(cls, center, size) -> BoxCell:
        """A box of ``size`` (scalar or (3,)) around ``center`` (3,)."""
        c = _vec3(center, "box view cell centre")
        s = np.broadcast_to(np.asarray(size, dtype=np.float64), (3,))
        return cls(c - 0.5 * s, c + 0.5 * s)

    @property
    def center(self) -> np.ndarray:
        """(3,) float64 centre."""
        return 0.5 * (self.lo + self.hi)

    @property
    def size(self) -> np.ndarray:
        """(3,) float64 edge lengths."""
        return self.hi - self.lo

    def corners(self) -> np.ndarray:
        """(8, 3) float64 corners, x varying fastest then y then z."""
        return box_corners(np.stack([self.lo, self.hi]))

    def contains(self, points, tol: float = 0.0) -> np.ndarray:
        """(n,) bool: which ``points`` (n, 3) lie inside the box grown by ``tol`` on each side."""
        p = _points(points)
        return np.all((p >= self.lo - tol) & (p <= self.hi + tol), axis=1)

    def distance_to_box(self, bounds) -> float:
        """Distance from the cell to an axis-aligned ``bounds`` (2, 3); 0 when they touch or overlap."""
        b = np.asarray(bounds, dtype=np.float64).reshape(2, 3)
        return box_distance(self.lo, self.hi, b[0], b[1])

    def sample_random(self, count: int, seed: int) -> np.ndarray:
        """(count, 3) float64 points drawn uniformly inside, deterministic for ``seed``."""
        rng = np.random.default_rng(seed)
        return self.lo + rng.random((int(count), 3)) * self.size

    def to_dict(self) -> dict:
        """JSON-ready description."""
        return {"kind": "box", "lo": self.lo.tolist(), "hi": self.hi.tolist()}


def length_and_unit(vector: np.ndarray) -> tuple[float, np.ndarray]:
    """(length, unit vector) of a (3,) float64 vector, also where its squares overflow or underflow
    (a difference of coordinates near 1e300): then scaled by its largest component first.  Where
    they do not, exactly ``norm`` and ``vector / norm``, so the results of ordinary inputs stay bit
    for bit what they were.  (0, zeros) for the zero vector.

    >>> length_and_unit(np.array([3e300, 4e300, 0.0]))[1].tolist()
    [0.6, 0.8, 0.0]
    """
    vector = np.asarray(vector, dtype=np.float64)
    with np.errstate(over="ignore", under="ignore"):
        norm = float(np.linalg.norm(vector))
    if math.isfinite(norm) and norm > 0.0:
        return norm, vector / norm
    largest = float(np.max(np.abs(vector)))
    if largest == 0.0 or not math.isfinite(largest):
        return largest, np.zeros(3)
    scaled = vector / largest
    norm = float(np.linalg.norm(scaled))
    return largest * norm, scaled / norm


def _orthonormal_frame(direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (3,) perpendicular to unit ``direction`` and to each other, deterministic.

    The first is horizontal (perpendicular to world z) unless ``direction`` is vertical.
    """
    # Written out (np.cross on 3-vectors costs more than the arithmetic; placements ask for many frames).
    x, y, z = (float(c) for c in direction)
    if abs(z) < 0.9:  # helper (0, 0, 1)
        ux, uy, uz = -y, x, 0.0
    else:  # helper (1, 0, 0)
        ux, uy, uz = 0.0, -z, y
    norm = math.sqrt(ux * ux + uy * uy + uz * uz)
    u = np.array([ux / norm, uy / norm, uz / norm])
    v = np.array([y * u[2] - z * u[1], z * u[0] - x * u[2], x * u[1] - y * u[0]])
    return u, v


@dataclass(frozen=True, slots=True)
class ShaftCell:
    """A square shaft view cell (seed 000 §1.3, Fig. 1.2).

    Parameters
    ----------
    apex : (3,) float64, world units
        Apex, in the centre of the represented part.
    direction : (3,) float64
        Axis from the apex towards the viewer; normalised on construction.
    apex_angle : float
        Full apex angle in radians, in (0, π).
    min_distance : float
        Distance (world units) from the apex to the near end of the shaft, > 0.
    max_distance : float
        Distance to the far end; ``inf`` for an unbounded shaft.
    """

    apex: np.ndarray  # (3,) float64
    direction: np.ndarray  # (3,) float64 unit
    apex_angle: float
    min_distance: float
    max_distance: float = math.inf
    kind: str = field(default="shaft", init=False)

    def __post_init__(self) -> None:
        apex = _vec3(self.apex, "shaft apex")
        d = _vec3(self.direction, "shaft direction")
        norm, _ = length_and_unit(d)
        if norm == 0.0:
            raise ViewCellError("shaft direction must be non-zero")
        if not (math.isfinite(self.apex_angle) and 0.0 < self.apex_angle < math.pi):
            raise ViewCellError(f"shaft apex angle must lie in (0°, 180°), got {math.degrees(self.apex_angle)!r}°")
        if not (math.isfinite(self.min_distance) and self.min_distance > 0.0):
            raise ViewCellError(f"shaft min_distance must be finite and > 0, got {self.min_distance!r}")
        if not self.max_distance > self.min_distance:
            raise ViewCellError(
                f"shaft max_distance ({self.max_distance!r}) must exceed min_distance ({self.min_distance!r})"
            )
        object.__setattr__(self, "apex", apex)
        object.__setattr__(self, "direction", d / norm)
        object.__setattr__(self, "apex_angle", float(self.apex_angle))
        object.__setattr__(self, "min_distance", float(self.min_distance))
        object.__setattr__(self, "max_distance", float(self.max_distance))

    @property
    def bounded(self) -> bool:
        return math.isfinite(self.max_distance)

    @property
    def half_tan(self) -> float:
        """tan(apex_angle / 2)."""
        return math.tan(0.5 * self.apex_angle)

    def frame(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(u, v, direction): the shaft's orthonormal frame, each (3,) float64."""
        u, v = _orthonormal_frame(self.direction)
        return u, v, self.direction

    def half_width(self, distance: float) -> float:
        """Half the side of the square cross-section at ``distance`` from the apex."""
        return float(distance) * self.half_tan

    @property
    def center(self) -> np.ndarray:
        """(3,) float64 centre of the near cap (the nearest point of the shaft's axis to the part)."""
        return self.apex + self.min_distance * self.direction

    def corners(self) -> np.ndarray:
        """(4, 3) or (8, 3) float64 corners: the near cap's four, then the far cap's if bounded."""
        u, v, d = self.frame()
        signs = np.array([[-1, -1], [1, -1], [-1, 1], [1, 1]], dtype=np.float64)
        caps = [self.min_distance] + ([self.max_distance] if self.bounded else [])
        out = []
        for dist in caps:
            h = self.half_width(dist)
            out.append(self.apex + dist * d + h * (signs[:, :1] * u + signs[:, 1:] * v))
        return np.concatenate(out, axis=0)

    def contains(self, points, tol: float = 0.0) -> np.ndarray:
        """(n,) bool: which ``points`` (n, 3) lie in the shaft (grown by ``tol`` along each bound)."""
        p = _points(points) - self.apex
        u, v, d = self.frame()
        along = p @ d
        lateral = np.maximum(np.abs(p @ u), np.abs(p @ v))
        return (
            (along >= self.min_distance - tol)
            & (along <= self.max_distance + tol)
            & (lateral <= along * self.half_tan + tol)
        )

    def distance_to_box(self, bounds) -> float:
        """Distance from the shaft's near cap to an axis-aligned ``bounds`` (2, 3).

        The part a shaft serves lies around its apex, behind the near cap, so the near cap is the
        nearest the viewer comes; this is the distance from the cap (a square) to the box.
        """
        from scipy.optimize import minimize

        b = np.asarray(bounds, dtype=np.float64).reshape(2, 3)
        u, v, d = self.frame()
        h = self.half_width(self.min_distance)
        c = self.center

        def dist2(x):
            p = c + h * (x[0] * u + x[1] * v)
            q = np.clip(p, b[0], b[1])
            return float(np.sum((p - q) ** 2))

        # The squared distance from an affine image of the square to a box is convex: one local
        # minimisation from the cap's centre finds the global minimum.
        best = minimize(dist2, np.zeros(2), bounds=[(-1, 1), (-1, 1)], method="L-BFGS-B").fun
        return math.sqrt(max(best, 0.0))

    def sample_random(self, count: int, seed: int, depth: float | None = None) -> np.ndarray:
        """(count, 3) float64 points in the shaft, deterministic for ``seed``.

        Distances are drawn uniformly in ``[min_distance, far]`` with ``far = max_distance``, or
        ``min_distance + depth`` for an unbounded shaft (``depth`` then required).
        """
        if self.bounded:
            far = self.max_distance
        elif depth is not None and depth > 0.0:
            far = self.min_distance + float(depth)
        else:
            raise ViewCellError("sampling an unbounded shaft needs a positive depth")
        rng = np.random.default_rng(seed)
        u, v, d = self.frame()
        r = rng.random((int(count), 3))
        dist = self.min_distance + r[:, 0] * (far - self.min_distance)
        h = dist * self.half_tan
        lat_u = (2.0 * r[:, 1] - 1.0) * h
        lat_v = (2.0 * r[:, 2] - 1.0) * h
        return self.apex + dist[:, None] * d + lat_u[:, None] * u + lat_v[:, None] * v

    def to_dict(self) -> dict:
        """JSON-ready description."""
        return {
            "kind": "shaft",
            "apex": self.apex.tolist(),
            "direction": self.direction.tolist(),
            "apex_angle_deg": math.degrees(self.apex_angle),
            "min_distance": self.min_distance,
            "max_distance": self.max_distance if self.bounded else None,
        }


@dataclass(frozen=True, slots=True)
class SphereOutsideCell:
    """Everything beyond a distance from a point: the view cell of an impostor that serves every
    direction from far enough away (an octahedral impostor, docs/techniques/octahedral.md).

    Parameters
    ----------
    centre : (3,) float64, world units
        The centre of the part (its bounding sphere's).
    radius : float
        The nearest a viewpoint comes to ``centre``, world units, > 0.
    hemisphere : bool
        Only viewpoints at or above the horizontal plane through ``centre`` (world +z up): the
        cell of an impostor never seen from below.
    """

    centre: np.ndarray  # (3,) float64
    radius: float
    hemisphere: bool = False
    kind: str = field(default="outside-sphere", init=False)

    def __post_init__(self) -> None:
        centre = _vec3(self.centre, "outside-sphere view cell centre")
        if not (isinstance(self.radius, int | float) and math.isfinite(self.radius) and self.radius > 0.0):
            raise ViewCellError(f"outside-sphere view cell radius must be finite and > 0, got {self.radius!r}")
        object.__setattr__(self, "centre", centre)
        object.__setattr__(self, "radius", float(self.radius))
        object.__setattr__(self, "hemisphere", bool(self.hemisphere))

    @property
    def center(self) -> np.ndarray:
        """(3,) float64 a viewpoint of the cell standing for it (the reference viewpoint): on the
        sphere, 45° above the horizon towards +x."""
        return self.centre + self.radius * np.array([math.sqrt(0.5), 0.0, math.sqrt(0.5)])

    def corners(self) -> np.ndarray:
        """(k, 3) float64 viewpoints on the sphere an evaluation always takes: straight down from
        above, grazing (on the horizon, 1° above it for a hemisphere) from four sides, four at
        45°, and for a full sphere straight up from below and four at 45° below.

        >>> SphereOutsideCell([0.0, 0.0, 0.0], 2.0, hemisphere=True).corners()[:2].round(3).tolist()
        [[0.0, 0.0, 2.0], [2.0, 0.0, 0.035]]
        """
        graze = math.radians(1.0) if self.hemisphere else 0.0
        elevations = [math.pi / 2, graze, math.pi / 4] + ([] if self.hemisphere else [-math.pi / 2, -math.pi / 4])
        directions = []
        for elevation in elevations:
            azimuths = (
                [0.0] if abs(abs(elevation) - math.pi / 2) < 1e-12 else [0.0, math.pi / 2, math.pi, 1.5 * math.pi]
            )
            offset = (
                math.pi / 4 if abs(elevation - math.pi / 4) < 1e-12 or abs(elevation + math.pi / 4) < 1e-12 else 0.0
            )
            for azimuth in azimuths:
                a = azimuth + offset
                directions.append(
                    [math.cos(elevation) * math.cos(a), math.cos(elevation) * math.sin(a), math.sin(elevation)]
                )
        return self.centre + self.radius * np.round(np.array(directions), 15)

    def contains(self, points, tol: float = 0.0) -> np.ndarray:
        """(n,) bool: which ``points`` (n, 3) lie at least ``radius - tol`` from the centre (and, for
        a hemisphere, no more than ``tol`` below its horizontal plane)."""
        p = _points(points) - self.centre
        inside = np.linalg.norm(p, axis=1) >= self.radius * (1.0 - 1e-12) - tol
        if self.hemisphere:
            inside &= p[:, 2] >= -tol - 1e-12 * self.radius
        return inside

    def distance_to_box(self, bounds) -> float:
        """Distance from the cell to an axis-aligned ``bounds`` (2, 3): 0 where the box reaches
        beyond the sphere, else the radius less the box's farthest corner's distance from the centre
        (a lower bound for a hemisphere)."""
        corners = box_corners(bounds)
        return max(0.0, self.radius - float(np.linalg.norm(corners - self.centre, axis=1).max()))

    def sample_random(self, count: int, seed: int, depth: float | None = None) -> np.ndarray:
        """(count, 3) float64 viewpoints, deterministic for ``seed``: directions uniform over the
        sphere (or the upper hemisphere), distances uniform in ``[radius, radius + depth]``
        (``depth`` by default the radius: out to twice the nearest distance).

        >>> cell = SphereOutsideCell([1.0, 2.0, 3.0], 5.0, hemisphere=True)
        >>> bool(cell.contains(cell.sample_random(100, 0)).all())
        True
        """
        rng = np.random.default_rng(seed)
        direction = rng.normal(size=(int(count), 3))
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        if self.hemisphere:
            direction[:, 2] = np.abs(direction[:, 2])
        far = self.radius if depth is None else float(depth)
        distance = self.radius + rng.random(int(count)) * far
        return self.centre + distance[:, None] * direction

    def to_dict(self) -> dict:
        """JSON-ready description."""
        return {
            "kind": "outside-sphere",
            "centre": self.centre.tolist(),
            "radius": self.radius,
            "hemisphere": self.hemisphere,
        }


ViewCell = BoxCell | ShaftCell | SphereOutsideCell


def sample_viewpoints(cell: ViewCell, random_count: int = 0, seed: int = 0, depth: float | None = None) -> np.ndarray:
    """(k, 3) float64 evaluation viewpoints: the cell's corners, its centre, then ``random_count`` random points.

    Deterministic for ``seed``; every returned point satisfies ``cell.contains``.
    """
    corners = cell.corners()
    if isinstance(cell, ShaftCell):
        random = cell.sample_random(random_count, seed, depth) if random_count else np.empty((0, 3))
    else:
        random = cell.sample_random(random_count, seed)
    return np.concatenate([corners, cell.center[None, :], random], axis=0)


def parse_viewcell(spec: str) -> ViewCell:
    """Parse a CLI view-cell spec.

    * ``box:x0,y0,z0,x1,y1,z1`` — corners;
    * ``box-center:cx,cy,cz,size`` — a cube;
    * ``shaft:ax,ay,az,dx,dy,dz,apex_deg,min_distance[,max_distance]``.
    * ``outside:cx,cy,cz,radius`` (``outside-hemi:...``: above the centre's horizon only).

    >>> parse_viewcell("box-center:0,0,0,10").size.tolist()
    [10.0, 10.0, 10.0]
    """
    return _checked(_parse_viewcell(spec))


def _parse_viewcell(spec: str) -> ViewCell:
    kind, _, rest = spec.partition(":")
    try:
        nums = [float(x) for x in rest.split(",")] if rest else []
    except ValueError:
        raise ViewCellError(f"view cell {spec!r}: numbers expected after '{kind}:'") from None
    if kind == "box" and len(nums) == 6:
        return BoxCell(nums[:3], nums[3:])
    if kind == "box-center" and len(nums) == 4:
        return BoxCell.from_center(nums[:3], nums[3])
    if kind == "shaft" and len(nums) in (8, 9):
        return ShaftCell(nums[:3], nums[3:6], math.radians(nums[6]), nums[7], nums[8] if len(nums) == 9 else math.inf)
    if kind in ("outside", "outside-hemi") and len(nums) == 4:
        return SphereOutsideCell(nums[:3], nums[3], hemisphere=kind == "outside-hemi")
    raise ViewCellError(
        f"view cell {spec!r} not understood; use box:x0,y0,z0,x1,y1,z1 | box-center:cx,cy,cz,size | "
        "shaft:ax,ay,az,dx,dy,dz,apex_deg,min_distance[,max_distance] | outside[-hemi]:cx,cy,cz,radius"
    )


def viewcell_from_dict(data: dict) -> ViewCell:
    """Inverse of ``BoxCell.to_dict`` / ``ShaftCell.to_dict`` (bundle manifests, API payloads);
    coordinates past ``TOL.max_coordinate`` are refused (:func:`within_range`)."""
    return _checked(_viewcell_from_dict(data))


def _number(data: dict, key: str) -> float:
    """``data[key]``, a number: not a bool nor a string (``true`` or ``"1"`` read as 1 is a loose type
    the job's other fields refuse too)."""
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ViewCellError(f"{data.get('kind')} view cell {key} must be a number, got {value!r}")
    return float(value)


def _point(data: dict, key: str):
    """``data[key]``, three numbers (a list, or an array of a numeric dtype)."""
    value = data[key]
    if isinstance(value, np.ndarray) and value.dtype.kind in "iuf":
        return value
    if not isinstance(value, (list, tuple)) or not all(
        isinstance(v, numbers.Real) and not isinstance(v, bool) for v in value
    ):
        raise ViewCellError(f"{data.get('kind')} view cell {key} must be 3 numbers, got {value!r}")
    return value


def _viewcell_from_dict(data: dict) -> ViewCell:
    try:
        kind = data["kind"]
        if kind == "box":
            return BoxCell(_point(data, "lo"), _point(data, "hi"))
        if kind == "outside-sphere":
            hemisphere = data.get("hemisphere", False)
            if not isinstance(hemisphere, bool):
                raise ViewCellError(f"outside-sphere view cell hemisphere must be true or false, got {hemisphere!r}")
            return SphereOutsideCell(_point(data, "centre"), _number(data, "radius"), hemisphere)
        if kind == "shaft":
            far = data.get("max_distance")
            return ShaftCell(
                _point(data, "apex"),
                _point(data, "direction"),
                math.radians(_number(data, "apex_angle_deg")),
                _number(data, "min_distance"),
                math.inf if far is None else _number(data, "max_distance"),
            )
    except (KeyError, TypeError, ValueError) as error:
        raise ViewCellError(f"view cell description {data!r} is incomplete: {error}") from None
    raise ViewCellError(
        f"unknown view cell kind {data.get('kind')!r}; known kinds: 'box' (lo, hi), 'shaft' (apex, direction, "
        "apex_angle_deg, min_distance[, max_distance]), 'outside-sphere' (centre, radius[, hemisphere])"
    )


@dataclass(frozen=True)
class BoxCells:
    """Many box view cells as arrays (``lo``, ``hi``: (n, 3) float64), for work in O(cells) without
    a :class:`BoxCell` object each (a job of 10,000 cells); ``cells[n]`` is the n-th as a :class:`BoxCell`."""

    lo: np.ndarray
    hi: np.ndarray

    def __len__(self) -> int:
        return len(self.lo)

    def __getitem__(self, n: int) -> BoxCell:
        return BoxCell(self.lo[n], self.hi[n])

    def to_dicts(self) -> list[dict]:
        """Each cell's :meth:`BoxCell.to_dict`."""
        return [{"kind": "box", "lo": lo, "hi": hi} for lo, hi in zip(self.lo.tolist(), self.hi.tolist(), strict=True)]


def grid_box_cells(lo, hi, counts) -> tuple[np.ndarray, BoxCells]:
    """:func:`grid_boxes` as arrays: ((n, 3) int64 (i, j, k), :class:`BoxCells`), the same cells in
    the same order with bit-identical coordinates (the same float64 operations, element by
    element), in numpy.  A grid of cells too thin for float64 is refused as :func:`grid_boxes` does.

    >>> ijk, boxes = grid_box_cells([0, 0, 0], [2, 1, 1], [2, 1, 1])
    >>> ijk.tolist(), boxes.to_dicts() == [box.to_dict() for _, box in grid_boxes([0, 0, 0], [2, 1, 1], [2, 1, 1])]
    ([[0, 0, 0], [1, 0, 0]], True)
    """
    lo, hi = _vec3(lo, "grid lo"), _vec3(hi, "grid hi")
    counts = np.asarray(counts, dtype=np.int64)
    if counts.shape != (3,) or np.any(counts < 1) or not (hi > lo).all():
        grid_boxes(lo, hi, counts)  # raises its own error
    with np.errstate(over="ignore"):
        if not np.isfinite(hi - lo).all():
            grid_boxes(lo, hi, counts)
    within_range(np.concatenate([lo, hi]), "grid")
    step = (hi - lo) / counts
    k, j, i = np.meshgrid(*(np.arange(c, dtype=np.int64) for c in counts[::-1]), indexing="ij")
    ijk = np.stack([i.ravel(), j.ravel(), k.ravel()], axis=1)  # x fastest
    lower = lo + step * ijk
    upper = np.where(ijk + 1 == counts, hi, lo + step * (ijk + 1))
    scale = np.maximum(np.max(np.abs(np.concatenate([lower, upper], axis=1)), axis=1), 1.0)
    least = np.maximum(TOL.min_extent, scale * 1e-15)
    thin = np.flatnonzero(np.any(upper - lower <= least[:, None], axis=1))
    if thin.size:
        BoxCell(lower[thin[0]], upper[thin[0]])  # raises BoxCell's own error
    return ijk, BoxCells(lower, upper)


def grid_boxes(lo, hi, counts) -> list[tuple[tuple[int, int, int], BoxCell]]:
    """The equal boxes of a grid of ``counts`` (3,) cells over the box ``lo``..``hi``, x fastest,
    each with its (i, j, k).  Shared faces come from the same products, so neighbours meet exactly.

    >>> [(ijk, box.lo.tolist()) for ijk, box in grid_boxes([0, 0, 0], [2, 1, 1], [2, 1, 1])]
    [((0, 0, 0), [0.0, 0.0, 0.0]), ((1, 0, 0), [1.0, 0.0, 0.0])]
    """
    lo, hi = _vec3(lo, "grid lo"), _vec3(hi, "grid hi")
    counts = np.asarray(counts, dtype=np.int64)
    if counts.shape != (3,) or np.any(counts < 1):
        raise ViewCellError(f"grid counts must be three integers >= 1, got {np.asarray(counts).tolist()}")
    if not (hi > lo).all():
        raise ViewCellError(f"grid box needs lo < hi on every axis, got lo={lo.tolist()}, hi={hi.tolist()}")
    with np.errstate(over="ignore"):
        overflow = not np.isfinite(hi - lo).all()
    if overflow:
        raise ViewCellError(f"grid box's size hi - lo is not finite in float64, got lo={lo.tolist()}, hi={hi.tolist()}")
    within_range(np.concatenate([lo, hi]), "grid")
    step = (hi - lo) / counts
    cells = []
    for k in range(counts[2]):
        for j in range(counts[1]):
            for i in range(counts[0]):
                index = np.array([i, j, k])
                upper = np.where(index + 1 == counts, hi, lo + step * (index + 1))
                cells.append(((i, j, k), BoxCell(lo + step * index, upper)))
    return cells
