"""Jobs and their cells: the request schema, the state machine, progress, and the impostor database index.

A job names a technique of the registry (:data:`farfield.core.techniques.TECHNIQUES`: ``layered``,
``envmap``, ``tdm``; the request's former field ``job_type`` is still accepted) and its options,
validated from the technique's ``Options`` together with every cell's plan (the technique's
``check``) when the job is created.  The SQL column keeps the name ``job_type``.

States (kept in SQL, never in Celery results):

    cell: queued -> running -> done | failed | cancelled;  running -> queued (a failed attempt that
          will be retried; the attempt is counted)
    job:  queued -> running -> done | failed | cancelled
          a placement job (service.placement_jobs): queued -> placing -> running -> placing (check)
          -> running (repairs) ... -> done | failed | cancelled

A job ends when its last cell does: ``done`` when every cell is done, ``failed`` when some cell
failed, ``cancelled`` when cancelled.  The worker that ends the last cell builds the job's
impostor database index (``jobs/<id>/index.json``): every cell's view cell, state and bundle key,
and its neighbours on the grid (what a runtime prefetches), plus the lookup from a viewpoint to the
cells that serve it.
"""

from __future__ import annotations

import hashlib
import json
import math
import uuid
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictFloat, StrictInt, model_validator
from sqlalchemy import func, select, update

from farfield.core import __version__
from farfield.core.errors import ConflictError, JobTooCostlyError, LayerPlanError, NotFoundError, QueryError, QuotaError, ViewCellError
from farfield.core.impostor.database import database_index
from farfield.core.options import options_json_schema, stored_values
from farfield.core.techniques import DEFAULT_TECHNIQUE, TECHNIQUES, get_technique
from farfield.core.viewcells import BoxCell, grid_boxes, viewcell_from_dict
from farfield.service.blobs import BlobStore
from farfield.service.db import CELL_FINAL, JOB_STATES, OPEN_JOB_STATES, CellRow, Database, JobRow, SceneRow, now, owned_row
from farfield.service.placement_jobs import PLACEMENT_JOB, PlacementSpec, begin_check, drop_ended_planning, new_placement_job, placement_params
from farfield.service.settings import AdmissionLimits

MAX_CELLS = 10_000


class GridSpec(BaseModel):
    """A grid of equal box view cells over a view-space box."""

    model_config = ConfigDict(extra="forbid")
    # Strict: a string or a boolean is not a number (pydantic would coerce "1" and true to 1).
    lo: tuple[StrictFloat | StrictInt, StrictFloat | StrictInt, StrictFloat | StrictInt]
    hi: tuple[StrictFloat | StrictInt, StrictFloat | StrictInt, StrictFloat | StrictInt]
    counts: tuple[StrictInt, StrictInt, StrictInt] = Field(description=f"cells along x, y, z (each >= 1; {MAX_CELLS} in all at most)")


def _options_help() -> str:
    return "technique parameters (GET /v1/techniques lists each technique's options with types, defaults, bounds and help); " + "; ".join(
        f"{t.name}: " + ", ".join(o["name"] for o in t.describe()["options"]) for t in TECHNIQUES.values()
    )


