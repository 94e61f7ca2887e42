"""``place``: the whole placement of seed 000 ch. 5 from a scene, a view space and a budget.

elements and hierarchy (§5.4) -> problem view space (§5.5) -> candidates (§5.6) -> greedy (§5.7)
-> :class:`~core.placement.result.Placement`.  Every step is timed (``Placement.seconds``) and
reports progress as ``(step, done, total)``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np

from farfield.core.placement.candidates import APEX_ANGLES_DEG, DIRECTION_STEP_DEG, DISTANCE_STEPS, CellKinds, generate_candidates
from farfield.core.placement.cost_model import CostModel
from farfield.core.placement.greedy import Greedy
from farfield.core.placement.hierarchy import DEFAULT_LEAF_SIZE, Elements, Hierarchy, PlacementError
from farfield.core.placement.result import Placement
from farfield.core.placement.view_space import FACE_NAMES, Visibility, problem_view_space
from farfield.core.scene import Scene
from farfield.core.stage_clock import StageClock
from farfield.core.techniques import get_technique

STEPS = ("hierarchy", "problem views", "candidates", "greedy")
DEFAULT_CPV_DIVISIONS = 8  # default CPV size: the view space's longest side / 8


@dataclass(frozen=True, slots=True)
class PlacementSettings:
    """The planner's knobs (see ``farfield place --help``)."""

    t_max: float
    model: CostModel
    technique: str = "layered"
    options: dict | None = None  # the technique's options (resolution and fov_deg included)
    cpv_size: float | None = None  # None: the view space's longest side / 8
    vdi_deg: float = 11.25
    depth_complexity: float = 4.0  # a view's rasterised pixels are at most this many frames (core.placement.view_space)
    cells: str = "both"
    leaf_size: int = DEFAULT_LEAF_SIZE
    cluster_triangles: int | None = None
    apex_angles_deg: tuple[float, ...] = APEX_ANGLES_DEG
    direction_step_deg: float = DIRECTION_STEP_DEG
    distance_steps: int = DISTANCE_STEPS


def _check(settings: PlacementSettings) -> None:
    if not (isinstance(settings.t_max, (int, float)) and math.isfinite(settings.t_max) and settings.t_max > 0):
        raise PlacementError(f"the budget must be a finite number > 0, got {settings.t_max!r}")
    if settings.cells not in CellKinds:
        raise PlacementError(f"cells must be one of {list(CellKinds)}, got {settings.cells!r}")
    if not 1 <= settings.distance_steps <= 30:
        raise PlacementError(f"distance steps must lie in 1..30, got {settings.distance_steps!r}")
    angles = np.asarray(settings.apex_angles_deg, dtype=np.float64)
    if angles.size == 0 or np.any(~((angles > 0.0) & (angles < 180.0))) or np.any(np.diff(angles) <= 0):
        raise PlacementError(f"shaft apex angles must be increasing and lie in (0, 180) degrees, got {list(settings.apex_angles_deg)}")
    if not (0.5 <= settings.direction_step_deg <= 90.0):
        raise PlacementError(f"the shaft direction step must lie in [0.5, 90] degrees, got {settings.direction_step_deg!r}")


def place(
    scene: Scene,
    view_lo,
    view_hi,
    settings: PlacementSettings,
    progress: Callable[[str, int, int], None] | None = None,
    visible: Visibility | None = None,
) -> Placement:
    """The impostor placement of ``scene`` for the view space box ``view_lo``..``view_hi`` (may be
    flat or a point) so that every view takes at most ``settings.t_max`` by the cost model, at
    least memory (greedily; seed 000 §5.7).  Raises PlacementError for unusable inputs; views no
    placement can serve are reported in the result (``Placement.message``), not raised."""
    _check(settings)
    technique = get_technique(settings.technique)
    if technique.estimate is None:
        raise PlacementError(
            f"technique {technique.name!r} cannot be placed: it replaces the whole scene around its cell; "
            "use a part technique (layered, tdm)"
        )
    options = technique.options({k: v for k, v in (settings.options or {}).items() if k not in ("resolution", "fov_deg")},
                                (settings.options or {}).get("resolution"), (settings.options or {}).get("fov_deg"))  # fmt: skip
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
        pv = problem_view_space(
            elements, hierarchy, lo, hi, settings.model, settings.t_max, fov, resolution, cpv_size, settings.vdi_deg, settings.depth_complexity, visible,
            lambda done, total: clock.report("problem views", done, total),
        )  # fmt: skip

    def estimate(cell, bounds):
        return technique.estimate(cell, options, bounds)

    with clock("candidates"):
        cand = generate_candidates(
            hierarchy, pv, settings.model, estimate, float(resolution) ** 2, settings.cells, settings.apex_angles_deg, settings.direction_step_deg,
            settings.distance_steps, lambda done, total: clock.report("candidates", done, total),
        )  # fmt: skip
    with clock("greedy"):
        greedy = Greedy(hierarchy, pv, cand, settings.t_max)
        greedy.run(progress=lambda chosen, worst: clock.report("greedy", chosen, cand.count))
    clock.report("greedy", 1, 1)
    return _result(scene, elements, hierarchy, pv, cand, greedy, settings, options, technique.name, lo, hi, cpv_size, clock.totals())


