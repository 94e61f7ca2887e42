"""Placement jobs: scene + view space + frame budget -> the impostors a planner chooses, baked as cells, checked and repaired.

A placement job (``POST /v1/jobs`` with ``"placement"``; SQL ``job_type`` ``"placement"``, the
impostors' technique in ``params["technique"]``) goes

    queued -> placing (plan) -> running (bake round 0) -> placing (check round 1) -> running (bake round 1) -> ... -> done | failed | cancelled

- **plan** (:func:`plan_job`, the worker task ``farfield.plan_placement``): the planner
  (:func:`farfield.core.placement.planner.place`, ``keep_state=True``) on the stored scene; its progress is
  the job's ``planning`` record (``GET /v1/jobs/{id}`` shows it as ``"placement"``), cancellation is
  looked at between progress calls, a :class:`~farfield.core.errors.FarfieldError` of bad input fails
  the job with its message, anything else as ``internal error: ...``.  The planner state is kept as a
  blob (``jobs/<id>/planner-<round>.pickle``) and every impostor becomes one cell (cell index =
  impostor id) that carries its own technique, objects, options and view cell (``cells.params``).
  A placement of no impostors ends ``done`` at once with its database.  Only the state the next
  check needs is kept: a committed round deletes the older rounds' states, and a job that ends
  deletes them all (:func:`drop_ended_planning`; a job failed while baking keeps its current one,
  which ``retry`` needs to check the round again); an attempt that finds its job cancelled or
  failed removes the index it wrote.
- **bake**: the cells go to the render workers as a grid job's do (:func:`service.cell_runner.run_cell`
  bakes a placement cell with :func:`farfield.core.placement.database.bake_impostor`; its result key is made
  of its own parameters, so equal impostors of another job are found, not baked again).
- **check** (:func:`check_job`, ``farfield.check_placement``), when the last cell of a round ends
  done: the planner state is loaded and repaired with the baked cells' real figures
  (``PlannerState.repair``); impostors it adds become cells of the next round, else (or after
  ``MAX_REPAIR_ROUNDS``) the database index is written (:func:`farfield.core.placement.database.placement_index`,
  ``jobs/<id>/index.json``) and the job ends done.

A **primitive-budget** job (``"algorithm": "primitive-budget"``, seed 004, technique ``ldi``) goes the
same way with one round: the plan is :func:`farfield.core.placement.solution_grid.place_primitives` and its
check of ``check_views`` random views; the grid is kept as ``jobs/<id>/planner-grid.json``; every
image becomes one cell (``cells.params``: its name "<point>-<image>" and what its LDI is made of,
:func:`farfield.core.placement.image_database.image_entries`), baked by
:func:`farfield.core.placement.image_database.bake_image` and keyed without its name, so the same image of
another job (another P that keeps it) is found, not baked.  The check has nothing to repair (the
guarantee counts triangles, which baking does not change): it writes the index
(:func:`farfield.core.placement.image_database.image_index`, ``kind`` "primitive-placement", the bundles
under ``cells/NNNNN/``) and ends the job.

Planning and checking are held by one worker at a time under a lease (``jobs.plan_worker``,
``jobs.lease_until``) that a heartbeat thread renews every ``HEARTBEAT_S``.  A worker process that
dies loses it: its worker's main process releases it at once (a pool process killed), else it
expires after ``LEASE_S`` (the whole worker gone) and the API's sweeper
(:func:`lost_planning_jobs`) sends the task again; each claim counts an attempt, and a phase whose
``max_attempts`` attempts never reported back fails the job.  So a job is never left ``placing``.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import threading
import time
import uuid
from dataclasses import dataclass
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, StrictFloat, StrictInt
from sqlalchemy import func, select, update

from farfield.core.options import stored_values
from farfield.core.placement.cost_model import LLVMPIPE_MODEL, CostModel, primitive_model
from farfield.core.placement.hierarchy import PlacementError
from farfield.core.placement.octree_cells import DEFAULT_DEPTH
from farfield.core.placement.planner import DEFAULT_MAX_IMPOSTOR_BYTES, check_placeable
from farfield.core.placement.view_space import MAX_REGIONS, MIN_VDI_DEG
from farfield.core.techniques import DEFAULT_TECHNIQUE, get_technique
from farfield.service.blobs import BlobStore
from farfield.service.db import CellRow, Database, JobRow, SceneRow, now
from farfield.service.settings import Settings

log = logging.getLogger("farfield.placement")

PLACEMENT_JOB = "placement"  # the job_type column of a placement job
LEASE_S = 20.0  # a held planning not renewed for this long is lost (its worker died)
HEARTBEAT_S = 3.0  # how often the holder renews it
CANCEL_CHECK_S = 0.2  # a planning job looks at its state at the first progress call after this
PROGRESS_EVERY_S = 0.5  # and writes its progress record
COST_MODELS = {"llvmpipe": LLVMPIPE_MODEL}  # cost models known by name
CELL_KINDS = ("shafts", "boxes", "both", "leaf-boxes")
FRAME_TIME, PRIMITIVE_BUDGET = "frame-time", "primitive-budget"
ALGORITHMS = (FRAME_TIME, PRIMITIVE_BUDGET)
FRAME_TIME_KNOBS = ("cpv_size", "vdi_deg", "depth_complexity", "cells", "leaf_size", "max_impostor_mb")
PRIMITIVE_KNOBS = ("p_opt", "octree_depth", "grid_points", "max_level", "check_views")
DEFAULT_CHECK_VIEWS = 2000
PRIMITIVE_INDEX_KIND = "primitive-placement"  # the "kind" of a primitive-budget job's database index
MAX_CHECK_VIEWS = 1_000_000

Number = StrictFloat | StrictInt


class ViewSpaceSpec(BaseModel):
    """The box the viewer moves in (may be flat or a point)."""

    model_config = ConfigDict(extra="forbid")
    lo: tuple[Number, Number, Number]
    hi: tuple[Number, Number, Number]


class BudgetSpec(BaseModel):
    """Every view within ``frame_ms`` by a cost model, or at most ``primitives`` triangles."""

    model_config = ConfigDict(extra="forbid")
    frame_ms: Number | None = Field(None, description="t_max in milliseconds by the cost model")
    cost_model: str | dict | None = Field(
        None, description="with frame_ms: 'llvmpipe' (the builtin model, the default) or a cost model document (CostModel.to_dict(), farfield calibrate --out)"
    )
    primitives: Number | None = Field(None, description="or t_max as a triangle count (the primitive model)")


class PlacementSpec(BaseModel):
    """A placement job's view space, budget and the planner's knobs (``farfield place --help``)."""

    model_config = ConfigDict(extra="forbid")
    view_space: ViewSpaceSpec
    budget: BudgetSpec
    algorithm: Literal[ALGORITHMS] = Field(  # type: ignore[valid-type]
        FRAME_TIME,
        description="'frame-time' (seed 000: impostors of a part technique wherever a view is too slow by the cost model) or "
        "'primitive-budget' (seed 004: a solution grid of layered depth images, technique 'ldi', so that no view draws more than "
        "budget.primitives triangles)",
    )
    cpv_size: Number | None = Field(None, description="smallest 3D region of a problem view (default: the view space's longest side / 8)")
    vdi_deg: Number = Field(11.25, description=f"smallest view-direction interval, degrees, in [{MIN_VDI_DEG:g}, 90]")
    depth_complexity: Number | None = Field(4.0, description="a view's rasterised pixels are at most this many frames (>= 1; null: no cap)")
    cells: Literal[CELL_KINDS] = Field("both", description="view cells of the candidates")  # type: ignore[valid-type]
    leaf_size: StrictInt = Field(4, description="elements per leaf of the object hierarchy (>= 1)")
    max_impostor_mb: Number = Field(DEFAULT_MAX_IMPOSTOR_BYTES / 2**20, description="largest impostor a placement considers, MiB by the cost model's memory estimate (> 0)")
    # the primitive-budget placement's knobs (seed 004 §5; farfield place --algorithm primitive-budget)
    p_opt: Number | None = Field(None, description="primitive-budget: the optimisation budget in (0, P] (default: P less 5 % of the model, at least P / 2)")
    octree_depth: StrictInt | None = Field(None, description=f"primitive-budget: depth of the octree's pseudo-leaf cells (default {DEFAULT_DEPTH})")
    grid_points: StrictInt | None = Field(None, description="primitive-budget: initial lattice points along the view space's longest side (>= 2, default 3)")
    max_level: StrictInt | None = Field(None, description="primitive-budget: deepest subdivision of the solution grid (>= 0, default 4)")
    check_views: StrictInt | None = Field(
        None, description=f"primitive-budget: random (eye, yaw) pairs the planner checks the guarantee on (0: none; default {DEFAULT_CHECK_VIEWS})"
    )


def _finite(value, what: str) -> float:
    value = float(value)
    if not math.isfinite(value):
        raise PlacementError(f"{what} must be a finite number, got {value!r}")
    return value


def cost_model_of(budget: BudgetSpec) -> tuple[CostModel, float, dict]:
    """The budget's cost model, t_max and the stored budget record."""
    if (budget.frame_ms is None) == (budget.primitives is None):
        which = "neither was given" if budget.frame_ms is None else "not both"
        raise PlacementError(f"give a budget: 'frame_ms' (with 'cost_model', default 'llvmpipe') or 'primitives'; {which}")
    if budget.primitives is not None:
        if budget.cost_model is not None:
            raise PlacementError("'primitives' counts triangles; 'cost_model' applies to 'frame_ms' only")
        t_max = _finite(budget.primitives, "budget.primitives")
        model, record = primitive_model(), {"primitives": t_max}
    else:
        t_max = _finite(budget.frame_ms, "budget.frame_ms")
        given = "llvmpipe" if budget.cost_model is None else budget.cost_model
        if isinstance(given, str):
            if given not in COST_MODELS:
                raise PlacementError(f"unknown cost model {given!r}; give one of {sorted(COST_MODELS)} or a cost model document (farfield calibrate --out)")
            model, name = COST_MODELS[given], given
        else:
            model, name = CostModel.from_dict(given), "given"  # CostModelError: bad input, names the problem
        record = {"frame_ms": t_max, "cost_model": name}
    if not t_max > 0:
        field = "budget.primitives" if budget.primitives is not None else "budget.frame_ms"
        raise PlacementError(f"the budget t_max must be > 0 ({field}), got {t_max!r}")
    return model, t_max, {**record, "t_max": t_max, "unit": model.unit}