class JobSpec(BaseModel):
    """A job request (``POST /v1/jobs``): one impostor per view cell of a scene's part (or of the
    whole scene, for a technique of scope ``scene``)."""

    # The document says what _one_view_space checks: exactly one of the two view spaces, not
    # null, and not both 'technique' and its former name.
    model_config = ConfigDict(extra="forbid", json_schema_extra={"oneOf": [
        {"required": ["viewcells"], "properties": {"viewcells": {"type": "array"}}},
        {"required": ["grid"], "properties": {"grid": {"type": "object"}}},
        {"required": ["placement"], "properties": {"placement": {"type": "object"}}},
    ], "not": {"anyOf": [
        {"required": ["technique", "job_type"], "properties": {"technique": {"type": "string"}, "job_type": {"type": "string"}}},
        {"required": ["placement", "objects"], "properties": {"placement": {"type": "object"}, "objects": {"type": "array"}}},
    ]}})  # fmt: skip
    scene_id: str
    technique: Literal[tuple(TECHNIQUES)] | None = Field(  # type: ignore[valid-type]
        None, description="the impostor technique (default layered): " + "; ".join(f"{t.name}: {t.help}" for t in TECHNIQUES.values())
    )
    job_type: Literal[tuple(TECHNIQUES)] | None = Field(  # type: ignore[valid-type]
        None, deprecated=True, description="the former name of 'technique', accepted until format 2 of the API; give one of them, not both"
    )
    viewcells: list[dict] | None = Field(None, description="explicit view cells, e.g. {'kind': 'box', 'lo': [..], 'hi': [..]}")
    grid: GridSpec | None = Field(None, description="or a grid of box cells over a view-space box")
    placement: PlacementSpec | None = Field(
        None,
        description="or a placement job: a view space, a frame budget and the planner's knobs; a worker plans where impostors of "
        "'technique' (a part technique: layered, tdm) are needed, bakes them, checks and repairs (job state 'placing' while it plans)",
    )
    objects: list[str] | None = Field(None, min_length=1, description="the represented objects, at least one (default, left out: all; not for scene-scope techniques)")
    resolution: StrictInt | None = Field(None, description="output image pixels per side (default: the technique's, 512)")
    fov_deg: StrictFloat | None = Field(None, description="output field of view, degrees (default: the technique's: 45, envmap 90)")
    options: dict = Field(
        default_factory=dict,
        description=_options_help(),
        json_schema_extra={"x-technique-options": {t.name: options_json_schema(t.Options) for t in TECHNIQUES.values()}},
    )
    evaluate: StrictBool = Field(
        True,
        description="evaluate each baked cell against the real geometry on the worker (techniques of one part: layered, tdm): "
        "hole pixels, pixels bloated beyond 1 px, colour error mean and 99th percentile, SSIM, from the reference viewpoint "
        "and three cell corners; the figures are in the cell's stats.evaluation, the time apart from the bake's. "
        "It changes no bundle; false skips it",
    )

    @model_validator(mode="after")
    def _one_view_space(self) -> JobSpec:
        if (self.viewcells is not None) + (self.grid is not None) + (self.placement is not None) != 1:
            raise ValueError("give exactly one of 'viewcells' (a list), 'grid' or 'placement'")
        if self.placement is not None and self.objects is not None:
            raise ValueError("a placement job chooses the objects its impostors replace: leave out 'objects'")
        former = self.__dict__.get("job_type")
        if self.technique is not None and former is not None:
            raise ValueError(f"'technique' ({self.technique}) and its former name 'job_type' ({former}) are both given; give one")
        return self

    @property
    def technique_name(self) -> str:
        # Read through __dict__: the deprecated field's attribute access warns.
        return self.technique or self.__dict__.get("job_type") or DEFAULT_TECHNIQUE


def grid_cells(grid: GridSpec) -> list[tuple[tuple[int, int, int], BoxCell]]:
    """The boxes of ``grid``, x fastest, with their (i, j, k)."""
    # Counts are checked as Python integers first: numpy's int64 product of huge ones would wrap.
    if min(grid.counts) < 1:
        raise ViewCellError(f"grid counts must be >= 1, got {list(grid.counts)}")
    total = math.prod(grid.counts)
    if total > MAX_CELLS:
        raise ViewCellError(f"grid of {total} cells is over the limit of {MAX_CELLS}")
    return grid_boxes(grid.lo, grid.hi, grid.counts)


def part_bounds(scene: SceneRow, objects: list[str] | None) -> np.ndarray:
    """(2, 3) bounds of the represented objects, from the stored object summaries."""
    by_name = {obj["name"]: obj for obj in scene.objects}
    names = objects or list(by_name)
    missing = [name for name in names if name not in by_name]
    if missing:
        known = sorted(by_name)  # a scene may have 10^5 objects: the message names a few
        shown = ", ".join(known[:20]) + (f", ... ({len(known)} in all; GET /v1/scenes/{scene.id}/objects)" if len(known) > 20 else "")
        raise NotFoundError(f"scene {scene.id!r} has no objects named {missing[:20]}; it has {shown}")
    bounds = np.array([by_name[name]["bounds"] for name in names], dtype=np.float64)
    return np.array([bounds[:, 0].min(axis=0), bounds[:, 1].max(axis=0)])


def approx(n: float) -> str:
    """A count for a message: exact below 100,000, else two significant digits.

    >>> approx(4096), approx(1_940_520_960), approx(4 * 10**9), approx(6.25e11)
    ('4,096', '1.9e9', '4e9', '6.2e11')
    """
    if n < 100_000:
        return f"{int(n):,}"
    mantissa, exponent = f"{n:.1e}".split("e")
    return f"{mantissa.removesuffix('.0')}e{int(exponent)}"


