"""``place``: the whole placement of seed 000 ch. 5 from a scene, a view space and a budget.

elements and hierarchy (§5.4) -> problem view space (§5.5) -> candidates (§5.6) -> greedy (§5.7)
-> :class:`~farfield.core.placement.result.Placement`.  Every step is timed (``Placement.seconds``) and
reports progress as ``(step, done, total)``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from farfield.core.impostor.impostor import wants_normals
from farfield.core.placement.candidates import (
    APEX_ANGLES_DEG,
    DIRECTION_STEP_DEG,
    DISTANCE_STEPS,
    CellKinds,
    generate_candidates,
)
from farfield.core.placement.cost_model import CostModel
from farfield.core.placement.greedy import Greedy
from farfield.core.placement.hierarchy import DEFAULT_LEAF_SIZE, Elements, Hierarchy, PlacementError
from farfield.core.placement.repair import PlannerState, scene_summary
from farfield.core.placement.result import Placement
from farfield.core.placement.view_space import Visibility, problem_view_space
from farfield.core.scene import Scene
from farfield.core.stage_clock import StageClock
from farfield.core.techniques import get_technique

STEPS = ("hierarchy", "problem views", "candidates", "greedy")
DEFAULT_CPV_DIVISIONS = 8  # default CPV size: the view space's longest side / 8
# The largest impostor a placement considers, by the model's memory estimate.  On a dense city a
# replanned greedy chose one impostor of 152 MB (estimated) over the whole view space, whose bake
# had not ended after 15 minutes on llvmpipe; the placement's other impostors were 0.02-1 MB.
DEFAULT_MAX_IMPOSTOR_BYTES = 32 * 2**20


@dataclass(frozen=True, slots=True)
class PlacementSettings:
    """The planner's knobs (see ``farfield place --help``)."""

    t_max: float
    model: CostModel
    technique: str = "layered"
    options: dict | None = None  # the technique's options (resolution and fov_deg included)
    cpv_size: float | None = None  # None: the view space's longest side / 8
    vdi_deg: float = 11.25
    depth_complexity: float = (
        4.0  # a view's rasterised pixels are at most this many frames (farfield.core.placement.view_space)
    )
    cells: str = "both"
    leaf_size: int = DEFAULT_LEAF_SIZE
    cluster_triangles: int | None = None
    apex_angles_deg: tuple[float, ...] = APEX_ANGLES_DEG
    direction_step_deg: float = DIRECTION_STEP_DEG
    distance_steps: int = DISTANCE_STEPS
    max_impostor_bytes: float = (
        DEFAULT_MAX_IMPOSTOR_BYTES  # larger candidates (by the model's memory estimate) are refused
    )
    # Problem views count only their region's potentially visible set (farfield.core.visibility.pvs,
    # sampled with id cube maps; docs/placement/visibility.md).  Off by default: the PVS is sampled,
    # not conservative, and the reference runtime still draws every element in the frustum.
    visibility: bool = False


def _check(settings: PlacementSettings) -> None:
    if not (isinstance(settings.t_max, (int, float)) and math.isfinite(settings.t_max) and settings.t_max > 0):
        raise PlacementError(f"the budget must be a finite number > 0, got {settings.t_max!r}")
    if settings.cells not in CellKinds:
        raise PlacementError(f"cells must be one of {list(CellKinds)}, got {settings.cells!r}")
    if not 1 <= settings.distance_steps <= 30:
        raise PlacementError(f"distance steps must lie in 1..30, got {settings.distance_steps!r}")
    angles = np.asarray(settings.apex_angles_deg, dtype=np.float64)
    if angles.size == 0 or np.any(~((angles > 0.0) & (angles < 180.0))) or np.any(np.diff(angles) <= 0):
        raise PlacementError(
            f"shaft apex angles must be increasing and lie in (0, 180) degrees, got {list(settings.apex_angles_deg)}"
        )
    if not (isinstance(settings.max_impostor_bytes, (int, float)) and settings.max_impostor_bytes > 0):
        raise PlacementError(f"the largest impostor must be > 0 bytes, got {settings.max_impostor_bytes!r}")
    if not (0.5 <= settings.direction_step_deg <= 90.0):
        raise PlacementError(
            f"the shaft direction step must lie in [0.5, 90] degrees, got {settings.direction_step_deg!r}"
        )


def region_visibility(scene: Scene, elements: Elements, lo, hi, cpv_size: float, resolution: int, fov: float):
    """The sampled PVS hook of ``settings.visibility`` (:class:`farfield.core.visibility.pvs.RegionVisibility`,
    imported here: only a placement with visibility needs a GL context while planning)."""
    from farfield.core.visibility.pvs import RegionVisibility

    return RegionVisibility(scene, elements, lo, hi, cpv_size, resolution, fov)


