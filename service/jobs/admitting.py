"""A job in the state ``admitting``: every cell's full check on a worker, before any cell is baked.

``POST /v1/jobs`` plans nothing (:mod:`farfield.service.jobs.admission`: a cheap lower bound, then the
job is stored ``admitting``); the worker task ``farfield.admit_job`` runs :func:`admit_job`, which
checks the job's queued cells in index order with their technique's full check
(:func:`~farfield.service.jobs.admission.check_cell`: for a part technique the layer plan the bake
will use):

- a cell whose plan has no answer, or whose texels pass ``FARFIELD_MAX_CELL_TEXELS``, fails with the
  message the request's 413 gave before issue 58 (``JobTooCostlyError: view cell 3 needs about ...``);
- when the cells' texels together pass ``FARFIELD_MAX_JOB_TEXELS`` the job fails with the job's
  413 message, every cell not yet failed with it;
- otherwise the job becomes ``queued`` and the cells that passed are sent, each to the queue of its
  planned texels (stored as ``cells.texels``: :mod:`farfield.service.pools`, GPU and CPU pools).

Progress (the job's ``planning`` record, ``GET /v1/jobs/{id}`` shows it as ``admission``: ``done`` of
``total`` cells checked, ``texels`` found, ``failed``, and the ``seconds`` the deliveries spent checking, the
job's ``timing.admission_s``: :mod:`farfield.service.jobs.timing`) is committed about every ``COMMIT_EVERY_S``
together with the cells failed meanwhile, so a delivery that dies loses at most that much work and
the next one goes on from ``next``.  One worker at a time holds the admission under a lease
(``jobs.plan_worker``, ``jobs.lease_until``, renewed at each commit); an admission whose lease runs
out (its worker died, or its message was lost) is sent again by the API's sweeper
(:func:`lost_admissions`).  A delivery that commits no progress counts: after ``max_attempts`` such
deliveries in a row the job fails.  A cancelled job's admission stops at its next commit.
"""

from __future__ import annotations

import time

from sqlalchemy import select, update

from farfield.core.errors import JobTooCostlyError
from farfield.core.techniques import get_technique
from farfield.core.viewcells import viewcell_from_dict
from farfield.service.blobs import BlobStore
from farfield.service.db import CellRow, Database, JobRow, SceneRow, now
from farfield.service.jobs.admission import check_cell, job_too_costly, part_bounds
from farfield.service.jobs.cells import finish_job_if_complete
from farfield.service.settings import ADMISSION_LEASE_S, AdmissionLimits

ADMIT = "admit"  # the planning record's phase while a job is admitted
COMMIT_EVERY_S = 0.5  # progress and the failed cells are committed this often


def _claim(db: Database, job_id: str, worker: str, max_attempts: int, lease_s: float):
    """Hold the job's admission for ``worker``: (job, attempt, part bounds), or (None, "why") when
    it must not run here (the job is not admitting, a live worker holds it, or this delivery ended it)."""
    with db.session() as s:
        job = s.get(JobRow, job_id, with_for_update=True)
        if job is None or job.state != "admitting":
            return None, "skipped", None
        if job.plan_worker is not None and (job.lease_until or 0.0) > now():
            return None, "skipped", None  # a duplicate delivery: a live worker holds it
        record = dict(job.planning or {})
        stalled = int(record.get("stalled", 0))
        if stalled >= max_attempts:
            message = (
                f"admission attempt {stalled} of {max_attempts} never reported back (its worker process died: "
                "killed, out of memory or crashed; or the database failed around it)"
            )
            _fail_job_in(s, job, message)
            return None, "failed", None
        job.plan_attempts += 1
        job.plan_worker, job.lease_until = worker, now() + lease_s
        job.planning = {**record, "stalled": stalled + 1, "worker": worker}
        scene = s.get(SceneRow, job.scene_id)
        technique = get_technique(job.job_type)
        bounds = part_bounds(scene, job.params.get("objects")) if technique.scope == "part" else None
        return job, job.plan_attempts, bounds


def _held(s, job_id: str, worker: str, attempt: int) -> JobRow | None:
    job = s.get(JobRow, job_id, with_for_update=True)
    if job is None or job.state != "admitting" or job.plan_worker != worker or job.plan_attempts != attempt:
        return None
    return job


def _fail_cells(s, failed: dict[str, str]) -> None:
    for cell_id, error in failed.items():
        s.execute(
            update(CellRow)
            .where(CellRow.id == cell_id, CellRow.state == "queued")
            .values(state="failed", error=error, finished_at=now())
        )