def open_tenant_cells(db: Database, tenant_id: str) -> int:
    """Cells of the tenant's jobs that are queued or running."""
    with db.session() as s:
        return s.scalar(
            select(func.count()).select_from(CellRow).join(JobRow, CellRow.job_id == JobRow.id)
            .where(JobRow.tenant_id == tenant_id, CellRow.state.in_(("queued", "running")))
        )  # fmt: skip


# How far past the limits admission plans a cell before it stops and refuses with a lower bound.
PLAN_BEYOND_LIMIT = 8


def admit_cells(technique, options, cells: list, bounds: np.ndarray | None, limits: AdmissionLimits) -> int:
    """Plan every cell (the technique's check) and refuse the job when a cell's estimated texels
    pass ``limits.max_cell_texels`` or all cells' pass ``limits.max_job_texels``
    (:class:`~farfield.core.errors.JobTooCostlyError`, 413); returns the job's texels.

    Each check is given ``PLAN_BEYOND_LIMIT`` times what is left of the budgets: a job a few times
    over its limits is refused with its full estimate, one far beyond them after planning that many
    layers, not all of its own (a hostile job costs the API a bounded plan), with a lower bound.
    """
    total = 0
    for n, (_, cell) in enumerate(cells):
        budget = PLAN_BEYOND_LIMIT * min(limits.max_cell_texels, limits.max_job_texels - total)
        try:
            cost = technique.check(cell, options, bounds, max_texels=budget)
        except (LayerPlanError, ViewCellError) as error:
            raise type(error)(f"view cell {n} ({cell.to_dict()}): {error}") from None
        about = "about" if cost.complete else "more than"
        if cost.texels > limits.max_cell_texels:
            raise JobTooCostlyError(
                f"view cell {n} needs {about} {approx(cost.texels)} texels ({cost.describe()}) over the limit of "
                f"{approx(limits.max_cell_texels)} per cell (FARFIELD_MAX_CELL_TEXELS): lower the resolution, use smaller "
                "or farther view cells, or raise the limit"
            )
        total += cost.texels
        if total > limits.max_job_texels:
            which = f"its {len(cells)} view cells need" if n == len(cells) - 1 else f"its first {n + 1} of {len(cells)} view cells already need"
            raise JobTooCostlyError(
                f"the job is too large: {which} {about} {approx(total)} texels over the limit of {approx(limits.max_job_texels)} per job "
                f"(FARFIELD_MAX_JOB_TEXELS): split it into smaller jobs, lower the resolution, or raise the limit"
            )
    return total


def create_job(db: Database, tenant_id: str, scene: SceneRow, spec: JobSpec, limits: AdmissionLimits | None = None) -> JobRow:
    """Validate ``spec`` against ``scene`` (every cell is planned by its technique's check) and store
    the job and its cells.  Stored parameters hold every option as validated (the technique's
    defaults filled in, numbers and lists normalised), so equal requests store equal parameters (and
    share their bundles, :func:`result_key`) and a job means the same thing if a default changes.

    Cost admission (``limits``; None: :meth:`AdmissionLimits.from_env`): a tenant whose queued and
    running cells would pass ``max_tenant_cells`` with this job's is refused with
    :class:`~farfield.core.errors.QuotaError` (429) before anything is planned; a job whose cells'
    plans pass the texel limits with :class:`~farfield.core.errors.JobTooCostlyError` (413,
    :func:`admit_cells`).  Nothing is stored for a refused job.  Two requests of one tenant at the
    same moment may both pass the cell count (it is read, not locked): the cap is a bound on work in
    flight, not an exact quota."""
    limits = AdmissionLimits.from_env() if limits is None else limits
    if spec.placement is not None:
        return create_placement_job(db, tenant_id, scene, spec)
    technique = get_technique(spec.technique_name)
    options = technique.options(spec.options, spec.resolution, spec.fov_deg)
    params = {"resolution": options.resolution, "fov_deg": options.fov_deg, "objects": spec.objects, "options": stored_values(options)}
    if technique.scope == "scene" and spec.objects is not None:
        raise LayerPlanError(f"a {technique.name} job represents the whole scene: leave out 'objects' (it is for techniques of one part)")
    if spec.grid is not None:
        cells = [(list(ijk), box) for ijk, box in grid_cells(spec.grid)]
    else:
        if not spec.viewcells:
            raise ViewCellError("'viewcells' is empty")
        if len(spec.viewcells) > MAX_CELLS:
            raise ViewCellError(f"{len(spec.viewcells)} view cells is over the limit of {MAX_CELLS}")
        cells = [(None, viewcell_from_dict(cell)) for cell in spec.viewcells]
    bounds = part_bounds(scene, spec.objects) if technique.scope == "part" else None
    if len(cells) > limits.max_tenant_cells:  # it could never pass: not a 429 to retry
        raise JobTooCostlyError(
            f"the job's {len(cells):,} view cells are more than a tenant may have queued or running, {limits.max_tenant_cells:,} "
            "(FARFIELD_MAX_TENANT_CELLS): split it into smaller jobs, or raise the limit"
        )
    open_cells = open_tenant_cells(db, tenant_id)
    if open_cells + len(cells) > limits.max_tenant_cells:
        raise QuotaError(
            f"tenant has {open_cells:,} cells queued or running; this job's {len(cells):,} would pass the limit of "
            f"{limits.max_tenant_cells:,} (FARFIELD_MAX_TENANT_CELLS): wait for some to end, or cancel a job"
        )
    admit_cells(technique, options, cells, bounds, limits)
    job = JobRow(
        id=uuid.uuid4().hex, tenant_id=tenant_id, scene_id=scene.id, job_type=technique.name, params=params,
        evaluate=spec.evaluate, state="queued", created_at=now(),
    )  # fmt: skip
    with db.session() as s:
        s.add(job)
        s.flush()
        for n, (grid, cell) in enumerate(cells):
            s.add(CellRow(id=uuid.uuid4().hex, job_id=job.id, index=n, grid=grid, viewcell=cell.to_dict(), state="queued", attempts=0, progress=0.0, queued_at=now()))
    return job


