"""Where point-based impostors sample a part: the sampling plane, the three LDI cameras and their resolution.

Seed 001 (Wimmer, Wonka, Sillion 2001) §3 and §5.1.  A point-based impostor of a part, for a box view
cell, samples the part's surfaces with three perspective layered depth images (LDIs) whose cameras
stand on the *sampling plane*:

1. **The sampling plane** (§5.1: "a plane oriented from the view cell towards the far field") has
   the unit normal ``n`` from the cell's centre towards the part's centre and passes through the
   cell's corner farthest along ``n``, so the whole cell lies behind it and every viewer's ray to
   the part crosses it.  The part must lie wholly beyond it (``D > 0`` below), else there is no
   such plane and :class:`~farfield.core.errors.ViewCellError` says so.
2. **The polygon** (§5.1: "the intersection of the supporting planes of the view cell and the far
   field with the sampling plane") is the cross-section of the convex hull of cell and part with
   the plane.  It holds the point where any viewer's ray to any point of the part crosses the
   plane: the cross-section of a point set's hull is the hull of where the segments between
   points on opposite sides cross the plane (:func:`cross_section`).
3. **The cameras** stand at the vertices of the triangle of least perimeter that encloses the
   polygon (§5.1: "the triangle with minimum circumference", :func:`min_perimeter_triangle`).
4. **The LDI cameras** all look along the plane's normal, each through the off-axis square window
   that holds the part's box (:class:`LdiCamera`), at the resolution of §5.1's three factors,
   written out in :func:`ldi_resolution`.

Everything is float64 in world units; angles are radians unless a name ends in ``_deg``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import minimize
from scipy.spatial import ConvexHull, QhullError

from farfield.core.constants import TOL
from farfield.core.errors import LayerPlanError, ViewCellError
from farfield.core.pixel_angles import check_error_px, check_fov, check_resolution
from farfield.core.render.raster import Camera
from farfield.core.viewcells import BoxCell, box_corners, length_and_unit

# An LDI window wider than this (half side in image tangents, the tangent of 80°) samples too
# obliquely at its border to be of use.
MAX_LDI_HALF_SIZE = math.tan(math.radians(80.0))


def plane_frame(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (3,) u, v spanning the plane perpendicular to unit ``normal``, deterministic
    (u horizontal in world x-z unless ``normal`` is nearly vertical along y), with u × v = -normal:
    as a camera's right, up and forward they make the frame :meth:`Camera.look_at
    <farfield.core.render.raster.Camera.look_at>` makes, so images are not mirrored.

    >>> u, v = plane_frame(np.array([0.0, 0.0, 1.0]))
    >>> (u + 0.0).tolist(), (v + 0.0).tolist()
    ([-1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    """
    helper = np.array([0.0, 1.0, 0.0]) if abs(float(normal[1])) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(normal, helper)
    u /= np.linalg.norm(u)
    v = np.cross(u, normal)
    return u, v


def cross_section(behind: np.ndarray, beyond: np.ndarray, normal: np.ndarray, offset: float) -> np.ndarray:
    """(m, 3) points whose convex hull is the cross-section of the hull of ``behind`` (n·x <= offset)
    and ``beyond`` (n·x > offset) with the plane ``n·x = offset``: ``behind``'s points on the plane
    and where each segment from a ``behind`` point to a ``beyond`` point crosses it.

    >>> pts = cross_section(np.array([[0.0, 0, 0], [0, 1, 0]]), np.array([[2.0, 0, 0], [2, 3, 0]]), np.array([1.0, 0, 0]), 1.0)
    >>> sorted(map(tuple, pts.round(6).tolist()))
    [(1.0, 0.0, 0.0), (1.0, 0.5, 0.0), (1.0, 1.5, 0.0), (1.0, 2.0, 0.0)]
    """
    a, b = np.asarray(behind, dtype=np.float64), np.asarray(beyond, dtype=np.float64)
    da, db = a @ normal - offset, b @ normal - offset
    if np.any(da > 0.0) or np.any(db <= 0.0):
        raise ValueError(
            "cross_section needs every 'behind' point at or behind the plane and every 'beyond' point beyond it"
        )
    t = -da[:, None] / (db[None, :] - da[:, None])  # (na, nb) in [0, 1)
    points = a[:, None, :] + t[..., None] * (b[None, :, :] - a[:, None, :])
    return points.reshape(-1, 3)


