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
    Candidates,
    CellKinds,
    generate_candidates,
)
from farfield.core.placement.cost_model import CostModel
from farfield.core.placement.greedy import Greedy
from farfield.core.placement.hierarchy import DEFAULT_LEAF_SIZE, Elements, Hierarchy, PlacementError
from farfield.core.placement.lod import LOD_TECHNIQUE, NodeLods
from farfield.core.placement.node_instances import node_instances
from farfield.core.placement.part_inputs import PartInputs
from farfield.core.placement.repair import PlannerState, scene_summary
from farfield.core.placement.result import Placement
from farfield.core.placement.view_space import DEFAULT_DEPTH_COMPLEXITY, Visibility, problem_view_space
from farfield.core.scene import Scene
from farfield.core.stage_clock import StageClock
from farfield.core.techniques import get_technique
from farfield.core.techniques.part import estimate_part_cell
from farfield.core.visibility.region_sets import region_sets

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
    # A view's estimated pixels are at most this many frames (farfield.core.placement.view_space, **Pixels**).
    depth_complexity: float = DEFAULT_DEPTH_COMPLEXITY
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
    # Other techniques whose candidates compete with ``technique``'s in the same greedy: name ->
    # its options (the job's resolution and fov_deg apply), e.g. {"octahedral": {"grid": 9}}
    # (docs/placement/frame-time.md, "Mixed candidates").  None or {}: ``technique``'s alone.
    also: dict | None = None
    # Simplified geometry competes too: QEM levels of detail of the hierarchy's nodes, held to the
    # technique's max_error_px (farfield.core.placement.lod; docs/placement/frame-time.md).
    lod: bool = False


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


def candidate_techniques(settings: PlacementSettings) -> list[tuple[object, object]]:
    """(technique, validated options) of the placement's main technique, then of each of
    ``settings.also`` (the job's ``resolution`` and ``fov_deg`` for all), each placeable and
    colour-only; raises PlacementError naming what cannot be used.

    >>> from farfield.core.placement.cost_model import LLVMPIPE_MODEL
    >>> s = PlacementSettings(1.0, LLVMPIPE_MODEL, options={"resolution": 128}, also={"octahedral": {"grid": 9}})
    >>> [(t.name, o.resolution, getattr(o, "grid", None)) for t, o in candidate_techniques(s)]
    [('layered', 128, None), ('octahedral', 128, 9)]
    >>> candidate_techniques(PlacementSettings(1.0, LLVMPIPE_MODEL, also={"layered": {}}))
    Traceback (most recent call last):
    ...
    farfield.core.placement.hierarchy.PlacementError: 'also' names the placement's own technique 'layered'
    """
    given = dict(settings.options or {})
    image = {k: given.pop(k) for k in ("resolution", "fov_deg") if k in given}
    also = settings.also or {}
    if not isinstance(also, dict):
        raise PlacementError(f"'also' must map technique names to their options, got {also!r}")
    if settings.technique in also:
        raise PlacementError(f"'also' names the placement's own technique {settings.technique!r}")
    out = []
    for name, values in [(settings.technique, given), *also.items()]:
        technique = get_technique(name)
        check_placeable(technique)
        values = {k: v for k, v in dict(values or {}).items() if k not in ("resolution", "fov_deg")}
        options = technique.options(values, image.get("resolution"), image.get("fov_deg"))
        check_colour_only(options)
        out.append((technique, options))
    return out


def technique_sources(techniques: list[tuple[object, object]]):
    """(estimate or None, outside estimates, the technique name of each candidate source) for
    :func:`~farfield.core.placement.candidates.generate_candidates`: the first technique without an
    ``outside_estimate`` gives the shafts and boxes (source 0), every one with it an outside-sphere
    candidate per node (sources 1 ..)."""
    estimate, outside, names = None, [], [None]
    for technique, options in techniques:
        reach = getattr(technique, "outside_estimate", None)
        if reach is not None:
            outside.append(lambda bounds, reach=reach, options=options: reach(options, bounds))
            names.append(technique.name)
        elif estimate is None:
            estimate = lambda cell, bounds, t=technique, o=options: t.estimate(cell, o, bounds)  # noqa: E731
            names[0] = technique.name
        else:
            raise PlacementError(
                f"one technique of shaft and box candidates per placement ({names[0]!r}), not {technique.name!r} too"
            )
    return estimate, tuple(outside), tuple(names)


def part_options(techniques: list[tuple[object, object]]):
    """The options of the shafts' and boxes' technique (:func:`technique_sources`' source 0) where
    its estimate is the layered part estimate, which candidates compute for many cells at once
    (:mod:`farfield.core.placement.part_estimates`); else None (one cell at a time)."""
    for technique, options in techniques:
        if getattr(technique, "outside_estimate", None) is None:
            return options if technique.estimate is estimate_part_cell else None
    return None


