"""A job's and its cells' records as the API shows them, and the queries behind them.

A job's record (:func:`job_record`) has its state, counts by cell state, progress, timings, the
first cell errors and an ETA, and, given its cells, each cell's record (:func:`cell_record`),
the evaluation summary of those evaluated so far and the breakdown of the job's time
(``timing``, :func:`farfield.service.jobs.timing.job_timing`); a placement job's shows its technique and its
planning record as ``"placement"``, a job of view cells its admission (``"admission"``, :data:`ADMISSION_FIELDS`).
"""

from __future__ import annotations

from dataclasses import dataclass

from sqlalchemy import false, func, select

from farfield.core.errors import NotFoundError, QueryError
from farfield.service.db import JOB_STATES, CellRow, Database, JobRow, job_cells, now, owned_row, storable
from farfield.service.jobs.timing import job_timing
from farfield.service.placement import PLACEMENT_JOB

__all__ = [
    "ERRORS_SHOWN", "CellView", "cell_record", "cell_views", "cell_records", "count_job_rows", "evaluation_summary", "full_job_record", "get_cell_row", "get_job_row",
    "cell_page", "count_cells", "job_cells", "job_record", "job_summaries", "list_job_rows", "queued_cell_ids",
]  # fmt: skip


def get_job_row(db: Database, tenant_id: str, job_id: str) -> JobRow:
    return owned_row(db, JobRow, tenant_id, job_id, "job")


def get_cell_row(db: Database, tenant_id: str, job_id: str, index: int) -> CellRow:
    get_job_row(db, tenant_id, job_id)
    with db.reading() as s:
        cell = s.scalar(select(CellRow).where(CellRow.job_id == job_id, CellRow.index == index))
    if cell is None:
        raise NotFoundError(f"job {job_id!r} has no cell {index}")
    return cell


def cell_record(cell: CellRow) -> dict:
    return {
        "index": cell.index, "grid": cell.grid, "viewcell": cell.viewcell, "state": cell.state,
        "attempts": cell.attempts, "worker": cell.worker, "error": cell.error, "progress": cell.progress, "seconds": cell.seconds,
        "stats": cell.stats, "has_result": cell.result_key is not None,
        "texels": cell.texels,  # what its admission planned (None: not planned); its queue's (service.pools)
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
    with db.reading() as s:
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
    } | _lit_summary([e["lit"] for e in found if e.get("lit")])


def _lit_summary(lit: list[dict]) -> dict:
    """The worst lit figures over the cells with lit impostors (``{}`` when none has one)."""
    if not lit:
        return {}
    return {
        "lit": {
            "cells": len(lit),
            "lit_error_mean_worst": max(e["lit_error_mean_worst"] for e in lit),
            "lit_to_unlit_worst": max(e["lit_to_unlit_worst"] for e in lit),
            "flat_to_lit_least": min(e["flat_to_lit_least"] for e in lit),
            "normal_error_median": max(e["normal_error_median"] for e in lit),
            "normal_error_smooth_p95": max(e["normal_error_smooth_p95"] for e in lit),
        }
    }


# What a job's record shows of its admission (service.jobs.admitting): "admit" while its cells are
# checked, "admitted" after; cells checked (done) of total, their texels, the cells that failed, the
# request's lower bound of the job's texels.
ADMISSION_FIELDS = ("phase", "done", "total", "texels", "failed", "bound_texels")


def job_record(job: JobRow, summary: dict, cells: list[CellRow] | None = None) -> dict:
    """The API's view of a job: state, counts, progress, timings, errors, ETA (and, given its cells,
    each cell's record, the :func:`evaluation_summary` of them and the job's ``timing``)."""
    counts = summary["counts"]
    total = sum(counts.values())
    # The share of the work that was carried out: a cancelled cell was not, so a job cancelled with 7
    # of 27 cells done shows 26 %, not 100 %.
    finished = counts["done"] + counts["failed"]
    # A done job did all its work, cells or none (a placement that needed no impostor: 0 cells).
    progress = 1.0 if job.state == "done" else (finished + summary["running_progress"]) / max(total, 1)
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
    if placement:  # phase, step, done, total, round, rounds, summary (service.placement)
        record["placement"] = job.planning
    elif job.planning is not None:  # the cells' full checks: done, total, texels, failed (service.jobs.admitting)
        record["admission"] = {k: job.planning.get(k) for k in ADMISSION_FIELDS}
    if cells is not None:
        record["cells"] = [cell_record(c) for c in cells]
        record["evaluation"] = evaluation_summary(cells)
        record["timing"] = job_timing(job, cells, placement)
    return record