def _view_space(spec: PlacementSpec) -> tuple[list[float], list[float], list[float]]:
    """The view space's (lo, hi, span), checked."""
    lo = [_finite(v, "view_space.lo") for v in spec.view_space.lo]
    hi = [_finite(v, "view_space.hi") for v in spec.view_space.hi]
    inverted = [axis for axis, a, b in zip("xyz", lo, hi, strict=True) if b < a]
    if inverted:
        raise PlacementError(f"the view space is empty: hi < lo on axis {', '.join(inverted)} (lo {lo}, hi {hi})")
    span = [b - a for a, b in zip(lo, hi, strict=True)]
    if not all(math.isfinite(s) for s in span):
        raise PlacementError(f"the view space's size is not finite: lo {lo}, hi {hi}")
    return lo, hi, span


def _not_given(spec: PlacementSpec, knobs: tuple[str, ...], algorithm: str) -> None:
    given = [k for k in knobs if k in spec.model_fields_set and getattr(spec, k) is not None]
    if given:
        raise PlacementError(f"{', '.join(given)}: {'not a knob' if len(given) == 1 else 'not knobs'} of the {algorithm} placement (algorithm {spec.algorithm!r})")


def placement_params(technique_name: str | None, given_options: dict, resolution, fov_deg, spec: PlacementSpec, model_triangles: int | None = None) -> dict:
    """Validate a placement request; the job's stored params (every option and knob as validated, the
    cost model as a document), or a 422 error naming the problem.  ``technique_name`` None: the
    algorithm's default (layered; ldi for the primitive-budget placement)."""
    if spec.algorithm == PRIMITIVE_BUDGET:
        return primitive_params(technique_name, given_options, resolution, fov_deg, spec, model_triangles)
    _not_given(spec, PRIMITIVE_KNOBS, FRAME_TIME)
    technique = get_technique(technique_name or DEFAULT_TECHNIQUE)
    check_placeable(technique)
    options = technique.options(given_options, resolution, fov_deg)
    lo, hi, span = _view_space(spec)
    model, t_max, budget = cost_model_of(spec.budget)
    cpv_size = None if spec.cpv_size is None else _finite(spec.cpv_size, "cpv_size")
    if cpv_size is not None and not cpv_size > 0:
        raise PlacementError(f"cpv_size must be > 0, got {cpv_size!r}")
    size = cpv_size if cpv_size is not None else (max(span) / 8 if max(span) > 0 else 1.0)
    cuts = [s / size for s in span]
    if not all(math.isfinite(c) for c in cuts):  # a size so small the quotient overflows
        raise PlacementError(f"a view space of {span} in regions of {size:.6g} has too many regions (over {MAX_REGIONS:.0e}); use a larger cpv_size")
    regions = math.prod(max(1.0, math.ceil(c)) for c in cuts)
    if regions > MAX_REGIONS:
        raise PlacementError(f"a view space of {span} in regions of {size:.6g} has {regions:.3g} regions, over {MAX_REGIONS:.0e}; use a larger cpv_size")
    vdi = _finite(spec.vdi_deg, "vdi_deg")
    if not MIN_VDI_DEG <= vdi <= 90:
        raise PlacementError(f"vdi_deg must lie in [{MIN_VDI_DEG:g}, 90] degrees, got {vdi!r}")
    depth = None if spec.depth_complexity is None else float(spec.depth_complexity)
    if depth is not None and not (depth >= 1.0):
        raise PlacementError(f"depth_complexity must be >= 1 (null: no cap), got {depth!r}")
    if depth is not None and math.isinf(depth):
        depth = None  # JSON (and PostgreSQL) hold no infinity: null is no cap
    if spec.leaf_size < 1:
        raise PlacementError(f"leaf_size must be >= 1, got {spec.leaf_size!r}")
    largest = _finite(spec.max_impostor_mb, "max_impostor_mb")
    if not largest > 0:
        raise PlacementError(f"max_impostor_mb must be > 0, got {largest!r}")
    knobs = {
        "view_space": {"lo": lo, "hi": hi}, "budget": budget, "cost_model": model.to_dict(), "cpv_size": cpv_size, "vdi_deg": vdi,
        "depth_complexity": depth, "cells": spec.cells, "leaf_size": spec.leaf_size, "cluster_triangles": None,
        "max_impostor_mb": largest,
    }  # fmt: skip
    return {"technique": technique.name, "resolution": options.resolution, "fov_deg": options.fov_deg, "objects": None, "options": stored_values(options), "placement": knobs}