def convex_polygon(points_2d: np.ndarray) -> np.ndarray:
    """(k, 2) the convex hull of ``points_2d`` (m, 2), counter-clockwise, k >= 3."""
    try:
        hull = ConvexHull(points_2d)
    except QhullError as error:
        raise ViewCellError(
            f"the view cell and the part span no area on the sampling plane: {str(error).splitlines()[0]}"
        ) from None
    return points_2d[hull.vertices]


def _support(polygon: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Support function h(θ) = max_i p_i · (cos θ, sin θ) of ``polygon`` (k, 2) at ``angles`` (...)."""
    directions = np.stack([np.cos(angles), np.sin(angles)], axis=-1)
    return np.max(directions @ polygon.T, axis=-1)


def _triangle(polygon: np.ndarray, angles: np.ndarray) -> np.ndarray | None:
    """(3, 2) vertices of the triangle bounded by the supporting lines of ``polygon`` with outward
    normal angles ``angles`` (3,), or None when those normals do not positively span the plane
    (consecutive gaps must be < π, else the three lines bound no triangle around the polygon)."""
    order = np.sort(np.mod(angles, 2.0 * math.pi))
    gaps = np.diff(np.concatenate([order, [order[0] + 2.0 * math.pi]]))
    if np.any(gaps >= math.pi - 1e-9) or np.any(gaps <= 1e-9):
        return None
    h = _support(polygon, order)
    normals = np.stack([np.cos(order), np.sin(order)], axis=1)
    vertices = []
    for i in range(3):
        j = (i + 1) % 3
        vertices.append(np.linalg.solve(normals[[i, j]], h[[i, j]]))
    return np.array(vertices)


def _cross2(a: np.ndarray, b: np.ndarray) -> float:
    """z of the cross product of 2-vectors ``a`` and ``b``."""
    return float(a[0] * b[1] - a[1] * b[0])


def _perimeter(triangle: np.ndarray) -> float:
    return float(np.sum(np.linalg.norm(triangle - np.roll(triangle, -1, axis=0), axis=1)))


def min_perimeter_triangle(polygon: np.ndarray) -> np.ndarray:
    """(3, 2) counter-clockwise vertices of the least-perimeter triangle enclosing the convex
    ``polygon`` (k, 2) (seed 001 §5.1).

    Every side of a least-perimeter enclosing triangle touches the polygon: a side that does not
    can move inward parallel to itself, which scales the triangle down about the opposite vertex.
    So the triangle is bounded by three *supporting lines* of the polygon, fixed by the angles of
    their outward normals (consecutive gaps < π), and the perimeter is a function of those three
    angles only.  It is minimised by Nelder-Mead from several starts: equilateral normal fans at
    5° steps, and one side flush with each polygon edge.  Tested against a brute-force search
    over all normal triples on a 2° grid and against the circle's answer (equilateral, 6√3 r).

    >>> square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    >>> t = min_perimeter_triangle(square)
    >>> round(float(np.sum(np.linalg.norm(t - np.roll(t, -1, axis=0), axis=1))), 4)
    6.4574
    """
    polygon = np.asarray(polygon, dtype=np.float64)
    centre = polygon.mean(axis=0)
    local = polygon - centre  # perimeters are translation-invariant; solve near the origin

    def cost(angles: np.ndarray) -> float:
        triangle = _triangle(local, angles)
        return math.inf if triangle is None else _perimeter(triangle)

    starts = [np.radians([a, a + 120.0, a + 240.0]) for a in np.arange(0.0, 120.0, 5.0)]
    edges = np.roll(local, -1, axis=0) - local
    for dx, dy in edges:  # one side flush with this edge: its outward normal (counter-clockwise polygon)
        flush = math.atan2(-dx, dy)
        starts.append(np.array([flush, flush + 2.0 * math.pi / 3.0, flush + 4.0 * math.pi / 3.0]))
    ranked = sorted(starts, key=cost)
    best, best_cost = ranked[0], cost(ranked[0])
    for start in ranked[:8]:
        result = minimize(cost, start, method="Nelder-Mead", options={"xatol": 1e-10, "fatol": 1e-12, "maxiter": 4000})
        if result.fun < best_cost:
            best, best_cost = result.x, float(result.fun)
    triangle = _triangle(local, best)
    area2 = _cross2(triangle[1] - triangle[0], triangle[2] - triangle[0])
    if area2 < 0.0:
        triangle = triangle[::-1]
    return triangle + centre


def farthest_from_cameras(polygon: np.ndarray, cameras: np.ndarray, boundary: bool = False) -> tuple[float, np.ndarray]:
    """(R, q): the largest distance from a point q of the convex ``polygon`` (k, 2) (of its
    boundary only, if ``boundary``) to its nearest of ``cameras`` (3, 2), and that point.

    Inside one camera's Voronoi region the distance to that camera is convex, so its maximum over
    (region ∩ polygon) lies at a vertex of that convex piece: a polygon vertex, a point where a
    bisector of two cameras crosses a polygon edge, or the cameras' circumcentre (the Voronoi
    vertex) when it lies inside the polygon.  For an acute triangle with the polygon around its
    circumcentre this is the circumcentre, seed 001 §5.1's "point equidistant from the three
    cameras"; for an obtuse one it is not.

    >>> cams = np.array([[0.0, 0.0], [2.0, 0.0], [1.0, 2.0]])
    >>> r, q = farthest_from_cameras(np.array([[0.5, 0.2], [1.5, 0.2], [1.0, 1.2]]), cams)
    >>> round(r, 4), q.round(4).tolist()
    (1.25, [1.0, 0.75])
    >>> r, q = farthest_from_cameras(np.array([[0.5, 0.2], [1.5, 0.2], [1.0, 1.2]]), cams, boundary=True)
    >>> round(r, 4), q.round(4).tolist()
    (1.1739, [0.82, 0.84])
    """
    polygon, cameras = np.asarray(polygon, dtype=np.float64), np.asarray(cameras, dtype=np.float64)
    candidates = [polygon]
    starts, ends = polygon, np.roll(polygon, -1, axis=0)
    for i in range(len(cameras)):
        for j in range(i + 1, len(cameras)):
            # Bisector: points x with (x - m) · d = 0, m the midpoint, d = c_j - c_i.
            m, d = 0.5 * (cameras[i] + cameras[j]), cameras[j] - cameras[i]
            fs, fe = (starts - m) @ d, (ends - m) @ d
            crossing = (fs * fe) < 0.0
            t = fs[crossing] / (fs[crossing] - fe[crossing])
            candidates.append(starts[crossing] + t[:, None] * (ends[crossing] - starts[crossing]))
    a, b, c = cameras[:3]
    det = 2.0 * _cross2(b - a, c - a)
    if abs(det) > 0.0:
        ab, ac = b - a, c - a
        centre = a + np.array([ac[1] * (ab @ ab) - ab[1] * (ac @ ac), ab[0] * (ac @ ac) - ac[0] * (ab @ ab)]) / det
        edges = ends - starts
        inside = np.all(edges[:, 0] * (centre[1] - starts[:, 1]) - edges[:, 1] * (centre[0] - starts[:, 0]) >= 0.0)
        if inside and not boundary:
            candidates.append(centre[None, :])
    points = np.concatenate(candidates)
    nearest = np.min(np.linalg.norm(points[:, None, :] - cameras[None, :, :], axis=2), axis=1)
    k = int(np.argmax(nearest))
    return float(nearest[k]), points[k]


def movement_factor(reach: float, depth: float, boundary_reach: float | None = None) -> float:
    """How much finer than an output pixel an LDI must sample for viewers anywhere in the cell
    (seed 001 §5.1, "movement within the view cell"), with ``reach`` R the largest distance from a
    polygon point to its nearest camera, ``boundary_reach`` R_b the same over the polygon's
    boundary (:func:`farthest_from_cameras`; default R) and ``depth`` D the smallest distance of
    the part from the sampling plane.

    Derivation.  A sample at p, height h >= D over the plane, is taken by its nearest camera c at
    distance sqrt(h² + r²), r the lateral distance from p's foot x to c; neighbouring samples of
    an LDI ray spacing α lie about α sqrt(h² + r²) apart.  A viewer sees them at most under that
    spacing over its distance to p.  Viewers behind the plane see less than the point where their
    ray crosses the plane (same direction, farther), which lies in the polygon, so viewers on the
    polygon bound all.  A viewer at lateral distance e from x is sqrt(h² + e²) away, so the ratio
    to α is at most sqrt((h² + r²) / (h² + e²)).

    - x in the polygon: a viewer stands at x (e = 0) and r <= R: sqrt(1 + R²/h²).
    - x a distance e > 0 outside it: the nearest polygon point y lies on the boundary, so
      r <= R_b + e, and (h² + (R_b + e)²) / (h² + e²) = 1 + (2e R_b + R_b²) / (h² + e²) peaks at
      e* = (sqrt(R_b² + 4h²) - R_b) / 2 with the value 1 + R_b / e*.

    Both fall as h grows, so h = D gives

        F_move = sqrt(max(1 + R²/D², 1 + 2 R_b / (sqrt(R_b² + 4D²) - R_b)))

    >>> movement_factor(0.0, 1.0), round(movement_factor(1.0, 1.0), 4), round(movement_factor(1.0, 100.0, 0.0), 6)
    (1.0, 1.618, 1.00005)
    """
    if not depth > 0.0:
        raise LayerPlanError(f"the part must lie beyond the sampling plane, got depth {depth!r}")
    outer = reach if boundary_reach is None else boundary_reach
    inside = 1.0 + (reach / depth) ** 2
    if outer <= 0.0:
        return math.sqrt(inside)
    root = math.sqrt(outer * outer + 4.0 * depth * depth)
    # 2 R_b / (root - R_b) = (root + R_b) R_b / (2 D²), without the cancellation of root - R_b when R_b >> D.
    return math.sqrt(max(inside, 1.0 + (root + outer) * outer / (2.0 * depth * depth)))


def corner_perspective_factor(fov: float) -> float:
    """1 / cos² of the angle between a square output frame's axis and its corner ray: how much
    smaller a pixel's radial angle is at the corner than at the centre (seed 001 §5.1,
    "perspective"; the paper's 1.17 at 45° is this factor at the middle of an edge,
    1 + tan²(fov/2); the corner, 1 + 2 tan²(fov/2), is where the criterion is tightest).

    >>> round(corner_perspective_factor(math.radians(45.0)), 4)
    1.3431
    """
    t = math.tan(0.5 * check_fov(fov))
    return 1.0 + 2.0 * t * t


@dataclass(frozen=True, slots=True)
class LdiCamera:
    """One of the three LDI cameras: at ``position`` on the sampling plane, looking along the
    plane's normal (its image axes the plane's u and v), with an off-axis square window: image
    tangents x/z and y/z within ``centre`` ± ``half_size``, ``resolution`` pixels per side.

    All three look the same way, so the part (wholly beyond the plane) is in front of each; the
    window is the smallest square holding the part's box."""

    position: np.ndarray  # (3,) float64 world, a vertex of the triangle on the sampling plane
    forward: np.ndarray  # (3,) unit: the sampling plane's normal
    right: np.ndarray  # (3,) unit: the plane's u
    up: np.ndarray  # (3,) unit: the plane's v
    centre: tuple[float, float]  # the window's centre, image tangents
    half_size: float  # the window's half side, image tangents
    resolution: int
    near: float
    far: float

    def camera(self) -> Camera:
        """This LDI's view as a :class:`~farfield.core.render.raster.Camera` (off-axis)."""
        return Camera(
            self.position,
            self.right,
            self.up,
            self.forward,
            2.0 * math.atan(self.half_size),
            self.resolution,
            self.near,
            self.far,
            self.centre,
        )

    def to_dict(self) -> dict:
        return {
            "position": self.position.tolist(), "forward": self.forward.tolist(), "right": self.right.tolist(), "up": self.up.tolist(),
            "window_centre": list(self.centre), "window_half_size": self.half_size, "resolution": self.resolution, "near": self.near, "far": self.far,
        }  # fmt: skip