@dataclass(slots=True)
class CellView:
    """A cell's columns that its record, the job's timing and its index read, as a plain object: a
    10,000-cell job's record loads its cells some times faster so than as ORM rows (each tracked
    in the session's identity map), and a ``Row``'s ``index`` would be the tuple method."""

    index: int
    grid: list | None
    viewcell: dict
    state: str
    attempts: int
    worker: str | None
    error: str | None
    progress: float
    seconds: float | None
    stats: dict | None
    result_key: str | None
    params: dict | None
    texels: float | None
    started_at: float | None
    finished_at: float | None


_VIEW_COLUMNS = tuple(getattr(CellRow, name) for name in CellView.__slots__)


def cell_views(db: Database, job_id: str) -> list[CellView]:
    """The job's cells by index as :class:`CellView` (read in a reading session: on SQLite it holds no
    write lock, so a large job's record never holds up the workers' commits)."""
    with db.reading() as s:
        return [
            CellView(*row)
            for row in s.execute(select(*_VIEW_COLUMNS).where(CellRow.job_id == job_id).order_by(CellRow.index))
        ]


def full_job_record(db: Database, job: JobRow) -> dict:
    """A job's record with all its cells."""
    return job_record(job, job_summaries(db, [job.id])[job.id], cell_views(db, job.id))


def cell_page(db: Database, job_id: str, limit: int, offset: int) -> list[dict]:
    """The records of the job's cells ``offset`` to ``offset + limit`` by index (``GET
    /v1/jobs/{id}/cells``): a client that polls a large job pages through its cells, or asks for the
    record without them (``?cells=none``), instead of the whole list every time."""
    query = select(*_VIEW_COLUMNS).where(CellRow.job_id == job_id).order_by(CellRow.index).limit(limit).offset(offset)
    with db.reading() as s:
        return [cell_record(CellView(*row)) for row in s.execute(query)]


def count_cells(db: Database, job_id: str) -> int:
    """How many cells :func:`cell_page` pages through."""
    with db.reading() as s:
        return s.scalar(select(func.count()).select_from(CellRow).where(CellRow.job_id == job_id))


def _jobs_query(query, tenant_id: str, state: str | None, scene_id: str | None):
    if state is not None and state not in JOB_STATES:
        raise QueryError(f"unknown job state {state!r}; one of {list(JOB_STATES)}")
    query = query.where(JobRow.tenant_id == tenant_id)
    if state:
        query = query.where(JobRow.state == state)
    if scene_id:
        # An id no backend can hold names no scene: no jobs (not a DataError on PostgreSQL).
        query = query.where(JobRow.scene_id == scene_id) if storable(scene_id) else query.where(false())
    return query


def list_job_rows(
    db: Database,
    tenant_id: str,
    state: str | None = None,
    scene_id: str | None = None,
    limit: int = 100,
    offset: int = 0,
) -> list[JobRow]:
    """The tenant's jobs, newest first, ``limit`` from ``offset``."""
    query = _jobs_query(select(JobRow), tenant_id, state, scene_id)
    with db.reading() as s:
        return list(s.scalars(query.order_by(JobRow.created_at.desc(), JobRow.id).limit(limit).offset(offset)))


def count_job_rows(db: Database, tenant_id: str, state: str | None = None, scene_id: str | None = None) -> int:
    """How many jobs :func:`list_job_rows` pages through."""
    with db.reading() as s:
        return s.scalar(_jobs_query(select(func.count()).select_from(JobRow), tenant_id, state, scene_id))


def queued_cell_ids(db: Database, job_id: str) -> list[str]:
    with db.reading() as s:
        return list(
            s.scalars(
                select(CellRow.id).where(CellRow.job_id == job_id, CellRow.state == "queued").order_by(CellRow.index)
            )
        )


def cell_records(db: Database, job_id: str, indices: list[int]) -> list[dict]:
    """The cell records of ``indices`` of a job, in that order (those it has)."""
    if not indices:
        return []
    with db.reading() as s:
        rows = {
            c.index: c for c in s.scalars(select(CellRow).where(CellRow.job_id == job_id, CellRow.index.in_(indices)))
        }
    return [cell_record(rows[i]) for i in indices if i in rows]