def planner_settings(params: dict):
    """The job's :class:`~farfield.core.placement.planner.PlacementSettings` and view-space corners."""
    from farfield.core.placement.planner import PlacementSettings

    knobs = params["placement"]
    settings = PlacementSettings(
        t_max=knobs["budget"]["t_max"], model=CostModel.from_dict(knobs["cost_model"]), technique=params["technique"],
        options={**params["options"], "resolution": params["resolution"], "fov_deg": params["fov_deg"]},
        cpv_size=knobs["cpv_size"], vdi_deg=knobs["vdi_deg"], cells=knobs["cells"], leaf_size=knobs["leaf_size"],
        depth_complexity=math.inf if knobs["depth_complexity"] is None else knobs["depth_complexity"],
        cluster_triangles=knobs["cluster_triangles"], max_impostor_bytes=float(knobs.get("max_impostor_mb", math.inf)) * 2**20,  # a job stored before the cap: none
    )  # fmt: skip
    return settings, knobs["view_space"]["lo"], knobs["view_space"]["hi"]


def primitive_params(technique_name: str | None, given_options: dict, resolution, fov_deg, spec: PlacementSpec, model_triangles: int | None) -> dict:
    """:func:`placement_params` of the primitive-budget placement (seed 004): technique ``ldi``, a
    budget of ``primitives``, the solution grid's knobs checked as ``farfield place`` checks them."""
    from farfield.core.placement.octree_cells import MAX_DEPTH

    _not_given(spec, FRAME_TIME_KNOBS, PRIMITIVE_BUDGET)
    if technique_name not in (None, "ldi"):
        raise PlacementError(f"the primitive-budget placement replaces geometry with layered depth images: technique 'ldi' (or none), not {technique_name!r}")
    if spec.budget.frame_ms is not None or spec.budget.cost_model is not None or spec.budget.primitives is None:
        raise PlacementError("the primitive-budget placement bounds the triangles a view draws: give budget.primitives (and no frame_ms or cost_model)")
    technique = get_technique("ldi")
    options = technique.options(given_options, resolution, fov_deg)
    lo, hi, _ = _view_space(spec)
    depth = DEFAULT_DEPTH if spec.octree_depth is None else spec.octree_depth
    if not 0 <= depth <= MAX_DEPTH:
        raise PlacementError(f"octree_depth must be an integer in 0..{MAX_DEPTH}, got {depth!r}")
    views = DEFAULT_CHECK_VIEWS if spec.check_views is None else spec.check_views
    if not 0 <= views <= MAX_CHECK_VIEWS:
        raise PlacementError(f"check_views must be an integer in 0..{MAX_CHECK_VIEWS:,}, got {views!r}")
    knobs = {
        "algorithm": PRIMITIVE_BUDGET, "view_space": {"lo": lo, "hi": hi}, "p_opt": None if spec.p_opt is None else _finite(spec.p_opt, "p_opt"),
        "octree_depth": depth, "grid_points": 3 if spec.grid_points is None else spec.grid_points, "max_level": 4 if spec.max_level is None else spec.max_level,
        "check_views": views,
    }  # fmt: skip
    primitives = _finite(spec.budget.primitives, "budget.primitives")
    knobs["budget"] = {"primitives": primitives, "t_max": primitives, "unit": "triangles"}
    params = {"technique": technique.name, "resolution": options.resolution, "fov_deg": options.fov_deg, "objects": None, "options": stored_values(options), "placement": knobs}
    budget_settings(params).checked(model_triangles if model_triangles is not None else 0)  # P, p_opt, the FOV's star-shape bound, the grid's knobs
    return params