def _store_texels(s, texels: dict[str, float]) -> None:
    """Each passed cell's planned texels (``cells.texels``: the queue it is sent to, service.pools)."""
    if texels:
        s.execute(update(CellRow), [{"id": cell_id, "texels": float(t)} for cell_id, t in texels.items()])


def _fail_job_in(s, job: JobRow, message: str) -> None:
    """Fail the job and its cells still queued with ``message``, in the session ``s``."""
    job.state, job.error, job.finished_at, job.plan_worker, job.lease_until = "failed", message, now(), None, None
    s.execute(
        update(CellRow)
        .where(CellRow.job_id == job.id, CellRow.state == "queued")
        .values(state="failed", error=message, finished_at=now())
    )


def _commit(
    db: Database,
    job_id: str,
    worker: str,
    attempt: int,
    failed: dict[str, str],
    progress: dict,
    texels: dict,
    lease_s: float,
) -> bool:
    """Store the cells ``failed`` since the last commit, the ``texels`` of those that passed and the
    ``progress`` (merged into the planning record), renewing the lease; False when this delivery no
    longer holds the job."""
    with db.session() as s:
        job = _held(s, job_id, worker, attempt)
        if job is None:
            return False
        _fail_cells(s, failed)
        _store_texels(s, texels)
        job.planning = {**job.planning, **progress, "stalled": 0}
        job.lease_until = now() + lease_s
        return True


def _stopped_in(s, job_id: str) -> str:
    """What a delivery that lost its hold reports: "cancelled" when the job was, else "skipped";
    read in the open session ``s`` (a second session here would wait on the first's SQLite write
    lock until the busy timeout: the API's writes behind it answered 500)."""
    return "cancelled" if s.scalar(select(JobRow.state).where(JobRow.id == job_id)) == "cancelled" else "skipped"


def _stopped(db: Database, job_id: str) -> str:
    """:func:`_stopped_in` in a session of its own (no other open)."""
    with db.session() as s:
        return _stopped_in(s, job_id)


def admit_job(
    db: Database,
    blobs: BlobStore,
    job_id: str,
    worker: str,
    max_attempts: int,
    limits: AdmissionLimits | None = None,
    deadline_s: float | None = None,
    lease_s: float = ADMISSION_LEASE_S,
    claimed: list[int] | None = None,
) -> tuple[str, list[str]]:
    """Check the admitting job's queued cells (see the module docstring): (the job's state after,
    the ids of the cells to send).  "continue" (and no ids): ``deadline_s`` seconds passed, the
    progress is committed and the hold freed, and the caller sends the admission again (so that a
    10,000-cell admission never meets a worker's time limit); "skipped": not this delivery's to run.
    ``lease_s``: the hold's lease (``FARFIELD_ADMISSION_LEASE_S``), renewed at each commit.
    ``claimed``, when given, gets the attempt this delivery holds as soon as it holds it, so that a
    caller whose delivery then fails frees that hold and no later one (:func:`release_admission`)."""
    begun = time.perf_counter()  # the delivery's seconds, claim to commit, count as admission
    limits = AdmissionLimits.from_env() if limits is None else limits
    job, attempt, bounds = _claim(db, job_id, worker, max_attempts, lease_s)
    if job is None:
        return attempt, []
    if claimed is not None:
        claimed.append(attempt)
    record = job.planning
    technique = get_technique(job.job_type)
    options = technique.options_of(job.params)
    with db.session() as s:
        rows = list(
            s.execute(
                select(CellRow.id, CellRow.index, CellRow.viewcell)
                .where(CellRow.job_id == job_id, CellRow.state == "queued", CellRow.index >= record["next"])
                .order_by(CellRow.index)
            )
        )
    progress = {k: record[k] for k in ("done", "texels", "failed", "next")}
    failed: dict[str, str] = {}
    passed: dict[str, float] = {}  # texels of the cells that passed since the last commit
    start = last = time.perf_counter()
    spent = float(record.get("seconds", 0.0))  # the earlier deliveries' (the job's timing: service.jobs.timing)

    def timed() -> dict:
        return {**progress, "seconds": spent + time.perf_counter() - begun}

    for cell_id, n, viewcell in rows:
        cost, error = check_cell(
            technique, options, n, viewcell_from_dict(viewcell), bounds, limits, progress["texels"]
        )
        progress["done"] += 1
        if error is not None:
            failed[cell_id] = error
            progress["failed"] += 1
        else:
            progress["texels"] += cost.texels
            passed[cell_id] = cost.texels
            if progress["texels"] > limits.max_job_texels:
                about = "about" if cost.complete else "more than"
                message = f"{JobTooCostlyError.__name__}: " + job_too_costly(
                    n, record["total"], progress["texels"], about, limits
                )
                with db.session() as s:
                    held = _held(s, job_id, worker, attempt)
                    if held is None:
                        return _stopped_in(s, job_id), []
                    _fail_cells(s, failed)
                    held.planning = {**held.planning, **timed()}
                    _fail_job_in(s, held, message)
                return "failed", []
        progress["next"] = n + 1
        clock = time.perf_counter()
        if clock - last >= COMMIT_EVERY_S:
            if not _commit(db, job_id, worker, attempt, failed, timed(), passed, lease_s):
                return _stopped(db, job_id), []
            failed, passed, last = {}, {}, clock
            if deadline_s is not None and clock - start >= deadline_s and progress["done"] < record["total"]:
                with db.session() as s:  # free the hold: the caller sends the admission again
                    s.execute(
                        update(JobRow)
                        .where(JobRow.id == job_id, JobRow.plan_worker == worker, JobRow.plan_attempts == attempt)
                        .values(plan_worker=None, lease_until=now() + lease_s)
                    )
                return "continue", []
    with db.session() as s:
        held = _held(s, job_id, worker, attempt)
        if held is None:
            return _stopped_in(s, job_id), []
        _fail_cells(s, failed)
        _store_texels(s, passed)
        planning = {**held.planning, **timed(), "phase": "admitted", "stalled": 0}
        planning.pop("worker", None)
        held.planning, held.state, held.plan_worker, held.lease_until = planning, "queued", None, None
        # Sent now: their queue time starts now, not when the job was created (the sweeper's clock).
        s.execute(update(CellRow).where(CellRow.job_id == job_id, CellRow.state == "queued").values(queued_at=now()))
        ids = list(
            s.scalars(
                select(CellRow.id).where(CellRow.job_id == job_id, CellRow.state == "queued").order_by(CellRow.index)
            )
        )
    if not ids:
        finish_job_if_complete(db, blobs, job_id)  # every cell failed its check: the job fails
        return "failed", []
    return "queued", ids