@dataclass(frozen=True, slots=True)
class PointSampling:
    """The sampling geometry of one point-based impostor (module docstring)."""

    normal: np.ndarray  # (3,) unit, from the cell towards the part
    offset: float  # the plane is normal · x = offset
    u: np.ndarray  # (3,) unit, in-plane axes: plane coordinates (x·u, x·v)
    v: np.ndarray
    polygon: np.ndarray  # (k, 2) plane coordinates, counter-clockwise: where viewers' rays cross the plane
    triangle: np.ndarray  # (3, 2) plane coordinates: the cameras
    rectangle: np.ndarray  # (2, 2) plane coordinates lo, hi: the polygon's bounding rectangle (appearance domain)
    depth: float  # D: smallest distance of the part's box from the plane
    reach: float  # R: largest distance from a polygon point to its nearest camera
    boundary_reach: float  # R_b: the same over the polygon's boundary
    factors: dict  # movement, perspective, diagonal
    cameras: tuple[LdiCamera, ...]

    def to_world(self, plane_points: np.ndarray) -> np.ndarray:
        """(m, 3) world points of plane coordinates (m, 2)."""
        p = np.asarray(plane_points, dtype=np.float64)
        return self.offset * self.normal + p[:, :1] * self.u + p[:, 1:2] * self.v

    def to_dict(self) -> dict:
        return {
            "plane": {
                "normal": self.normal.tolist(),
                "offset": self.offset,
                "u": self.u.tolist(),
                "v": self.v.tolist(),
            },
            "polygon": self.polygon.tolist(),
            "triangle": self.triangle.tolist(),
            "perimeter": _perimeter(self.triangle),
            "rectangle": self.rectangle.tolist(),
            "depth": self.depth,
            "reach": self.reach,
            "boundary_reach": self.boundary_reach,
            "factors": dict(self.factors),
            "cameras": [c.to_dict() for c in self.cameras],
        }