def create_placement_job(db: Database, tenant_id: str, scene: SceneRow, spec: JobSpec, requeue_after: float = 3600.0) -> JobRow:
    """Validate a placement request (:func:`service.placement_jobs.placement_params`: 422 naming the
    problem) and store the job, queued for planning, without cells (the planner makes them).  Its
    cells are not known yet, so the texel and tenant-cell admission of a grid job does not apply."""
    technique = spec.technique or spec.__dict__.get("job_type")  # None: the algorithm's default
    params = placement_params(technique, spec.options, spec.resolution, spec.fov_deg, spec.placement, scene.triangles)
    job = new_placement_job(tenant_id, scene, params, requeue_after)
    with db.session() as s:
        s.add(job)
    return job


def get_job_row(db: Database, tenant_id: str, job_id: str) -> JobRow:
    return owned_row(db, JobRow, tenant_id, job_id, "job")


def job_cells(db: Database, job_id: str) -> list[CellRow]:
    with db.session() as s:
        return list(s.scalars(select(CellRow).where(CellRow.job_id == job_id).order_by(CellRow.index)))


def get_cell_row(db: Database, tenant_id: str, job_id: str, index: int) -> CellRow:
    get_job_row(db, tenant_id, job_id)
    with db.session() as s:
        cell = s.scalar(select(CellRow).where(CellRow.job_id == job_id, CellRow.index == index))
    if cell is None:
        raise NotFoundError(f"job {job_id!r} has no cell {index}")
    return cell


def cell_record(cell: CellRow) -> dict:
    return {
        "index": cell.index, "grid": cell.grid, "viewcell": cell.viewcell, "state": cell.state,
        "attempts": cell.attempts, "worker": cell.worker, "error": cell.error, "progress": cell.progress, "seconds": cell.seconds,
        "stats": cell.stats, "has_result": cell.result_key is not None,
        "params": cell.params,  # a placement cell's own impostor (technique, objects, options); None: the job's
    }  # fmt: skip


ERRORS_SHOWN = 20  # cell errors listed per job record (errors_total counts them all)


def job_summaries(db: Database, job_ids: list[str]) -> dict[str, dict]:
    """Per job, computed in SQL (no cell rows loaded): counts by state, the running cells' progress,
    finished cells' seconds, and the first cell errors."""
    out = {job_id: {"counts": dict.fromkeys(("queued", "running", "done", "failed", "cancelled"), 0), "running_progress": 0.0,
                    "done_seconds": 0.0, "done_timed": 0, "errors": [], "errors_total": 0} for job_id in job_ids}  # fmt: skip
    if not job_ids:
        return out
    with db.session() as s:
        rows = s.execute(
            select(CellRow.job_id, CellRow.state, func.count(), func.sum(CellRow.progress), func.sum(CellRow.seconds), func.count(CellRow.seconds))
            .where(CellRow.job_id.in_(job_ids)).group_by(CellRow.job_id, CellRow.state)
        )  # fmt: skip
        for job_id, state, count, progress, seconds, timed in rows:
            summary = out[job_id]
            summary["counts"][state] = count
            if state == "running":
                summary["running_progress"] = float(progress or 0.0)
            if state == "done":
                summary["done_seconds"], summary["done_timed"] = float(seconds or 0.0), int(timed)
        errors = s.execute(
            select(CellRow.job_id, CellRow.index, CellRow.error).where(CellRow.job_id.in_(job_ids), CellRow.error.is_not(None)).order_by(CellRow.job_id, CellRow.index)
        )  # fmt: skip
        for job_id, index, error in errors:
            summary = out[job_id]
            summary["errors_total"] += 1
            if len(summary["errors"]) < ERRORS_SHOWN:
                summary["errors"].append({"index": index, "error": error})
    return out