def check_placeable(technique) -> None:
    """Refuse a technique the frame-time planner cannot place, saying why.

    >>> from farfield.core.techniques import get_technique
    >>> check_placeable(get_technique("ldi"))
    Traceback (most recent call last):
    ...
    farfield.core.placement.hierarchy.PlacementError: technique 'ldi' has no memory and frame-time estimate for the frame-time planner; layered depth images are placed by the primitive-budget algorithm (algorithm primitive-budget, a primitives budget); for a frame budget use layered or tdm
    """
    if technique.estimate is not None:
        return
    if technique.scope == "scene":
        raise PlacementError(
            f"technique {technique.name!r} cannot be placed: it replaces the whole scene around its cell; use a part technique (layered, tdm)"
        )
    why = "has no memory and frame-time estimate for the frame-time planner"
    if technique.placement:  # what places it instead
        why += f"; {technique.placement}"
    raise PlacementError(f"technique {technique.name!r} {why}; for a frame budget use layered or tdm")


def check_colour_only(options) -> None:
    """Refuse technique ``options`` that keep a normal channel: the cost model and the memory
    budget of placement count colour texels (4 bytes each), and a normal channel doubles them,
    which they do not know yet (issue 55)."""
    if wants_normals(getattr(options, "channels", "albedo")):
        raise PlacementError(
            "placement jobs bake colour only for now (channels=albedo): their memory model does not count a normal "
            "channel's pages; bake lit impostors with a grid job"
        )


def place(
    scene: Scene,
    view_lo,
    view_hi,
    settings: PlacementSettings,
    progress: Callable[[str, int, int], None] | None = None,
    visible: Visibility | None = None,
    keep_state: bool = False,
) -> Placement:
    """The impostor placement of ``scene`` for the view space box ``view_lo``..``view_hi`` (may be
    flat or a point) so that every view takes at most ``settings.t_max`` by the cost model, at
    least memory (greedily; seed 000 §5.7).  Raises PlacementError for unusable inputs; views no
    placement can serve are reported in the result (``Placement.message``), not raised.

    ``keep_state``: the result's ``state`` is the :class:`~farfield.core.placement.repair.PlannerState`
    (hierarchy, problem views, candidates, greedy) that check-and-repair rounds resume."""
    _check(settings)
    technique = get_technique(settings.technique)
    check_placeable(technique)
    options = technique.options({k: v for k, v in (settings.options or {}).items() if k not in ("resolution", "fov_deg")},
                                (settings.options or {}).get("resolution"), (settings.options or {}).get("fov_deg"))  # fmt: skip
    check_colour_only(options)
    fov, resolution = math.radians(options.fov_deg), int(options.resolution)
    lo, hi = np.asarray(view_lo, dtype=np.float64).reshape(-1), np.asarray(view_hi, dtype=np.float64).reshape(-1)
    if lo.shape != (3,) or hi.shape != (3,):
        raise PlacementError("the view space needs two corners of three numbers each")
    with np.errstate(over="ignore", invalid="ignore"):
        span = hi - lo
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(np.isfinite(span))):
        raise PlacementError(f"the view space needs finite corners and size, got {lo.tolist()} .. {hi.tolist()}")
    cpv_size = settings.cpv_size
    if cpv_size is None:
        longest = float(np.max(span))
        cpv_size = longest / DEFAULT_CPV_DIVISIONS if longest > 0 else 1.0
    clock = StageClock(STEPS, progress)

    with clock("hierarchy"):
        elements = Elements.of(scene, settings.cluster_triangles)
        hierarchy = Hierarchy.build(elements, settings.leaf_size)
    clock.report("hierarchy", 1, 1)
    with clock("problem views"):
        pvs = (
            region_visibility(scene, elements, lo, hi, float(cpv_size), resolution, fov)
            if settings.visibility and visible is None
            else None
        )
        try:
            pv = problem_view_space(
                elements, hierarchy, lo, hi, settings.model, settings.t_max, fov, resolution, cpv_size, settings.vdi_deg, settings.depth_complexity,
                pvs if pvs is not None else visible, lambda done, total: clock.report("problem views", done, total),
            )  # fmt: skip
        finally:
            if pvs is not None:
                pvs.release()
        if pvs is not None:
            pv.stats["visibility"] = pvs.stats()

    def estimate(cell, bounds):
        return technique.estimate(cell, options, bounds)

    with clock("candidates"):
        cand = generate_candidates(
            hierarchy, pv, settings.model, estimate, float(resolution) ** 2, settings.cells, settings.apex_angles_deg, settings.direction_step_deg,
            settings.distance_steps, lambda done, total: clock.report("candidates", done, total), settings.max_impostor_bytes,
        )  # fmt: skip
    with clock("greedy"):
        greedy = Greedy(hierarchy, pv, cand, settings.t_max)
        greedy.run(progress=lambda chosen, worst: clock.report("greedy", chosen, cand.count))
    clock.report("greedy", 1, 1)
    state = PlannerState(
        scene_summary(scene, elements), elements, hierarchy, pv, cand, greedy, settings, options, technique.name, lo, hi, float(cpv_size), clock.totals()
    )  # fmt: skip
    placement = state.placement()
    return replace(placement, state=state) if keep_state else placement
