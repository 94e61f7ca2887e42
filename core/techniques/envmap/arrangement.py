"""Layer arrangement of layered environment-map impostors: scalar float64 distances from a cubic view cell's centre.

Seed 002 (Jeschke, Wimmer, Schumann, GI 2002) §4: impostor layers are nested cubes around a cubic
view cell of side ``2 m``, recorded from its centre.  Going inwards from infinity, the parallax
criterion (Eq. 1) gives the next closer border or layer, and the texel criterion (Eq. 2) gives the
closest a next layer may come; the farther of the two wins (§4.2).  The innermost border is the
near field: geometry inside it is drawn as polygons.

Both criteria are similarities in the variable ``u = 1 - m/F``: every Eq. 1 step multiplies ``u``
by one constant ``q_par`` and every Eq. 2 step by exactly ``1 - 1/Res``.  The arrangement is
computed in that form, which is exact, vectorised and free of the cancellation of ``F - m`` at
large ``F``; the printed equations are kept as functions so tests can check the two agree.

Seed 003 (textured depth meshes) §4.1 Eq. 1 generalises Eq. 2 to a recording frustum narrower than
90 degrees: :func:`tdm_texel_limit`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from farfield.core.constants import TOL
from farfield.core.errors import LayerPlanError
from farfield.core.pixel_angles import check_fov, check_resolution

DIMENSIONS = (2, 3)


def corner_angle(dims: int = 3) -> float:
    """beta of seed 002 §4.2: pi/4 in 2D, arctan(sqrt 2) in 3D (the view-cell corner direction)."""
    if dims == 2:
        return 0.25 * math.pi
    if dims == 3:
        return math.atan(math.sqrt(2.0))
    raise LayerPlanError(f"dimensions must be 2 or 3, got {dims!r}")


def _check_alpha(alpha: float) -> float:
    # A parallax angle is about one pixel; from 90 degrees on Eq. 1's angles leave their domain.
    if not (math.isfinite(alpha) and 0.0 < alpha < 0.5 * math.pi):
        raise LayerPlanError(f"parallax angle alpha must lie in (0, pi/2) radians, got {alpha!r}")
    return float(alpha)


def _check_half_size(m: float) -> float:
    if not (math.isfinite(m) and m > 0.0):
        raise LayerPlanError(f"view cell size must be finite and > 0, got half size {m!r}")
    return float(m)


def parallax_step(F: float, m: float, alpha: float, dims: int = 3) -> float:
    """Seed 002 Eq. 1 as printed: from a border (or layer) at ``F`` the next closer layer (or border).

    ``F = inf`` gives the first layer (gamma = phi - alpha/2).  The maximum parallax error is seen
    from a view-cell corner under ``phi = pi/4 - beta/2``.

    >>> round(parallax_step(parallax_step(math.inf, 5.0, 2.2661e-3), 5.0, 2.2661e-3), 1)
    1738.0
    """
    m, alpha = _check_half_size(m), _check_alpha(alpha)
    beta = corner_angle(dims)
    phi = 0.25 * math.pi - 0.5 * beta
    if math.isinf(F):
        gamma = phi - 0.5 * alpha
    else:
        fx = math.tan(phi - 0.5 * alpha) * (F - m) - m * math.tan(beta)
        gamma = math.atan(fx / F)
    return (
        m
        * math.cos(gamma)
        * math.sin(phi + 0.5 * alpha + beta)
        / (math.cos(beta) * math.sin(phi + 0.5 * alpha - gamma))
    )


def texel_limit(F: float, m: float, resolution: int) -> float:
    """Seed 002 Eq. 2: the closest distance ``P`` a next layer may have so texels move < 1 texel.

    ``P = F m Res / (m Res + F - m)``; then ``(1 - m/P) / (1 - m/F) = 1 - 1/Res`` exactly.
    """
    m = _check_half_size(m)
    res = check_resolution(resolution, "layer resolution")
    if math.isinf(F):
        return m * res
    return F * m * res / (m * res + F - m)


def alpha_for_spacing(P: float, F: float, m: float, dims: int = 3) -> float:
    """Seed 002 §4.2: the parallax angle for which two Eq. 1 steps lead from layer ``F`` to layer ``P``.

    Used to re-place the border between two layers when the texel criterion (Eq. 2) chose ``P``:
    ``alpha = 2 atan(f cos(beta) ((P (F - m)) / (F (P - m)))^(1/4) - tan(beta)) - 2 phi``, f = 2 (2D)
    or 3 (3D).
    """
    m = _check_half_size(m)
    if not (m < P < F):
        raise LayerPlanError(f"alpha re-computation needs m < P < F, got m={m!r}, P={P!r}, F={F!r}")
    beta = corner_angle(dims)
    phi = 0.25 * math.pi - 0.5 * beta
    f = float(dims)
    ratio = P * (F - m) / (F * (P - m))
    return 2.0 * math.atan(f * math.cos(beta) * ratio**0.25 - math.tan(beta)) - 2.0 * phi


def tdm_texel_limit(F: float, m: float, resolution: int, fov: float) -> float:
    """Seed 003 Eq. 1: :func:`texel_limit` for a recording frustum of field of view ``fov`` (radians).

    ``P = (tan(FOV/2) + 1) F / (1 + tan(FOV/2) (1 + 2 (F - m) / (Res m)))``; at 90 degrees it is
    seed 002 Eq. 2.  Evaluate it on both image axes and keep the larger value.
    """
    m = _check_half_size(m)
    res = check_resolution(resolution, "layer resolution")
    k = math.tan(0.5 * check_fov(fov))
    return (k + 1.0) * F / (1.0 + k * (1.0 + 2.0 * (F - m) / (res * m)))


def parallax_factor(m: float, alpha: float, dims: int = 3) -> float:
    """q_par: the constant factor by which one Eq. 1 step multiplies ``u = 1 - m/F``.

    From infinity (u = 1) Eq. 1 reaches ``F1``, so ``q_par = 1 - m / F1``.  Written with the
    closed form of ``m / F1`` so that it keeps its digits when ``alpha`` is tiny.
    """
    m, alpha = _check_half_size(m), _check_alpha(alpha)
    beta = corner_angle(dims)
    phi = 0.25 * math.pi - 0.5 * beta
    gamma = phi - 0.5 * alpha
    # m / F1 with sin(phi + alpha/2 - gamma) = sin(alpha):
    ratio = math.cos(beta) * math.sin(alpha) / (math.cos(gamma) * math.sin(phi + 0.5 * alpha + beta))
    if not 0.0 < ratio < 1.0:
        raise LayerPlanError(
            f"parallax angle {alpha!r} rad is too large: the first layer would lie inside the view cell"
        )
    return 1.0 - ratio


@dataclass(frozen=True, slots=True)
class EnvmapPlan:
    """Nested impostor cubes around a cubic view cell; distances from the cell centre, ascending."""

    cell_size: float  # 2 m
    resolution: int  # texels per cube face side
    alpha: float  # radians
    dims: int
    distances: np.ndarray  # (k,) float64, layer cube half-sizes, nearest first
    borders: np.ndarray  # (k + 1,) float64; layer i covers [borders[i], borders[i+1]]; last is inf
    criterion: tuple[str, ...]  # per layer: "parallax" (Eq. 1) or "texel" (Eq. 2) or "first"

    @property
    def near_field(self) -> float:
        """Half-size of the near-field cube (innermost border)."""
        return float(self.borders[0])

    @property
    def count(self) -> int:
        return int(self.distances.shape[0])

    def to_dict(self) -> dict:
        """JSON-ready form (the outer border ``inf`` becomes ``None``)."""
        borders = [float(b) if math.isfinite(b) else None for b in self.borders]
        return {
            "arrangement": "envmap",
            "cell_size": self.cell_size,
            "resolution": self.resolution,
            "alpha_rad": self.alpha,
            "dims": self.dims,
            "layers": self.count,
            "near_field": self.near_field,
            "distances": self.distances.tolist(),
            "borders": borders,
            "depth_ranges": [[a, b] for a, b in zip(borders[:-1], borders[1:])],
            "criterion": list(self.criterion),
        }


def _log_factors(m: float, resolution: int, alpha: float, dims: int) -> tuple[float, float, bool]:
    """(log q_par, log q_layer, texel_wins): per-step log factors on ``u = 1 - m/F``."""
    log_par = math.log1p(-(1.0 - parallax_factor(m, alpha, dims)))
    log_tex = math.log1p(-1.0 / resolution)
    texel_wins = log_tex > 2.0 * log_par
    return log_par, max(2.0 * log_par, log_tex), texel_wins


def _log_u_near_field(log_par: float, log_layer: float, layers: int) -> float:
    """log u of the near-field border: the first layer, ``layers - 1`` layer steps, one Eq. 1 step."""
    return 2.0 * log_par + (layers - 1) * log_layer


def _distance(m: float, log_u) -> np.ndarray:
    """F = m / (1 - u) with u = exp(log_u), without cancellation: 1 - u = -expm1(log_u)."""
    return m / -np.expm1(np.asarray(log_u, dtype=np.float64))


def envmap_plan(cell_size: float, resolution: int, layers: int, alpha: float, dims: int = 3) -> EnvmapPlan:
    """The seed 002 §4.2 arrangement of ``layers`` impostor cubes around a cubic view cell.

    Parameters
    ----------
    cell_size : float
        Side of the cubic view cell (scene units), > 0.
    resolution : int
        Texels per side of each cube face (seed 002's Res), >= 1.
    layers : int
        Number of impostor layers, >= 1.
    alpha : float
        Parallax angle (radians), usually the minimal angle of an output pixel (§4.3).
    dims : {3, 2}

    The first layer comes from Eq. 1 at infinity; each further layer is the farther of two Eq. 1
    steps and Eq. 2; a border between layers is one Eq. 1 step in front of the farther layer, with
    alpha re-computed (§4.2) where Eq. 2 chose the layer; the near field is one Eq. 1 step in
    front of the last layer.

    >>> round(envmap_plan(10.0, 512, 64, 2.2661e-3).near_field, 1)
    42.2
    """
    m = _check_half_size(0.5 * float(cell_size))
    resolution = check_resolution(resolution, "layer resolution")
    if isinstance(layers, bool) or int(layers) != layers or layers < 1:
        raise LayerPlanError(f"number of layers must be an integer >= 1, got {layers!r}")
    layers = int(layers)
    if layers > TOL.max_layers:
        raise LayerPlanError(f"at most {TOL.max_layers} layers, got {layers}")
    log_par, log_layer, texel_wins = _log_factors(m, resolution, alpha, dims)
    k = np.arange(layers, dtype=np.float64)
    log_u_layers = log_par + k * log_layer  # far to near
    # Border in front of each layer: one Eq. 1 step, or half a layer step where Eq. 2 chose the
    # next layer (alpha re-computed so that two Eq. 1 steps span the layer gap exactly).
    # (Where Eq. 1 chose the layer, half a layer step *is* one Eq. 1 step.)
    log_u_borders = log_u_layers + 0.5 * log_layer
    log_u_borders[-1] = _log_u_near_field(log_par, log_layer, layers)
    far_to_near = _distance(m, log_u_layers)
    borders_near = _distance(m, log_u_borders)
    distances = far_to_near[::-1].copy()
    borders = np.concatenate([borders_near[::-1], [math.inf]])
    crit = ["first"] + ["texel" if texel_wins else "parallax"] * (layers - 1)
    return EnvmapPlan(float(cell_size), resolution, float(alpha), dims, distances, borders, tuple(crit[::-1]))


def near_field_distance(cell_size: float, resolution: int, layers: int, alpha: float, dims: int = 3) -> float:
    """Half-size of the near-field cube for ``layers`` layers (seed 002 §4.3: 10 m, 512, 64 -> 42 m)."""
    m = _check_half_size(0.5 * float(cell_size))
    resolution = check_resolution(resolution, "layer resolution")
    log_par, log_layer, _ = _log_factors(m, resolution, alpha, dims)
    return float(_distance(m, _log_u_near_field(log_par, log_layer, int(layers))))


def layers_for_near_field(cell_size: float, resolution: int, near_field: float, alpha: float, dims: int = 3) -> int:
    """Fewest layers whose near field lies at most ``near_field`` from the cell centre.

    Inverse of :func:`near_field_distance`: ``layers_for_near_field(near_field_distance(n)) == n``.
    The near field can never shrink to the view cell itself (half-size m): asking for that raises.
    """
    m = _check_half_size(0.5 * float(cell_size))
    resolution = check_resolution(resolution, "layer resolution")
    if not (math.isfinite(near_field) and near_field > m):
        raise LayerPlanError(
            f"a near field at {near_field!r} is impossible: it must lie outside the view cell (> {m!r})"
        )
    log_par, log_layer, _ = _log_factors(m, resolution, alpha, dims)
    # u_target = 1 - m / near_field, in log form without cancellation.
    log_target = math.log1p(-m / near_field)
    estimate = 1 + (log_target - 2.0 * log_par) / log_layer
    n = max(1, math.ceil(estimate) - 1)
    while near_field_distance(cell_size, resolution, n, alpha, dims) > near_field:
        n += 1
        if n > TOL.max_layers:
            raise LayerPlanError(f"a near field at {near_field!r} needs more than {TOL.max_layers} layers")
    while n > 1 and near_field_distance(cell_size, resolution, n - 1, alpha, dims) <= near_field:
        n -= 1
    return n