def evaluation_summary(cells: list[CellRow]) -> dict | None:
    """Over the cells evaluated so far (``stats.evaluation``, :func:`farfield.core.techniques.part.report_part`):
    how many, how many break the guarantee (a hole pixel or a pixel bloated beyond one), their hole
    and bloated pixels, the worst SSIM and the seconds spent evaluating; None when none was."""
    found = [c.stats["evaluation"] for c in cells if c.stats and c.stats.get("evaluation")]
    if not found:
        return None
    return {
        "cells": len(found),
        "cells_broken": sum(1 for e in found if e["hole_pixels"] or e["bloat_beyond_1px"]),
        "hole_pixels": sum(e["hole_pixels"] for e in found),
        "bloat_beyond_1px": sum(e["bloat_beyond_1px"] for e in found),
        "colour_error_mean": max(e["colour_error_mean"] for e in found),  # the worst cell's
        "ssim_min": min(e["ssim_min"] for e in found),
        "seconds": sum(e["seconds"] for e in found),
    }


def job_record(job: JobRow, summary: dict, cells: list[CellRow] | None = None) -> dict:
    """The API's view of a job: state, counts, progress, timings, errors, ETA (and, given its cells,
    each cell's record and the :func:`evaluation_summary` of them)."""
    counts = summary["counts"]
    total = sum(counts.values())
    # The share of the work that was carried out: a cancelled cell was not, so a job cancelled with 7
    # of 27 cells done shows 26 %, not 100 %.
    finished = counts["done"] + counts["failed"]
    progress = (finished + summary["running_progress"]) / max(total, 1)
    mean = summary["done_seconds"] / summary["done_timed"] if summary["done_timed"] else None
    eta = None
    if job.state in ("queued", "running") and mean is not None:
        remaining = counts["queued"] + counts["running"] - summary["running_progress"]
        busy = max(counts["running"], 1)  # cells in flight approximates the workers serving the job
        eta = remaining * mean / busy
    placement = job.job_type == PLACEMENT_JOB
    record = {
        "id": job.id, "scene_id": job.scene_id, "technique": job.params["technique"] if placement else job.job_type, "job_type": job.job_type, "state": job.state, "params": job.params,
        "evaluate": job.evaluate, "error": job.error, "cells_total": total, "counts": counts, "progress": progress, "eta_s": eta,
        "created_at": job.created_at, "started_at": job.started_at, "finished_at": job.finished_at,
        "seconds": {"cells_total": summary["done_seconds"], "cell_mean": mean,
                    "wall": (job.finished_at or now()) - job.started_at if job.started_at else None},
        "errors": summary["errors"], "errors_total": summary["errors_total"],
        "has_index": job.index_key is not None,
    }  # fmt: skip
    if placement:  # phase, step, done, total, round, rounds, summary (service.placement_jobs)
        record["placement"] = job.planning
    if cells is not None:
        record["cells"] = [cell_record(c) for c in cells]
        record["evaluation"] = evaluation_summary(cells)
    return record


def full_job_record(db: Database, job: JobRow) -> dict:
    """A job's record with all its cells."""
    return job_record(job, job_summaries(db, [job.id])[job.id], job_cells(db, job.id))


def _jobs_query(query, tenant_id: str, state: str | None, scene_id: str | None):
    if state is not None and state not in JOB_STATES:
        raise QueryError(f"unknown job state {state!r}; one of {list(JOB_STATES)}")
    query = query.where(JobRow.tenant_id == tenant_id)
    if state:
        query = query.where(JobRow.state == state)
    if scene_id:
        query = query.where(JobRow.scene_id == scene_id)
    return query


def list_job_rows(db: Database, tenant_id: str, state: str | None = None, scene_id: str | None = None, limit: int = 100, offset: int = 0) -> list[JobRow]:
    """The tenant's jobs, newest first, ``limit`` from ``offset``."""
    query = _jobs_query(select(JobRow), tenant_id, state, scene_id)
    with db.session() as s:
        return list(s.scalars(query.order_by(JobRow.created_at.desc(), JobRow.id).limit(limit).offset(offset)))