def instance_sources(techniques: list[tuple[object, object]], instanced: dict) -> tuple[dict, ...]:
    """Per outside source (:func:`technique_sources`' order): the nodes (``instanced``,
    :func:`~farfield.core.placement.node_instances.node_instances`) whose candidate is their
    prototype's moved, sharing its atlas: all of them, but for a hemisphere bake only the
    instances that keep the prototype's up axis (:mod:`farfield.core.techniques.octahedral.instancing`)."""
    return tuple(
        {n: i for n, i in instanced.items() if not getattr(o, "hemisphere", False) or i.keeps_up()}
        for t, o in techniques
        if getattr(t, "outside_estimate", None) is not None
    )


def place(
    scene: Scene,
    view_lo,
    view_hi,
    settings: PlacementSettings,
    progress: Callable[[str, int, int], None] | None = None,
    visible: Visibility | None = None,
    keep_state: bool = False,
    candidates: Callable[[PartInputs, Callable[[int, int], None]], Candidates] | None = None,
) -> Placement:
    """The impostor placement of ``scene`` for the view space box ``view_lo``..``view_hi`` (may be
    flat or a point) so that every view takes at most ``settings.t_max`` by the cost model, at
    least memory (greedily; seed 000 §5.7).  Raises PlacementError for unusable inputs; views no
    placement can serve are reported in the result (``Placement.message``), not raised.

    ``keep_state``: the result's ``state`` is the :class:`~farfield.core.placement.repair.PlannerState`
    (hierarchy, problem views, candidates, greedy) that check-and-repair rounds resume.

    ``candidates``: computes the candidate step from its :class:`~farfield.core.placement.part_inputs.PartInputs`
    and a progress callback ``(done, total)`` (a placement job fans its parts out to the render
    workers and merges them, :mod:`farfield.service.placement.candidate_fanout`); it must return
    what the in-process step gives.  None: generated here."""
    _check(settings)
    techniques = candidate_techniques(settings)
    technique, options = techniques[0]
    estimate, outside, sources = technique_sources(techniques)
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
            if pvs is not None:  # the lattice first, reported per batch: minutes on a CPU, and cancellable
                pvs.render_lattice(lambda done, total: clock.report("visibility", done, total))
            pv = problem_view_space(
                elements, hierarchy, lo, hi, settings.model, settings.t_max, fov, resolution, cpv_size, settings.vdi_deg, settings.depth_complexity,
                pvs if pvs is not None else visible, lambda done, total: clock.report("problem views", done, total),
            )  # fmt: skip
            if pvs is not None:  # what the runtime draws: the PVS of every smallest region (docs/formats.md)
                pv.stats["pvs"] = region_sets(pvs, elements.names, lo, hi, float(cpv_size))
                pv.stats["visibility"] = pvs.stats()
        finally:
            if pvs is not None:
                pvs.release()

    with clock("candidates"):
        shared = instance_sources(techniques, node_instances(scene, elements, hierarchy) if outside else {})
        lods = None
        if settings.lod:  # the last source of candidates (farfield.core.placement.candidates)
            lods = NodeLods(scene, elements, hierarchy, fov, resolution, float(getattr(options, "max_error_px", 1.0)))
            sources = (*sources, LOD_TECHNIQUE)
        report = lambda done, total: clock.report("candidates", done, total)  # noqa: E731
        if (
            candidates is not None and lods is None
        ):  # parts computed elsewhere, merged (farfield.core.placement.candidate_parts)
            cand = candidates(PartInputs(settings, hierarchy, pv, shared, resolution), report)
        else:  # levels of detail simplify the scene's meshes: computed here, not in parts
            cand = generate_candidates(
                hierarchy, pv, settings.model, estimate, float(resolution) ** 2, settings.cells, settings.apex_angles_deg, settings.direction_step_deg,
                settings.distance_steps, report, settings.max_impostor_bytes, outside, shared, part_options(techniques), lods,
            )  # fmt: skip
        if lods is not None:
            cand.stats["lod_nodes_simplified"] = lods.built
    with clock("greedy"):
        greedy = Greedy(hierarchy, pv, cand, settings.t_max)
        greedy.own = int(settings.lod)  # a faster candidate may replace a node's own level of detail
        greedy.run(progress=lambda chosen, worst: clock.report("greedy", chosen, cand.count))
    clock.report("greedy", 1, 1)
    state = PlannerState(
        scene_summary(scene, elements), elements, hierarchy, pv, cand, greedy, settings, options, technique.name, lo, hi, float(cpv_size), clock.totals(),
        sources=sources, also={t.name: o for t, o in techniques[1:]},
    )  # fmt: skip
    placement = state.placement()
    return replace(placement, state=state) if keep_state else placement