def _result(scene, elements, hierarchy, pv, cand, greedy, settings, options, technique, lo, hi, cpv_size, seconds) -> Placement:
    kept = [imp for k, imp in enumerate(greedy.chosen) if k not in greedy.deleted]
    new_id = {imp.order: n for n, imp in enumerate(kept)}
    unit = settings.model.unit
    impostors = []
    for n, imp in enumerate(kept):
        i = imp.candidate
        names = [elements.names[e] for e in np.sort(hierarchy.elements_of(imp.node))]
        impostors.append({
            "id": n,
            "node": imp.node,
            "objects": names,
            "cell": cand.cells[i].to_dict(),
            "technique": technique,
            "layers_estimated": float(cand.layers[i]),
            "texels_per_layer": float(cand.texels[i]),
            "quads_estimated": float(cand.quads[i]),
            "memory_bytes": float(cand.memory[i]),
            "cpvs": len(imp.cpvs),
            "time_max": max(t for _, t in imp.cpvs.values()),
        })  # fmt: skip
    solvable = ~pv.unsolvable
    after = np.where(solvable, greedy.t, pv.time)
    unsolved = solvable & (after > settings.t_max * (1.0 + 1e-9))
    cpvs = []
    for p in range(pv.count):
        status = "unsolvable" if pv.unsolvable[p] else ("unsolved" if unsolved[p] else "solved")
        r = int(pv.cpv_region[p])
        v = pv.cpv_vdi[p]
        cpvs.append({
            "id": p,
            "region": [pv.region_lo[r].tolist(), pv.region_hi[r].tolist()],
            "vdi": {"face": FACE_NAMES[v.face], "level": v.level, "i": v.i, "j": v.j},
            "time_before": float(pv.time[p]),
            "time_after": float(after[p]),
            "impostors": sorted(new_id[k] for k in greedy.drawn[p]),
            "status": status,
        })  # fmt: skip
    blame = []
    unsolvable = np.flatnonzero(pv.unsolvable)
    by_region: dict[int, list[int]] = {}
    for p in unsolvable:
        by_region.setdefault(int(pv.cpv_region[p]), []).append(int(p))
    for r in sorted(by_region):
        cpv_ids = by_region[r]
        worst = max(cpv_ids, key=lambda p: (pv.fixed_time[p], -p))
        a, b = pv.offsets[worst], pv.offsets[worst + 1]
        ids = hierarchy.order[pv.positions[a:b][pv.entry_fixed[a:b]]]
        blame.append({
            "region": [pv.region_lo[r].tolist(), pv.region_hi[r].tolist()],
            "cpvs": len(cpv_ids),
            "fixed_time": float(pv.fixed_time[worst]),
            "elements": sorted(elements.names[e] for e in ids),
        })  # fmt: skip
    memory = float(sum(imp["memory_bytes"] for imp in impostors))
    split = elements.split_counts(scene)
    summary = {
        "t_max": float(settings.t_max),
        "unit": unit,
        "cpvs": pv.count,
        "cpvs_solved": int(np.sum(solvable & ~unsolved)),
        "cpvs_unsolved": int(unsolved.sum()),
        "cpvs_unsolvable": int(pv.unsolvable.sum()),
        "candidates": cand.count,
        "candidates_considered": int(cand.stats["considered"]),
        "candidates_refused_by_technique": int(cand.stats["refused_by_technique"]),
        "impostors": len(impostors),
        "impostors_deleted": len(greedy.deleted),
        "memory_bytes": memory,
        "worst_before": float(pv.time.max()) if pv.count else 0.0,
        "worst_after": float(after.max()) if pv.count else 0.0,
        "worst_after_solvable": float(after[solvable].max()) if solvable.any() else 0.0,
        "leaf_regions_with_cpvs": int(pv.region_lo.shape[0]),
        "vdis_evaluated": int(pv.stats["vdis_evaluated"]),
        "hierarchy_nodes": hierarchy.count,
        "elements": elements.count,
        "rescored": greedy.rescored,
    }
    parameters = {
        "scene": {"source": scene.source, "content_hash": scene.content_hash, "objects": scene.object_count, "triangles": scene.triangle_count},
        "view_space": [lo.tolist(), hi.tolist()],
        "t_max": float(settings.t_max),
        "cost_model": settings.model.to_dict(),
        "technique": technique,
        "options": {k: (v if not isinstance(v, tuple) else list(v)) for k, v in asdict(options).items()},
        "cpv_size": float(cpv_size),
        "vdi_deg": float(settings.vdi_deg),
        "depth_complexity": float(settings.depth_complexity),
        "cells": settings.cells,
        "leaf_size": settings.leaf_size,
        "apex_angles_deg": [float(a) for a in settings.apex_angles_deg],
        "direction_step_deg": float(settings.direction_step_deg),
        "distance_steps": int(settings.distance_steps),
        "visibility": "none (no occlusion culling; seed 000 Table 5.1 test 16 setting)",
    }
    return Placement(
        parameters=parameters,
        elements={"count": elements.count, "cluster_triangles": elements.cluster_triangles, "split": split},
        impostors=impostors,
        cpvs=cpvs,
        unsolvable=blame,
        summary=summary,
        seconds=seconds,
    )