def count_job_rows(db: Database, tenant_id: str, state: str | None = None, scene_id: str | None = None) -> int:
    """How many jobs :func:`list_job_rows` pages through."""
    with db.session() as s:
        return s.scalar(_jobs_query(select(func.count()).select_from(JobRow), tenant_id, state, scene_id))


def queued_cell_ids(db: Database, job_id: str) -> list[str]:
    with db.session() as s:
        return list(s.scalars(select(CellRow.id).where(CellRow.job_id == job_id, CellRow.state == "queued").order_by(CellRow.index)))


# --- the worker's side -------------------------------------------------------------------------


def result_key(scene_hash: str, job_type: str, params: dict, viewcell: dict) -> str:
    """Blob prefix of a cell's bundle: a digest of everything that determines its bytes.

    Equal inputs (even in another job) give the same key, so a redelivered or repeated cell
    overwrites identical bytes and never makes a second impostor.
    """
    blob = json.dumps(
        {"scene": scene_hash, "type": job_type, "params": params, "viewcell": viewcell, "code": __version__},
        sort_keys=True, separators=(",", ":"),
    )  # fmt: skip
    return "impostors/" + hashlib.sha256(blob.encode()).hexdigest()


@dataclass(frozen=True)
class Claim:
    """What :func:`claim_cell` decided: run ``cell`` (attempt ``cell.attempts``), or not; ``ended``
    when it ended the cell itself (cancelled job, attempts used up), so the job may be complete."""

    cell: CellRow | None
    job_id: str | None = None
    ended: bool = False


def claim_cell(db: Database, cell_id: str, max_attempts: int, worker: str | None = None) -> Claim:
    """Mark the cell running and count the attempt, unless it must not run.

    A cell found ``running`` is one whose earlier attempt never reported back: its worker process
    died (killed, out of memory, a driver crash) and the broker delivered it again.  Such a cell
    runs again until ``max_attempts``, then is failed here, so a cell that kills its worker cannot
    loop forever.  Locks the job row before the cell row, as :func:`cancel_job` does.
    """
    with db.session() as s:
        job_id = s.scalar(select(CellRow.job_id).where(CellRow.id == cell_id))
        if job_id is None:
            return Claim(None)
        job = s.get(JobRow, job_id, with_for_update=True)
        cell = s.get(CellRow, cell_id, with_for_update=True, populate_existing=True)
        if cell.state in CELL_FINAL:
            return Claim(None, job_id)
        if job.state == "cancelled":
            cell.state, cell.finished_at = "cancelled", now()
            return Claim(None, job_id, ended=True)
        if cell.state == "running" and cell.attempts >= max_attempts:
            cell.state, cell.finished_at = "failed", now()
            cell.error = _never_reported(cell.attempts, max_attempts, "its worker process died: killed, out of memory or crashed; or the database or blob store failed around it")
            return Claim(None, job_id, ended=True)
        cell.state, cell.attempts, cell.started_at, cell.progress, cell.error = "running", cell.attempts + 1, now(), 0.0, None
        cell.worker = worker
        if job.state == "queued":
            job.state, job.started_at = "running", now()
        return Claim(cell, job_id)


def _never_reported(attempt: int, max_attempts: int, why: str) -> str:
    return f"attempt {attempt} of {max_attempts} never reported back ({why})"


# queued_at of a cell whose message is stuck with a dead worker: the API's sweeper
# (lost_queued_cells) sends it again at its next sweep instead of after FARFIELD_REQUEUE_AFTER.
RESEND_NOW = 0.0


