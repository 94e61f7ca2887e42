"""The accuracy distance of an octahedral impostor: the distance (world units, from the part's
centre) beyond which it is drawn within one output pixel of the real geometry
(docs/techniques/octahedral.md, "Accuracy distance", derives it).

``D`` solves ``(D - r) * a * (1 - r² / D²) = delta``: the largest displacement ``delta`` (world
units) of a silhouette or a surface point, seen at distance ``D - r`` (the part's nearest point)
by a pixel of angle ``a = 2 tan(fov / 2) / resolution`` at the image centre, shrunk by
``cos²`` of the angle the part subtends (the pixels away from the centre are smaller), is one
pixel.  ``delta = sqrt(2) * texel + extent * sin(theta)``: the conservative recording grows a
silhouette by up to one texel on each axis (``texel = 2 r / frame_resolution``), and a frame
``theta`` away from the view direction moves a point ``h`` above its card plane by ``h *
sin(theta)`` in the image; ``theta`` is the grid's weighted-median angle
(:func:`farfield.core.techniques.octahedral.mapping.grid_angle`): the 0.5 alpha cut lets frames of
more than half the weight decide every pixel.  ``extent`` is the part's depth extent: the largest
height of a recorded surface above any frame's card plane (at most ``r``); with depth kept the
height field's walls (the part extruded behind the surface each frame sees) can reach the whole
slab, so ``extent`` is doubled there (a bound, not an estimate), unless every frame has an opposite
frame (a full-sphere grid of odd ``n``): then a texel's column runs only between the two frames'
surfaces, every point of it is within half the part's longest internal ``gap`` of the part along
the line, and the parallax height is ``gap / 2`` plus the depth's half step ``r / 254``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from farfield.core.techniques.octahedral.mapping import grid_angle


@dataclass(frozen=True, slots=True)
class AccuracyDistance:
    """The accuracy distance and the figures it comes from (world units and degrees)."""

    distance: float  # from the part's centre, world units
    radii: float  # distance / radius
    radius: float  # the bounding sphere's
    grid_angle_deg: float  # theta: the grid's weighted-median angle
    texel: float  # a frame texel, world units
    extent: (
        float  # the parallax height used (doubled with one-sided depth; half the gap and a depth step with two-sided)
    )
    displacement: float  # delta, world units
    pixel_angle: float  # radians at the image centre
    resolution: int
    fov_deg: float
    gap: float | None = None  # the part's longest internal gap (two-sided depth), world units

    def to_dict(self) -> dict:
        return asdict(self)


def solve_distance(radius: float, displacement: float, pixel_angle: float) -> float:
    """The ``D > radius`` where ``(D - r) * a * (1 - r² / D²) = delta`` (module docstring), by bisection.

    >>> round(solve_distance(1.0, 0.01, 0.001), 4)
    11.0821
    """
    r, delta, a = float(radius), float(displacement), float(pixel_angle)

    def seen(d: float) -> float:
        return (d - r) * a * (1.0 - (r / d) ** 2)

    lo, hi = r, r + delta / a + 2.0 * r
    while seen(hi) < delta:
        hi *= 2.0
    for _ in range(200):  # seen() increases with d beyond r
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if seen(mid) < delta else (lo, mid)
        if hi - lo <= 1e-12 * hi:
            break
    return hi


def accuracy_distance(
    radius: float, extent: float, n: int, hemisphere: bool, frame_resolution: int, resolution: int, fov_deg: float,
    depth: bool, gap: float | None = None,
) -> AccuracyDistance:  # fmt: skip
    """The accuracy distance of a bake (module docstring).

    >>> a = accuracy_distance(1.0, 1.0, 12, False, 128, 128, 45.0, depth=False)
    >>> round(a.grid_angle_deg, 1), round(a.radii, 1)
    (21.4, 60.9)
    >>> accuracy_distance(1.0, 1.0, 24, False, 128, 128, 45.0, depth=False).radii < a.radii
    True
    >>> round(accuracy_distance(1.0, 1.0, 13, False, 128, 128, 45.0, depth=True, gap=0.0).radii, 1)  # a convex part
    4.8
    """
    theta = grid_angle(n, hemisphere)
    texel = 2.0 * radius / frame_resolution
    if depth and gap is not None:  # two-sided columns
        height = 0.5 * gap + radius / 254.0
    else:
        height = (2.0 if depth else 1.0) * extent
    delta = math.sqrt(2.0) * texel + height * math.sin(theta)
    pixel = 2.0 * math.tan(0.5 * math.radians(fov_deg)) / resolution
    d = solve_distance(radius, delta, pixel)
    used = gap if depth else None
    return AccuracyDistance(
        d, d / radius, radius, math.degrees(theta), texel, height, delta, pixel, resolution, fov_deg, used
    )