def release_admission(db: Database, job_id: str, worker: str, attempt: int | None = None) -> bool:
    """Free ``worker``'s hold of the job's admission from its ``attempt`` (its delivery failed): the
    API's sweeper sends it again at its next sweep.  False when that attempt does not hold it: a
    later delivery on the same host (the sweeper's, while this one waited to retry) keeps its hold.
    ``attempt`` None frees the host's hold whatever its attempt (a message of an older release)."""
    held = [JobRow.id == job_id, JobRow.state == "admitting", JobRow.plan_worker == worker]
    if attempt is not None:
        held.append(JobRow.plan_attempts == attempt)
    with db.session() as s:
        return bool(s.execute(update(JobRow).where(*held).values(plan_worker=None, lease_until=0.0)).rowcount)


def resend_admission_at_next_sweep(db: Database, job_id: str) -> bool:
    """An admitting job whose admission task could not be sent (the broker away longer than the
    send's retries) and that no worker holds: its lease ended now, so that the API's next sweep
    (:func:`lost_admissions`) sends it again, not ``FARFIELD_REQUEUE_AFTER`` (an hour by default)
    after the job was created.  False when it had moved on."""
    with db.session() as s:
        return bool(
            s.execute(
                update(JobRow)
                .where(JobRow.id == job_id, JobRow.state == "admitting", JobRow.plan_worker.is_(None))
                .values(lease_until=0.0)
            ).rowcount
        )


def lost_admissions(db: Database, requeue_after: float) -> list[str]:
    """Ids of admitting jobs whose admission message or holder is lost (the lease ran out), claimed
    for sending again: their lease pushed ``requeue_after`` on and the hold dropped, each by a
    conditional update, so several API processes sweeping at once send it once."""
    with db.session() as s:
        found = list(
            s.execute(
                select(JobRow.id, JobRow.lease_until).where(JobRow.state == "admitting", JobRow.lease_until < now())
            )
        )
    claimed = []
    for job_id, lease in found:
        with db.session() as s:
            if s.execute(
                update(JobRow)
                .where(JobRow.id == job_id, JobRow.state == "admitting", JobRow.lease_until == lease)
                .values(plan_worker=None, lease_until=now() + requeue_after)
            ).rowcount:
                claimed.append(job_id)
    return claimed