def release_lost_cells(db: Database, blobs: BlobStore, cell_ids: list[str], max_attempts: int, why: str, *, worker: str | None = None, resend: bool = False) -> dict[str, str]:
    """The cells of a worker process that died, moved on at once instead of showing ``running``
    until their message comes back (which, for a whole worker, is the visibility timeout later).

    Each of ``cell_ids`` still running (on ``worker``, when given) is queued again with ``why`` as
    its error, or failed when its attempt was the last (:func:`claim_cell` would fail it on the
    next delivery); a job left without open cells ends.  ``resend``: its message is not coming
    back soon (the whole worker died with it unacknowledged), so the API's sweeper sends it again.
    Returns the new state by cell id (cells that had moved on are left out)."""
    changed: dict[str, str] = {}
    for cell_id in cell_ids:
        with db.session() as s:
            job_id = s.scalar(select(CellRow.job_id).where(CellRow.id == cell_id))
            if job_id is None:
                continue
            s.get(JobRow, job_id, with_for_update=True)  # the lock order of claim_cell
            cell = s.get(CellRow, cell_id, with_for_update=True, populate_existing=True)
            if cell.state != "running" or (worker is not None and cell.worker != worker):
                continue
            if cell.attempts >= max_attempts:
                cell.state, cell.finished_at = "failed", now()
                cell.error = _never_reported(cell.attempts, max_attempts, why)
            else:
                cell.state, cell.progress = "queued", 0.0
                cell.queued_at = RESEND_NOW if resend else now()
                cell.error = f"attempt {cell.attempts} of {max_attempts} was lost ({why}); queued again"
            changed[cell_id] = cell.state
        if changed[cell_id] == "failed":
            finish_job_if_complete(db, blobs, job_id)
    return changed


def running_cells_of(db: Database, worker: str) -> list[str]:
    """Ids of the cells that ``worker`` (a Celery node name, ``name@host``) is running."""
    with db.session() as s:
        return list(s.scalars(select(CellRow.id).where(CellRow.state == "running", CellRow.worker == worker)))


def job_cancelled(db: Database, job_id: str) -> bool:
    with db.session() as s:
        return s.scalar(select(JobRow.state).where(JobRow.id == job_id)) == "cancelled"


def set_progress(db: Database, cell_id: str, fraction: float) -> None:
    with db.session() as s:
        s.execute(update(CellRow).where(CellRow.id == cell_id, CellRow.state == "running").values(progress=fraction))


def end_cell(db: Database, cell_id: str, attempt: int, state: str, *, result: str | None = None, stats: dict | None = None, error: str | None = None, seconds: float | None = None) -> bool:
    """Move the cell from running attempt ``attempt`` to ``state`` (done, failed, cancelled, or
    queued for another attempt).  False, and nothing written, when the cell has moved on since (a
    stale duplicate delivery of an older attempt, or a cancel)."""
    values: dict = {"state": state, "error": error}
    if state == "queued":
        values.update(progress=0.0, queued_at=now())
    else:
        values.update(finished_at=now(), seconds=seconds)
        if state == "done":
            values["progress"] = 1.0
    if result is not None:
        values.update(result_key=result, stats=stats)
    with db.session() as s:
        return s.execute(update(CellRow).where(CellRow.id == cell_id, CellRow.state == "running", CellRow.attempts == attempt).values(**values)).rowcount == 1


def finish_job_if_complete(db: Database, blobs: BlobStore, job_id: str) -> bool:
    """End the job when no cell is left to run; True if this call ended it.

    The index is written before the state flips, so a ``done`` job always has one; workers that
    finish at once may both write it (the same document), and the conditional update lets one win.
    """
    with db.session() as s:
        open_cells = s.scalar(select(func.count()).select_from(CellRow).where(CellRow.job_id == job_id, CellRow.state.in_(("queued", "running"))))
        if open_cells:
            return False
        job = s.get(JobRow, job_id)
        if job.state == "cancelled":
            if job.finished_at is None:
                job.finished_at = now()
            return False
        if job.state not in ("queued", "running"):
            return False
        states = set(s.scalars(select(CellRow.state).where(CellRow.job_id == job_id)))
    final = "failed" if "failed" in states else "done" if states <= {"done"} else "cancelled"
    if job.job_type == PLACEMENT_JOB:
        return _end_placement_round(db, job_id, final)
    key = write_index(db, blobs, job_id, final)
    with db.session() as s:
        won = s.execute(update(JobRow).where(JobRow.id == job_id, JobRow.state.in_(("queued", "running"))).values(state=final, finished_at=now(), index_key=key)).rowcount
    return bool(won)


def _end_placement_round(db: Database, job_id: str, final: str) -> bool:
    """A placement job's round ended: all done -> placing, to be checked (its worker sends the check
    task, :func:`service.placement_jobs.pending_check`); else the job ends ``final`` (no database:
    it is written by the check)."""
    with db.session() as s:
        job = s.get(JobRow, job_id, with_for_update=True)
        if job.state != "running":
            return False
        if final == "done":
            begin_check(s, job)
            return False
        job.state, job.finished_at = final, now()
        return True


def index_document(job: JobRow, cells: list[CellRow]) -> dict:
    """The impostor database index of a job (:func:`farfield.core.impostor.database.database_index`)."""
    entries = [
        {"index": c.index, "grid": c.grid, "viewcell": c.viewcell, "state": c.state, "bundle": f"cells/{c.index:05d}/" if c.result_key else None}
        for c in cells
    ]  # fmt: skip
    return database_index(job.job_type, job.params, entries, job=job.id, scene=job.scene_id)


