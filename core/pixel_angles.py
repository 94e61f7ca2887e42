"""Pinhole-camera sampling quantities: scalar float64 angles (radians) and resolutions (texels per side).

An output image is square, ``resolution`` pixels per side, with the same field of view ``fov``
(radians, full angle) on both axes.  Two conventions for "the angle of one pixel" are offered:

``"center"``
    the angle a pixel subtends at the image centre, ``2 tan(fov/2) / Res`` in the small-angle form the
    thesis uses (seed 000 §3.3.1 with [Scha95b]; it reproduces Table 4.1 of seed 000).
``"min"``
    the smallest angle any pixel side subtends anywhere in the image (seed 002 §4.3: "an obvious
    choice for α is the minimal angle subtended by a pixel").  That is at the image corner; seed 001
    §5.1 notes the same effect as its perspective factor.  This is farfield's default, because the
    product promises at most one pixel of error from *every* view direction.
"""

from __future__ import annotations

import math
from typing import Literal

from farfield.core.constants import TOL
from farfield.core.errors import LayerPlanError

PixelModel = Literal["center", "min"]
# How a part technique spends its error budget (farfield.core.techniques.part.layer_budget).
ErrorBudgetKind = Literal["strict", "thesis"]
PIXEL_MODELS: tuple[str, ...] = ("center", "min")


# The largest output or face resolution any technique accepts (pixels per side): 16 times the
# default and beyond every documented example; larger images are refused when options are checked.
MAX_RESOLUTION = 16384


def check_fov(fov: float) -> float:
    """Return ``fov`` (radians) if it lies in the open interval (0, π), else raise LayerPlanError."""
    if not (math.isfinite(fov) and 0.0 < fov < math.pi):
        raise LayerPlanError(f"field of view must lie in (0°, 180°), got {math.degrees(fov)!r}°")
    return float(fov)


# The largest error budget a bake takes, in output pixels: beyond it an impostor is no stand-in.
MAX_ERROR_PX = 64.0


def check_error_px(max_error_px: float) -> float:
    """Return the error budget ``max_error_px`` (output pixels) if it lies in (0, MAX_ERROR_PX],
    else raise LayerPlanError."""
    if isinstance(max_error_px, bool) or not (math.isfinite(max_error_px) and 0.0 < max_error_px <= MAX_ERROR_PX):
        raise LayerPlanError(f"error budget must lie in (0, {MAX_ERROR_PX:g}] pixels, got {max_error_px!r}")
    return float(max_error_px)


def check_resolution(resolution: int, what: str = "output resolution") -> int:
    """Return ``resolution`` as int if it is an integer >= 1, else raise LayerPlanError."""
    if isinstance(resolution, bool) or int(resolution) != resolution or resolution < 1:
        raise LayerPlanError(f"{what} must be an integer >= 1, got {resolution!r}")
    return int(resolution)


def perspective_factor(fov: float) -> float:
    """Ratio of a pixel's angle at the image centre to its angle at the middle of an image edge.

    Seed 001 §5.1: "the sampling resolution has to be increased by the factor between angular
    resolution in the center of the camera and at the border of the viewing frustum", which is
    ``1 / cos²(fov/2)``.

    >>> round(perspective_factor(math.radians(45)), 4)
    1.1716
    """
    fov = check_fov(fov)
    return 1.0 / math.cos(0.5 * fov) ** 2


def pixel_angle(fov: float, resolution: int, model: PixelModel = "min") -> float:
    """Angle (radians) of one output pixel under ``model`` (see the module docstring).

    ``"min"`` is the angle of a pixel side at the image corner, where a ray at image-plane
    coordinates (T, T), T = tan(fov/2), moves by ``sqrt(1 + T²) / (1 + 2T²)`` radians per unit of
    image-plane x; the centre moves by 1 radian per unit.

    >>> round(pixel_angle(math.radians(45), 512, "center"), 6)
    0.001618
    >>> pixel_angle(math.radians(45), 512, "min") < pixel_angle(math.radians(45), 512, "center")
    True
    """
    fov = check_fov(fov)
    resolution = check_resolution(resolution)
    half = math.tan(0.5 * fov)
    centre = 2.0 * half / resolution
    if model == "center":
        return centre
    if model == "min":
        return centre * math.sqrt(1.0 + half * half) / (1.0 + 2.0 * half * half)
    raise LayerPlanError(f"pixel model must be one of {PIXEL_MODELS}, got {model!r}")


def texture_resolution(width: float, distance: float, angle: float) -> int:
    """Texels across an impostor of ``width`` so that no texel is magnified on screen.

    A texel of the nearest layer is ``width / res`` wide at ``distance`` from the nearest viewpoint
    of the view cell; it must subtend at most one output pixel ``angle``.  Farther layers subtend
    less (seed 000 §3.3.1, texel size p = w (t + s) / (res (t0 + s))), so the nearest one decides.

    Parameters
    ----------
    width : float
        Frustum width (scene units) at the part's near plane.
    distance : float
        Smallest distance (scene units) from the view cell to that plane, > 0.
    angle : float
        Output pixel angle in radians, > 0.

    >>> texture_resolution(30.0, 90.0, 0.001)
    334
    """
    if not (distance > 0.0 and width > 0.0 and angle > 0.0):
        raise LayerPlanError(
            f"texture resolution needs width > 0, distance > 0 and angle > 0; "
            f"got width={width!r}, distance={distance!r}, angle={angle!r}"
        )
    exact = width / (distance * angle)
    # Shrink by a relative epsilon before rounding up so that exact integers stay themselves
    # under uniform scaling of width and distance (whose quotient may be off by one ulp).
    shrunk = exact * (1.0 - TOL.rel_round)
    if not shrunk <= TOL.max_texture_resolution:  # before ceil: an overflowing quotient has no integer
        raise LayerPlanError(
            f"impostor texture would need {shrunk:.4g} texels per side (> {TOL.max_texture_resolution}): "
            f"the part ({width:.6g} wide) is too close ({distance:.6g}) for a {angle:.3g} rad pixel"
        )
    return max(1, math.ceil(shrunk))


def star_shape_distance(spacing: float, fov: float) -> float:
    """Seed 004 §3.2.1: farthest eye distance ``s = r / (2 tan(fov/2))`` that may still pick a grid point.

    ``s <= r`` exactly when ``fov >= 2 atan(1/2)`` (53.13°), which lets a star-shape be bounded by a
    sphere of diameter ``4 r``.

    >>> round(star_shape_distance(1.0, 2 * math.atan(0.5)), 12)
    1.0
    """
    fov = check_fov(fov)
    if not spacing > 0.0:
        raise LayerPlanError(f"grid spacing must be > 0, got {spacing!r}")
    return spacing / (2.0 * math.tan(0.5 * fov))