def ldi_resolution(half_size: float, fov: float, resolution: int, movement: float, max_error_px: float = 1.0) -> int:
    """Pixels per side of an LDI camera whose window is ``half_size`` image tangents either side
    of its centre, so that, seen from any
    viewer in the cell through an output camera of ``fov`` and ``resolution``, no edge of the
    LDI's sampling pattern spans more than one output pixel (seed 001 §5.1's three factors):

        N = ceil( 2 half_size · √2 · F_move · F_persp / β ),   β = 2 tan(fov/2) / resolution

    - β is the output pixel's angle at the frame's centre; F_persp (:func:`corner_perspective_factor`)
      shrinks it to the radial angle of a corner pixel, the smallest anywhere in the frame;
    - 2 half_size / N is the LDI's pixel in image tangents, and a ray's angle moves by at most
      that much per pixel (by cos² of its angle from the axis less); √2 turns a pixel side into
      its diagonal, the longest edge of the triangulated sampling grid (§5.1, "sampling pattern
      orientation");
    - F_move (:func:`movement_factor`) bounds how much larger that spacing looks from the nearest
      viewer in the cell than from the camera that took it.

    With an error budget of ``max_error_px`` pixels, β is that many pixels' angle.

    >>> ldi_resolution(math.tan(math.radians(20.0)), math.radians(45.0), 256, 1.0)
    428
    """
    beta = 2.0 * math.tan(0.5 * check_fov(fov)) / check_resolution(resolution) * check_error_px(max_error_px)
    exact = 2.0 * half_size * math.sqrt(2.0) * movement * corner_perspective_factor(fov) / beta
    n = max(1, math.ceil(exact * (1.0 - TOL.rel_round)))
    if n > TOL.max_texture_resolution:
        raise LayerPlanError(
            f"a point impostor's LDI would need {n} pixels per side (> {TOL.max_texture_resolution}): the part is too close to the view cell or too wide for it"
        )
    return n