def budget_settings(params: dict):
    """A primitive-budget job's :class:`~farfield.core.placement.solution_grid.BudgetSettings`."""
    from farfield.core.placement.solution_grid import BudgetSettings

    knobs = params["placement"]
    return BudgetSettings(
        primitives=knobs["budget"]["primitives"], p_opt=knobs["p_opt"], fov_deg=params["fov_deg"], octree_depth=knobs["octree_depth"],
        grid_points=knobs["grid_points"], max_level=knobs["max_level"],
    )  # fmt: skip


def algorithm_of(params: dict) -> str:
    """A placement job's algorithm (a job stored before there were two: frame-time)."""
    return params["placement"].get("algorithm", FRAME_TIME)


def new_placement_job(tenant_id: str, scene: SceneRow, params: dict, requeue_after: float) -> JobRow:
    """The row of a new placement job (queued; its plan task is sent by the caller)."""
    return JobRow(
        id=uuid.uuid4().hex, tenant_id=tenant_id, scene_id=scene.id, job_type=PLACEMENT_JOB, params=params, evaluate=False, state="queued",
        created_at=now(), planning={"phase": "plan", "step": "queued", "done": 0, "total": 0, "round": 0, "rounds": []},
        lease_until=now() + requeue_after, plan_attempts=0,
    )  # fmt: skip


def cell_params(entry: dict, cluster_triangles: int) -> dict:
    """A placement cell's own parameters (``cells.params``, what determines its bundle's bytes) from
    its entry of :func:`farfield.core.placement.database.placement_cells`."""
    return {"technique": entry["technique"], "objects": list(entry["objects"]), "params": entry["params"], "cluster_triangles": int(cluster_triangles)}


def impostor_entry(cell: CellRow) -> dict:
    """The entry :func:`farfield.core.placement.database.bake_impostor` bakes for a placement cell."""
    p = cell.params
    return {"index": cell.index, "technique": p["technique"], "objects": p["objects"], "params": p["params"], "viewcell": cell.viewcell}


# --- claiming, the lease and its heartbeat ------------------------------------------------------


class PlanningCancelled(Exception):
    """The job was cancelled (or its hold lost) while it was planned or checked."""


@dataclass(frozen=True)
class PlanClaim:
    job: JobRow | None
    attempt: int = 0
    ended: bool = False  # this claim ended the job (attempts used up)


def claim_planning(db: Database, blobs: BlobStore, job_id: str, phase: str, worker: str, max_attempts: int) -> PlanClaim:
    """Hold the job's planning (``phase`` "plan" or "check") for ``worker``, counting the attempt;
    None when it must not run here (another worker holds it, the phase is over, the job ended)."""
    with db.session() as s:
        job = s.get(JobRow, job_id, with_for_update=True)
        if job is None or job.job_type != PLACEMENT_JOB or job.state not in ("queued", "placing"):
            return PlanClaim(None)
        if (job.planning or {}).get("phase") != phase:
            return PlanClaim(None)
        if job.plan_worker is not None and (job.lease_until or 0) > now():
            return PlanClaim(None)  # held by a live worker: this is a duplicate delivery
        if job.plan_attempts >= max_attempts:
            job.state, job.finished_at, job.plan_worker, job.lease_until = "failed", now(), None, None
            job.error = f"{phase} attempt {job.plan_attempts} of {max_attempts} never reported back (its worker process died: killed, out of memory or crashed)"
            return PlanClaim(None, ended=True)
        job.plan_attempts += 1
        job.state, job.plan_worker, job.lease_until = "placing", worker, now() + LEASE_S
        if job.started_at is None:
            job.started_at = now()
        # A lost attempt's message (release_planning) is history, not this attempt's error: kept in
        # "lost_attempts", so that a later success's record shows no "error".
        planning = dict(job.planning or {})
        lost = planning.pop("error", None)
        if lost:
            planning["lost_attempts"] = [*planning.get("lost_attempts", []), lost]
        job.planning = {**planning, "attempt": job.plan_attempts, "worker": worker}
        return PlanClaim(job, job.plan_attempts)


def _held(job_id: str, worker: str, attempt: int):
    return (JobRow.id == job_id, JobRow.state == "placing", JobRow.plan_worker == worker, JobRow.plan_attempts == attempt)