def write_index(db: Database, blobs: BlobStore, job_id: str, final_state: str) -> str:
    """Write the job's impostor database index (as it ends in ``final_state``); returns its key."""
    with db.session() as s:
        job = s.get(JobRow, job_id)
    job.state = final_state  # the state the index describes; the row itself changes after the write
    key = f"jobs/{job_id}/index.json"
    blobs.put_bytes(key, json.dumps(index_document(job, job_cells(db, job_id)), sort_keys=True, indent=1).encode())
    return key


# --- the API's side ----------------------------------------------------------------------------


def cancel_job(db: Database, blobs: BlobStore, tenant_id: str, job_id: str) -> JobRow:
    """Cancel: queued cells never run; running cells stop at their next layer."""
    get_job_row(db, tenant_id, job_id)
    with db.session() as s:
        # Conditional, and the job row first (the lock order of claim_cell): a job that ended
        # meanwhile stays as it ended.
        changed = s.execute(update(JobRow).where(JobRow.id == job_id, JobRow.state.in_(OPEN_JOB_STATES)).values(state="cancelled")).rowcount
        if changed:
            s.execute(update(CellRow).where(CellRow.job_id == job_id, CellRow.state == "queued").values(state="cancelled", finished_at=now()))
    if not changed:
        raise ConflictError(f"job {job_id!r} is already {get_job_row(db, tenant_id, job_id).state}")
    finish_job_if_complete(db, blobs, job_id)
    job = get_job_row(db, tenant_id, job_id)
    if job.job_type == PLACEMENT_JOB and job.plan_worker is None:
        # No worker holds its planning (one that does deletes them when it sees the cancel), and a
        # check message still queued would only find the job cancelled: its planner states go now.
        drop_ended_planning(db, blobs, job_id)
    return job


def retry_job(db: Database, tenant_id: str, job_id: str) -> list[str]:
    """Queue the failed cells of a failed job again (attempts reset); returns their ids.  A placement
    job that failed before its cells were baked (planning or checking) is not retried: submit it again."""
    job = get_job_row(db, tenant_id, job_id)
    if job.job_type == PLACEMENT_JOB and job.state == "failed" and (job.planning or {}).get("phase") != "bake":
        raise ConflictError(f"job {job_id!r} failed while placing ({job.error}); submit it again")
    with db.session() as s:
        changed = s.execute(update(JobRow).where(JobRow.id == job_id, JobRow.state == "failed").values(state="running", finished_at=None, index_key=None)).rowcount
        if changed:
            ids = list(s.scalars(select(CellRow.id).where(CellRow.job_id == job_id, CellRow.state == "failed")))
            s.execute(update(CellRow).where(CellRow.id.in_(ids)).values(state="queued", attempts=0, error=None, progress=0.0, finished_at=None, queued_at=now()))
    if not changed:
        raise ConflictError(f"only a failed job can be retried; job {job_id!r} is {get_job_row(db, tenant_id, job_id).state}")
    return ids


def lost_queued_cells(db: Database, older_than_s: float) -> list[str]:
    """Cells queued longer than ``older_than_s`` ago, claimed for sending again.

    A queued cell's message can be lost: Redis restarted without writing its last second, or the
    API died while sending a job's cells.  Such a cell would wait forever; sending it again costs at
    most a duplicate delivery, which the attempt-keyed state changes make harmless.  Each id is
    claimed by a conditional update of ``queued_at``, so several API processes sweeping at once send
    it once.
    """
    cutoff = now() - older_than_s
    with db.session() as s:
        candidates = list(s.scalars(select(CellRow.id).where(CellRow.state == "queued", CellRow.queued_at < cutoff).limit(MAX_CELLS)))
    claimed = []
    for cell_id in candidates:
        with db.session() as s:
            if s.execute(update(CellRow).where(CellRow.id == cell_id, CellRow.state == "queued", CellRow.queued_at < cutoff).values(queued_at=now())).rowcount:
                claimed.append(cell_id)
    return claimed


def lookup(cells: list[CellRow], point) -> list[CellRow]:
    """The cells whose view cell contains ``point`` (the impostors that serve that viewpoint)."""
    p = np.asarray(point, dtype=np.float64).reshape(1, 3)
    return [c for c in cells if bool(viewcell_from_dict(c.viewcell).contains(p, tol=1e-9)[0])]