def plan_point_sampling(
    cell: BoxCell, part_bounds, fov_deg: float, resolution: int, max_error_px: float = 1.0
) -> PointSampling:
    """The sampling plane, polygon, cameras and LDI resolutions for ``part_bounds`` ((2, 3) lo, hi)
    seen from ``cell`` through an output camera of ``fov_deg`` and ``resolution`` (module docstring).

    >>> s = plan_point_sampling(BoxCell.from_center([0.0, 0.0, 0.0], 1.0), np.array([[-2.0, -2.0, 10.0], [2.0, 2.0, 12.0]]), 45.0, 256)
    >>> s.normal.tolist(), s.offset, s.depth, len(s.cameras), round(s.factors["movement"], 3)
    ([0.0, 0.0, 1.0], 0.5, 9.5, 3, 1.077)
    >>> [c.resolution for c in s.cameras]
    [267, 267, 267]
    """
    fov = check_fov(math.radians(float(fov_deg)))
    resolution = check_resolution(resolution)
    bounds = np.asarray(part_bounds, dtype=np.float64).reshape(2, 3)
    if not np.all(np.isfinite(bounds)) or np.any(bounds[1] < bounds[0]):
        raise LayerPlanError(f"part bounds must be finite with lo <= hi, got {bounds.tolist()}")
    part = box_corners(bounds)
    corners = cell.corners()
    length, normal = length_and_unit(0.5 * (bounds[0] + bounds[1]) - cell.center)  # no overflow near 1e300
    if not length > 0.0:
        raise ViewCellError(
            "the part's centre is the view cell's centre: a point impostor needs the part on one side of the cell"
        )
    offset = float(np.max(corners @ normal))
    depth = float(np.min(part @ normal) - offset)
    scale = max(float(np.max(np.abs(np.concatenate([corners, part])))), 1.0)
    if not depth > TOL.rel_round * scale:
        raise ViewCellError(
            f"the part reaches the view cell's side facing it (distance {depth:.6g} along {normal.round(4).tolist()}): "
            "a point impostor needs the part wholly beyond a plane that has the whole cell behind it"
        )
    u, v = plane_frame(normal)
    section = cross_section(corners, part, normal, offset)
    polygon = convex_polygon(np.stack([section @ u, section @ v], axis=1))
    triangle = min_perimeter_triangle(polygon)
    reach, _ = farthest_from_cameras(polygon, triangle)
    boundary_reach, _ = farthest_from_cameras(polygon, triangle, boundary=True)
    movement = movement_factor(reach, depth, boundary_reach)
    sampling = PointSampling(
        normal, offset, u, v, polygon, triangle, np.stack([polygon.min(axis=0), polygon.max(axis=0)]), depth, reach, boundary_reach,
        {"movement": movement, "perspective": corner_perspective_factor(fov), "diagonal": math.sqrt(2.0)}, (),
    )  # fmt: skip
    cameras = []
    for position in sampling.to_world(triangle):
        local = (part - position) @ np.stack([u, v, normal]).T  # depth >= D > 0 for every corner
        tangents = local[:, :2] / local[:, 2:3]
        lo, hi = tangents.min(axis=0), tangents.max(axis=0)
        half = 0.5 * float(np.max(hi - lo))
        if half > MAX_LDI_HALF_SIZE:
            raise ViewCellError(
                f"an LDI camera would need a window {2.0 * half:.3g} tangents wide (at most {2.0 * MAX_LDI_HALF_SIZE:.3g}): "
                "the part is too wide or too close for a point impostor from this cell"
            )
        centre = (float(0.5 * (lo[0] + hi[0])), float(0.5 * (lo[1] + hi[1])))
        near, far = float(local[:, 2].min()), float(local[:, 2].max())
        n = ldi_resolution(half, fov, resolution, movement, max_error_px)
        cameras.append(LdiCamera(position, normal, u, v, centre, half, n, near * (1.0 - 1e-6), far * (1.0 + 1e-6)))
    return replace(sampling, cameras=tuple(cameras))