@contextlib.contextmanager
def heartbeat(db: Database, job_id: str, worker: str, attempt: int):
    """Renew the hold every ``HEARTBEAT_S`` while the body runs (a thread)."""
    stop = threading.Event()

    def beat() -> None:
        while not stop.wait(HEARTBEAT_S):
            try:
                with db.session() as s:
                    s.execute(update(JobRow).where(*_held(job_id, worker, attempt)).values(lease_until=now() + LEASE_S))
            except Exception:  # noqa: BLE001 - the next beat tries again; a lost lease is the sweeper's
                log.warning("job %s: could not renew the planning lease", job_id, exc_info=True)

    thread = threading.Thread(target=beat, name=f"farfield-lease-{job_id[:8]}", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(timeout=10)


def set_planning(db: Database, job_id: str, worker: str, attempt: int, **values) -> bool:
    """Merge ``values`` into the held job's planning record; False when the hold is gone."""
    with db.session() as s:
        job = s.get(JobRow, job_id, with_for_update=True)
        if job is None or job.state != "placing" or job.plan_worker != worker or job.plan_attempts != attempt:
            return False
        job.planning = {**(job.planning or {}), **values}
        return True


def fail_planning(db: Database, job_id: str, message: str, worker: str | None = None, attempt: int | None = None, blobs: BlobStore | None = None) -> bool:
    """Fail the job (if still held by ``worker``'s ``attempt``, when given) with ``message``; given
    ``blobs``, then delete its planner states (:func:`drop_ended_planning`)."""
    where = [JobRow.id == job_id, JobRow.state.in_(("queued", "placing"))]
    if worker is not None:
        where.append(JobRow.plan_worker == worker)
    if attempt is not None:
        where.append(JobRow.plan_attempts == attempt)
    with db.session() as s:
        failed = bool(s.execute(update(JobRow).where(*where).values(state="failed", error=message, finished_at=now(), plan_worker=None, lease_until=None)).rowcount)
    if failed and blobs is not None:
        drop_ended_planning(db, blobs, job_id)
    return failed


def release_planning(db: Database, job_id: str, why: str, worker: str | None, max_attempts: int, blobs: BlobStore | None = None) -> str:
    """A planning whose worker process died: free it for the next delivery (or fail the job when
    that was its last attempt, and then, given ``blobs``, delete its planner states).  Returns the
    job's state, or "unchanged"."""
    with db.session() as s:
        job = s.get(JobRow, job_id, with_for_update=True)
        if job is None or job.state != "placing" or job.plan_worker is None or (worker is not None and job.plan_worker != worker):
            return "unchanged"
        phase = (job.planning or {}).get("phase", "plan")
        if job.plan_attempts >= max_attempts:
            job.state, job.finished_at = "failed", now()
            job.error = f"{phase} attempt {job.plan_attempts} of {max_attempts} never reported back ({why})"
        else:
            job.planning = {**job.planning, "error": f"{phase} attempt {job.plan_attempts} of {max_attempts} was lost ({why}); sent again"}
            job.lease_until = 0.0  # the sweeper sends it again at its next sweep
        job.plan_worker = None
        state = job.state
    if state == "failed" and blobs is not None:
        drop_ended_planning(db, blobs, job_id)
    return state


def planning_jobs_of(db: Database, worker: str) -> list[str]:
    """Ids of the placement jobs whose planning ``worker`` (a Celery node name) holds."""
    with db.session() as s:
        return list(s.scalars(select(JobRow.id).where(JobRow.state == "placing", JobRow.plan_worker == worker)))


def lost_planning_jobs(db: Database, requeue_after: float) -> list[tuple[str, str]]:
    """(job id, phase) of placement jobs whose planning message or holder is lost (the lease ran
    out), claimed for sending again (their lease pushed ``requeue_after`` on, the hold dropped)."""
    with db.session() as s:
        found = list(s.execute(
            select(JobRow.id, JobRow.lease_until).where(JobRow.job_type == PLACEMENT_JOB, JobRow.state.in_(("queued", "placing")), JobRow.lease_until < now())
        ))  # fmt: skip
    claimed = []
    for job_id, lease in found:
        with db.session() as s:
            job = s.get(JobRow, job_id, with_for_update=True)
            if job.state not in ("queued", "placing") or job.lease_until != lease:
                continue
            job.plan_worker, job.lease_until = None, now() + requeue_after
            claimed.append((job_id, (job.planning or {}).get("phase", "plan")))
    return claimed


def pending_check(db: Database, job_id: str) -> bool:
    """Whether the job waits for its check task (the caller sends it)."""
    with db.session() as s:
        job = s.get(JobRow, job_id)
    return job is not None and job.state == "placing" and (job.planning or {}).get("phase") == "check" and job.plan_worker is None


def begin_check(session, job: JobRow, requeue_after: float | None = None) -> None:
    """The job's last cell of a round ended done: back to ``placing`` for the check (in the
    caller's session, the job row locked).  Its check message, if lost, is sent again by the
    API's sweeper after ``requeue_after`` seconds: by default ``FARFIELD_REQUEUE_AFTER`` of this
    process's settings (every process of a service has the same), as a queued plan's."""
    if requeue_after is None:
        requeue_after = Settings.from_env().requeue_after
    k = int((job.planning or {}).get("round", 0)) + 1
    job.state, job.plan_worker, job.plan_attempts, job.lease_until = "placing", None, 0, now() + requeue_after
    job.planning = {**(job.planning or {}), "phase": "check", "step": f"check round {k}", "done": 0, "total": 1, "check_round": k}


# --- plan and check -----------------------------------------------------------------------------


def _progress(db: Database, job_id: str, worker: str, attempt: int, round_: int):
    last_check, last_write, last_step = [0.0], [0.0], [None]

    def progress(step: str, done: int, total: int) -> None:
        clock = time.perf_counter()
        if clock - last_check[0] >= CANCEL_CHECK_S:
            last_check[0] = clock
            with db.session() as s:
                state = s.scalar(select(JobRow.state).where(JobRow.id == job_id))
            if state != "placing":
                raise PlanningCancelled(f"job {job_id} is {state}")
        if step != last_step[0] or clock - last_write[0] >= PROGRESS_EVERY_S or done == total:
            last_step[0], last_write[0] = step, clock
            if not set_planning(db, job_id, worker, attempt, step=step, done=int(done), total=int(total), round=round_):
                raise PlanningCancelled(f"job {job_id}: its planning is no longer held here")

    return progress


def _state_key(job_id: str, round_: int) -> str:
    return f"jobs/{job_id}/planner-{round_}.pickle"


def _grid_key(job_id: str) -> str:
    """Where a primitive-budget job keeps its solution grid between planning and its database."""
    return f"jobs/{job_id}/planner-grid.json"


def planner_state_keys(blobs: BlobStore, job_id: str) -> list[str]:
    """The keys of the job's stored planner states (``jobs/<id>/planner-<round>.pickle``, a primitive-budget
    job's ``planner-grid.json``)."""
    return [f"jobs/{job_id}/{name}" for name in blobs.list_files(f"jobs/{job_id}") if name.startswith("planner-") and name.endswith((".pickle", ".json"))]


def drop_planner_states(blobs: BlobStore, job_id: str, keep: str | None = None) -> list[str]:
    """Delete the job's planner states but ``keep``; returns the keys deleted."""
    dropped = [key for key in planner_state_keys(blobs, job_id) if key != keep]
    for key in dropped:
        blobs.delete_prefix(key)
    return dropped


def drop_ended_planning(db: Database, blobs: BlobStore, job_id: str) -> list[str]:
    """When the placement job has ended (done, failed, cancelled), delete its planner states: all of
    them, except that a job that failed while baking keeps its current one (``retry`` bakes the
    failed cells again, and the check that follows loads it).  Returns the keys deleted."""
    with db.session() as s:
        job = s.get(JobRow, job_id)
    if job is None or job.job_type != PLACEMENT_JOB or job.state not in ("done", "failed", "cancelled"):
        return []
    planning = job.planning or {}
    keep = planning.get("state_key") if job.state == "failed" and planning.get("phase") == "bake" else None
    return drop_planner_states(blobs, job_id, keep)


def after_cell(db: Database, blobs: BlobStore, job_id: str) -> bool:
    """After a cell of the job ended: whether the job waits for its check task (the caller sends
    it); otherwise a placement job that has ended drops its planner states."""
    if pending_check(db, job_id):
        return True
    drop_ended_planning(db, blobs, job_id)
    return False


def _frame_time_cells(placement: dict, ids) -> list[dict]:
    """The cells (index, view cell, own parameters) of a frame-time placement's impostors ``ids``."""
    from farfield.core.placement.database import placement_cells

    cluster = placement["elements"]["cluster_triangles"]
    return [{"index": int(e["index"]), "viewcell": e["viewcell"], "params": cell_params(e, cluster)} for e in placement_cells(placement) if e["index"] in ids]


def image_cell_params(entry: dict) -> dict:
    """A primitive-budget cell's own parameters: its image's name and what its LDI is baked from
    (:func:`farfield.core.placement.image_database.image_entries`)."""
    return {"technique": "ldi", "image": entry["name"], "params": entry["params"]}


def _add_cells(session, job: JobRow, cells: list[dict]) -> list[str]:
    made = []
    for entry in cells:
        cell = CellRow(
            id=uuid.uuid4().hex, job_id=job.id, index=int(entry["index"]), grid=None, viewcell=entry["viewcell"], params=entry["params"],
            state="queued", attempts=0, progress=0.0, queued_at=now(),
        )  # fmt: skip
        session.add(cell)
        made.append(cell.id)
    return made


def _cell_entries(db: Database, job_id: str) -> list[dict]:
    from farfield.service.jobs import job_cells

    return [{"index": c.index, "state": c.state, "bundle": f"cells/{c.index:05d}/" if c.result_key else None, "stats": c.stats} for c in job_cells(db, job_id)]


def _write_database(db: Database, blobs: BlobStore, job: JobRow, placement: dict, rounds: list) -> str:
    """Write the job's database index (``jobs/<id>/index.json``): a frame-time placement's
    (:func:`farfield.core.placement.database.placement_index`) or a primitive-budget grid's
    (:func:`farfield.core.placement.image_database.image_index`, its images' bundles under ``cells/NNNNN/``)."""
    key = f"jobs/{job.id}/index.json"
    if algorithm_of(job.params) == PRIMITIVE_BUDGET:
        from farfield.core.placement.image_database import image_index
        from farfield.service.jobs import job_cells

        with db.session() as s:
            scene_hash = s.get(SceneRow, job.scene_id).content_hash
        cells = job_cells(db, job.id)
        bundles = {c.params["image"]: f"cells/{c.index:05d}/" for c in cells if c.result_key}
        baked = [{"index": c.index, "image": c.params["image"], "state": c.state, "bundle": bundles.get(c.params["image"]), "stats": c.stats} for c in cells]
        options = job.params["options"]
        index = image_index(placement, bundles, job.params["resolution"], options["images"], scene_hash, kind=PRIMITIVE_INDEX_KIND, job=job.id,
                            scene=job.scene_id, cells_baked=baked)  # fmt: skip
    else:
        from farfield.core.placement.database import placement_index

        index = placement_index(placement, _cell_entries(db, job.id), job=job.id, scene=job.scene_id, rounds=rounds)
    blobs.put_bytes(key, json.dumps(index, sort_keys=True, indent=1, allow_nan=False).encode())  # strict JSON: engines read it
    return key


def plan_job(db: Database, blobs: BlobStore, job_id: str, worker: str, max_attempts: int) -> tuple[str, list[str]]:
    """Plan a placement job (see the module docstring): (its state after, cell ids to send)."""
    from farfield.service.scenes import load_stored_scene

    claim = claim_planning(db, blobs, job_id, "plan", worker, max_attempts)
    if claim.job is None:
        drop_ended_planning(db, blobs, job_id)
        return ("failed" if claim.ended else "skipped"), []
    job, attempt = claim.job, claim.attempt
    try:
        with heartbeat(db, job_id, worker, attempt):
            with db.session() as s:
                scene_row = s.get(SceneRow, job.scene_id)
            scene = load_stored_scene(blobs, scene_row)
            progress = _progress(db, job_id, worker, attempt, 0)
            plan = _plan_images if algorithm_of(job.params) == PRIMITIVE_BUDGET else _plan_frame_time
            state_key, doc, cells = plan(blobs, job, scene, progress)
            index_key = _write_database(db, blobs, job, doc, []) if not cells else None
    except PlanningCancelled:
        return _end_cancelled(db, blobs, job_id), []
    return _commit_round(db, blobs, job_id, worker, attempt, state_key, cells, _impostors(doc), doc.get("summary"), 0, index_key, [])


def _impostors(doc: dict) -> int:
    """How many impostors a placement (frame-time) or a grid (primitive-budget) holds."""
    return len(doc["impostors"]) if "impostors" in doc else int(doc["summary"]["images"])


def _plan_frame_time(blobs: BlobStore, job: JobRow, scene, progress) -> tuple[str, dict, list[dict]]:
    """Seed 000's planner: (its state's key, the placement, the cells of its impostors)."""
    from farfield.core.placement.planner import place

    settings, lo, hi = planner_settings(job.params)
    placement = place(scene, lo, hi, settings, progress=progress, keep_state=True)
    state_key = _state_key(job.id, 0)
    blobs.put_bytes(state_key, placement.state.dumps())
    as_dict = placement.to_dict()
    return state_key, as_dict, _frame_time_cells(as_dict, {imp["id"] for imp in as_dict["impostors"]})


def _plan_images(blobs: BlobStore, job: JobRow, scene, progress) -> tuple[str, dict, list[dict]]:
    """Seed 004's solution grid, checked on ``check_views`` random views: (the grid's key, the grid
    with the check in its summary, one cell per image)."""
    from farfield.core.placement.image_database import image_entries
    from farfield.core.placement.solution_grid import check_views, place_primitives

    knobs, options = job.params["placement"], job.params["options"]
    placement = place_primitives(scene, knobs["view_space"]["lo"], knobs["view_space"]["hi"], budget_settings(job.params), progress=progress)
    grid = placement.to_dict()
    if knobs["check_views"]:
        grid["summary"]["check"] = check_views(placement, knobs["check_views"], progress=progress)
    entries = image_entries(placement, job.params["resolution"], options["images"], options["max_layers"])
    state_key = _grid_key(job.id)
    blobs.put_bytes(state_key, json.dumps(grid, allow_nan=False).encode())
    return state_key, grid, [{"index": e["index"], "viewcell": e["viewcell"], "params": image_cell_params(e)} for e in entries]


def _end_cancelled(db: Database, blobs: BlobStore, job_id: str) -> str:
    """After :class:`PlanningCancelled`: end a cancelled job's planning ("cancelled") and delete its
    planner states, or leave the job alone when this attempt only lost its hold ("skipped"): a newer
    attempt holds it, and clearing the hold would leave the job ``placing`` with nothing to send it again."""
    with db.session() as s:
        s.execute(update(JobRow).where(JobRow.id == job_id, JobRow.state == "cancelled", JobRow.finished_at.is_(None)).values(finished_at=now()))
        ended = s.execute(update(JobRow).where(JobRow.id == job_id, JobRow.state == "cancelled").values(plan_worker=None, lease_until=None)).rowcount
    if not ended:
        return "skipped"
    drop_ended_planning(db, blobs, job_id)
    return "cancelled"


def _commit_round(db, blobs, job_id, worker, attempt, state_key, cells: list[dict], impostors: int, summary, round_, index_key, rounds) -> tuple[str, list[str]]:
    """Store a planned or repaired round: its ``cells`` (queued), or the database when none was added.
    Then only the state the next check loads is kept (all are deleted when the job ended).  An
    attempt that finds its job cancelled or failed meanwhile removes the index it wrote (a newer
    attempt that only took its hold writes its own under the same key: that one is left alone)."""
    committed, state, made = _commit_round_row(db, job_id, worker, attempt, state_key, cells, impostors, summary, round_, index_key, rounds)
    if committed and state == "running":
        drop_planner_states(blobs, job_id, keep=state_key)
    elif state in ("failed", "cancelled") or (committed and state == "done"):
        if not committed and index_key is not None:
            blobs.delete_prefix(index_key)
        drop_ended_planning(db, blobs, job_id)
    return state, made


def _commit_round_row(db, job_id, worker, attempt, state_key, cells: list[dict], impostors: int, summary, round_, index_key, rounds) -> tuple[bool, str, list[str]]:
    """:func:`_commit_round`'s change of the job's row: (whether this attempt committed, the job's
    state, the cells made)."""
    with db.session() as s:
        job = s.get(JobRow, job_id, with_for_update=True)
        if job.state != "placing" or job.plan_worker != worker or job.plan_attempts != attempt:
            return False, job.state, []  # cancelled meanwhile (or the hold was lost): nothing stored
        if index_key is None:
            from farfield.service.jobs import MAX_CELLS

            have = s.scalar(select(func.count()).select_from(CellRow).where(CellRow.job_id == job_id))
            if have + len(cells) > MAX_CELLS:
                job.state, job.finished_at, job.plan_worker, job.lease_until = "failed", now(), None, None
                images = algorithm_of(job.params) == PRIMITIVE_BUDGET
                job.error = (
                    f"PlacementError: the placement needs {have + len(cells):,} {'images' if images else 'impostors'}, over the limit of {MAX_CELLS:,} cells per job: "
                    + ("raise the primitive budget or p_opt, or use a smaller view space" if images else "use a larger budget, a smaller view space or larger --cpv-size / --vdi-deg")
                )  # fmt: skip
                return True, job.state, []
        made = _add_cells(s, job, cells) if index_key is None else []
        record = {
            **job.planning, "phase": "bake", "step": f"bake round {round_}" if made else "done", "round": round_, "state_key": state_key,
            "impostors": impostors, "summary": _summary_of(summary), "rounds": rounds, "done": 0, "total": 0,
        }  # fmt: skip
        record.pop("worker", None)
        job.planning, job.plan_worker, job.lease_until, job.plan_attempts = record, None, None, 0
        if index_key is not None:
            job.state, job.finished_at, job.index_key = "done", now(), index_key
        else:
            job.state = "running"
        return True, job.state, made


def _summary_of(summary: dict | None) -> dict | None:
    if not summary:
        return None
    keep = (
        "t_max", "unit", "cpvs", "cpvs_solved", "cpvs_unsolved", "cpvs_unsolvable", "impostors", "memory_bytes", "worst_before", "worst_after",
        "primitives", "p_opt", "model_triangles", "grid_points", "points_per_level", "images", "points_with_images", "unsolved_points", "check",
    )  # fmt: skip
    return {k: summary[k] for k in keep if k in summary}


def check_job(db: Database, blobs: BlobStore, job_id: str, worker: str, max_attempts: int) -> tuple[str, list[str]]:
    """Check a placement job's baked round and repair it (see the module docstring): (its state
    after, the cell ids of the added impostors, to send)."""
    from farfield.core.placement.repair import MAX_REPAIR_ROUNDS, PlannerState
    from farfield.service.jobs import job_cells

    claim = claim_planning(db, blobs, job_id, "check", worker, max_attempts)
    if claim.job is None:
        drop_ended_planning(db, blobs, job_id)
        return ("failed" if claim.ended else "skipped"), []
    job, attempt = claim.job, claim.attempt
    planning = job.planning
    round_ = int(planning.get("check_round", planning.get("round", 0) + 1))
    rounds = list(planning.get("rounds", []))
    if algorithm_of(job.params) == PRIMITIVE_BUDGET:  # no repair: the grid's guarantee counts triangles, which baking does not change
        with heartbeat(db, job_id, worker, attempt):
            grid = json.loads(blobs.read_bytes(planning["state_key"]))
            index_key = _write_database(db, blobs, job, grid, [])
        return _commit_round(db, blobs, job_id, worker, attempt, planning["state_key"], [], _impostors(grid), grid["summary"], round_ - 1, index_key, [])
    with heartbeat(db, job_id, worker, attempt):
        state = PlannerState.loads(blobs.read_bytes(planning["state_key"]))
        baked = {c.index: c.stats for c in job_cells(db, job_id) if c.state == "done" and c.stats}
        added: set[int] = set()
        # Past the last round the baked figures still go in (extend=False: nothing added), so the
        # database's CPV times and statuses are those of what is baked, never estimates.
        repaired = state.repair(baked, extend=round_ <= MAX_REPAIR_ROUNDS)
        rounds.append({**repaired.to_dict(), "round": round_})
        added = {int(i) for i in repaired.added}
        current = state.placement().to_dict()
        if added:
            state_key = _state_key(job_id, round_)
            blobs.put_bytes(state_key, state.dumps())
            return _commit_round(db, blobs, job_id, worker, attempt, state_key, _frame_time_cells(current, added), _impostors(current), current.get("summary"),
                                 round_, None, rounds)  # fmt: skip
        index_key = _write_database(db, blobs, job, current, rounds)
    return _commit_round(db, blobs, job_id, worker, attempt, planning["state_key"], [], _impostors(current), current.get("summary"), round_, index_key, rounds)


def run_planning(db: Database, blobs: BlobStore, job_id: str, phase: str, worker: str, max_attempts: int) -> tuple[str, list[str]]:
    """:func:`plan_job` or :func:`check_job`, a failure sorted as a cell's is
    (:func:`service.cell_runner.failure_class`): bad input fails the job with its message at once;
    a bug fails it as ``internal error: ...`` (a plan is deterministic: running it again would fail
    again); a transient failure frees the hold and is raised for the task to retry."""
    from farfield.service.cell_runner import BAD_INPUT, INTERNAL, TRANSIENT, failure_class, failure_message

    from celery.exceptions import SoftTimeLimitExceeded

    run = plan_job if phase == "plan" else check_job
    try:
        return run(db, blobs, job_id, worker, max_attempts)
    except SoftTimeLimitExceeded:  # the task fails the job, naming its limit
        raise
    except Exception as error:  # noqa: BLE001 - every failure is classified and recorded on the job
        klass = failure_class(error)
        if klass == TRANSIENT:
            release_planning(db, job_id, f"{type(error).__name__}: {error}", worker, max_attempts, blobs)
            raise
        if klass == INTERNAL:
            log.error("job %s %s: %s", job_id, phase, failure_message(error, klass), exc_info=error)
        message = failure_message(error, klass) if klass != BAD_INPUT else f"{type(error).__name__}: {error}"
        # Only while this worker holds it: a stale attempt must not fail a job a newer one plans.
        return ("failed" if fail_planning(db, job_id, message, worker, blobs=blobs) else "skipped"), []
