"""The cell state machine: a cell's attempts, a job's end, and the API's cancel and retry.

States (kept in SQL, never in Celery results):

    cell: queued -> running -> done | failed | cancelled;  running -> queued (a failed attempt that
          will be retried, or one whose lease expired: its worker died; the attempt is counted)
    job:  admitting -> queued -> running -> done | failed | cancelled  (admitting: a worker checks
          every cell's full plan first, service.jobs.admitting; a cell over the limits fails there)
          a placement job (service.placement): queued -> placing -> running -> placing (check)
          -> running (repairs) ... -> done | failed | cancelled

A job ends when its last cell does: ``done`` when every cell is done, ``failed`` when some cell
failed, ``cancelled`` when cancelled.  The worker that ends the last cell builds the job's
impostor database index (:func:`farfield.service.jobs.index.write_index`); a placement job's round ends
instead (:func:`farfield.service.placement.rounds.end_round`: its check writes its database).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass

from sqlalchemy import Select, select, update

from farfield.core import __version__
from farfield.core.errors import ConflictError
from farfield.service.blobs import BlobStore
from farfield.service.db import CELL_FINAL, OPEN_JOB_STATES, CellRow, Database, JobRow, SceneRow, now
from farfield.service.jobs.index import write_index
from farfield.service.jobs.leases import new_token
from farfield.service.jobs.records import get_job_row
from farfield.service.placement import PLACEMENT_JOB
from farfield.service.placement.rounds import end_round
from farfield.service.placement.states import drop_ended_planning
from farfield.service.settings import LEASE_S, MAX_CELLS


def result_key(scene_hash: str, job_type: str, params: dict, viewcell: dict, tenant_id: str) -> str:
    """Blob prefix of a cell's bundle: a digest of everything that determines its bytes, and of the
    tenant that asked for it.

    Equal inputs of one tenant (even in another job) give the same key, so a redelivered or
    repeated cell overwrites identical bytes and never makes a second impostor.  Results are shared
    within a tenant only: were they shared across tenants, a tenant submitting a scene it holds
    with another's parameters would see the cell found (``stats.baked`` false, a cell of
    milliseconds) and learn that someone else had baked that content (issue 59, item 9).
    """
    blob = json.dumps(
        {"scene": scene_hash, "type": job_type, "params": params, "viewcell": viewcell, "code": __version__,
         "tenant": tenant_id},
        sort_keys=True, separators=(",", ":"),
    )  # fmt: skip
    return "impostors/" + hashlib.sha256(blob.encode()).hexdigest()


@dataclass(frozen=True)
class Claim:
    """What :func:`claim_cell` decided: run ``cell`` (attempt ``cell.attempts``) of ``job`` on
    ``scene`` (read in the claim's transaction, so the attempt needs no other before it bakes), or
    not; ``ended`` when it ended the cell itself (cancelled job, attempts used up), so the job may be
    complete."""

    cell: CellRow | None
    job_id: str | None = None
    ended: bool = False
    job: JobRow | None = None
    scene: SceneRow | None = None


def claim_cell(
    db: Database, cell_id: str, max_attempts: int, worker: str | None = None, lease_s: float = LEASE_S
) -> Claim:
    """Mark the cell running and count the attempt, unless it must not run; the attempt holds a new
    lease (``cell.lease_token``, for ``lease_s``: :mod:`farfield.service.jobs.leases`).

    A cell found ``running`` under a live lease of another worker is left to it (a duplicate
    delivery).  One found ``running`` otherwise is one whose earlier attempt never reported back: its
    worker process died (killed, out of memory, a driver crash) and the broker delivered it again.
    Such a cell runs again until ``max_attempts``, then is failed here, so a cell that kills its
    worker cannot loop forever.  Locks the job row before the cell row, as :func:`cancel_job` does.
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
        if (
            cell.state == "running"
            and cell.worker != worker
            and cell.lease_until is not None
            and cell.lease_until >= now()
        ):
            return Claim(None, job_id)  # held by a live worker: a duplicate delivery
        if cell.state == "running" and cell.attempts >= max_attempts:
            cell.state, cell.finished_at = "failed", now()
            cell.error = _never_reported(
                cell.attempts,
                max_attempts,
                "its worker process died: killed, out of memory or crashed; or the database or blob store failed around it",
            )
            return Claim(None, job_id, ended=True)
        cell.state, cell.attempts, cell.started_at, cell.progress, cell.error = (
            "running",
            cell.attempts + 1,
            now(),
            0.0,
            None,
        )
        cell.worker, cell.lease_token, cell.lease_until = worker, new_token(), now() + lease_s
        if job.state == "queued":
            job.state, job.started_at = "running", now()
        return Claim(cell, job_id, job=job, scene=s.get(SceneRow, job.scene_id))


def _never_reported(attempt: int, max_attempts: int, why: str) -> str:
    return f"attempt {attempt} of {max_attempts} never reported back ({why})"


# queued_at of a cell whose message is stuck with a dead worker, or was never sent: the API's sweeper
# (lost_queued_cells) sends it again at its next sweep instead of after FARFIELD_REQUEUE_AFTER.
RESEND_NOW = 0.0


def resend_at_next_sweep(db: Database, cell_ids: list[str]) -> int:
    """Cells whose bake message could not be sent (the broker away longer than the send's retries,
    ``farfield.workers.app.SEND_RETRY_POLICY``): each still queued gets ``queued_at`` RESEND_NOW, so
    the API's next sweep (:func:`lost_queued_cells`) sends it again, not FARFIELD_REQUEUE_AFTER (an
    hour by default) after it was queued.  Should the message have gone after all, the cell gets two:
    harmless, since :func:`claim_cell` takes a queued cell once and every later write of an attempt
    names its lease token.  Returns how many cells were marked."""
    with db.session() as s:
        return s.execute(
            update(CellRow).where(CellRow.id.in_(cell_ids), CellRow.state == "queued").values(queued_at=RESEND_NOW)
        ).rowcount


def release_lost_cells(
    db: Database,
    blobs: BlobStore,
    cell_ids: list[str],
    max_attempts: int,
    why: str,
    *,
    worker: str | None = None,
    resend: bool = False,
    expired_only: bool = False,
) -> dict[str, str]:
    """The cells of a worker process that died, moved on at once instead of showing ``running``
    until their message comes back (which, for a whole worker, is the visibility timeout later).

    Each of ``cell_ids`` still running (on ``worker``, when given) is queued again with ``why`` as
    its error, or failed when its attempt was the last (:func:`claim_cell` would fail it on the
    next delivery), or cancelled when its job was; a job left without open cells ends.  ``resend``:
    its message is not coming back soon (the whole worker died with it unacknowledged), so the API's
    sweeper sends it again.  ``expired_only``: only cells whose lease has run out (a heartbeat may
    have renewed one since it was found).  Returns the new state by cell id (cells that had moved
    on are left out)."""
    changed: dict[str, str] = {}
    for cell_id in cell_ids:
        with db.session() as s:
            job_id = s.scalar(select(CellRow.job_id).where(CellRow.id == cell_id))
            if job_id is None:
                continue
            job = s.get(JobRow, job_id, with_for_update=True)  # the lock order of claim_cell
            cell = s.get(CellRow, cell_id, with_for_update=True, populate_existing=True)
            if cell.state != "running" or (worker is not None and cell.worker != worker):
                continue
            if expired_only and (cell.lease_until is None or cell.lease_until >= now()):
                continue
            cell.lease_token, cell.lease_until = None, None  # whatever the attempt still sends is discarded
            if job.state == "cancelled":
                cell.state, cell.finished_at = "cancelled", now()
            elif cell.attempts >= max_attempts:
                cell.state, cell.finished_at = "failed", now()
                cell.error = _never_reported(cell.attempts, max_attempts, why)
            else:
                cell.state, cell.progress = "queued", 0.0
                cell.queued_at = RESEND_NOW if resend else now()
                cell.error = f"attempt {cell.attempts} of {max_attempts} was lost ({why}); queued again"
            changed[cell_id] = cell.state
        if changed.get(cell_id) in ("failed", "cancelled"):
            finish_job_if_complete(db, blobs, job_id)
    return changed


def expired_cells(db: Database, limit: int = 1000) -> list[str]:
    """Ids of running cells whose lease ran out."""
    with db.reading() as s:
        return list(
            s.scalars(
                select(CellRow.id)
                .where(CellRow.state == "running", CellRow.lease_until < now())
                .order_by(CellRow.lease_until)
                .limit(limit)
            )
        )


def release_expired_leases(db: Database, blobs: BlobStore, max_attempts: int, lease_s: float) -> dict[str, str]:
    """Queue again (or fail at the last attempt, or cancel in a cancelled job) every running cell whose
    lease ran out; returns the new state by cell id.  Queued ones are marked to be sent at the next
    look for lost messages (:func:`lost_queued_cells`)."""
    found = expired_cells(db)
    if not found:
        return {}
    return release_lost_cells(
        db, blobs, found, max_attempts, f"its lease expired: its worker stopped renewing it for {lease_s:g} s",
        resend=True, expired_only=True,
    )  # fmt: skip


def running_cells_of(db: Database, worker: str) -> list[str]:
    """Ids of the cells that ``worker`` (a Celery node name, ``name@host``) is running."""
    with db.reading() as s:
        return list(s.scalars(select(CellRow.id).where(CellRow.state == "running", CellRow.worker == worker)))


def attempt_stopped(db: Database, cell: CellRow) -> str | None:
    """Why the running attempt ``cell`` (as claimed) must stop: "cancelled" (its job was), "lost" (its
    lease expired and the cell was queued again or went to another worker), or None: carry on."""
    with db.reading() as s:
        job_state, token = s.execute(
            select(JobRow.state, CellRow.lease_token).join(CellRow, CellRow.job_id == JobRow.id).where(CellRow.id == cell.id)
        ).one()  # fmt: skip
    if job_state == "cancelled":
        return "cancelled"
    return "lost" if cell.lease_token is not None and token != cell.lease_token else None


def set_progress(db: Database, cell_id: str, fraction: float, token: str | None = None) -> None:
    """The running cell's progress; given its attempt's lease ``token``, only while that attempt holds it."""
    where = [CellRow.id == cell_id, CellRow.state == "running"]
    if token is not None:
        where.append(CellRow.lease_token == token)
    with db.session() as s:
        s.execute(update(CellRow).where(*where).values(progress=fraction))


def end_cell(
    db: Database,
    cell_id: str,
    attempt: int,
    state: str,
    *,
    result: str | None = None,
    stats: dict | None = None,
    error: str | None = None,
    seconds: float | None = None,
    token: str | None = None,
) -> bool:
    """Move the cell from running attempt ``attempt`` (holding the lease ``token``, when given) to
    ``state`` (done, failed, cancelled, or queued for another attempt), in one conditional ``UPDATE``.
    False, and nothing written, when the cell has moved on since (a stale duplicate delivery of an
    older attempt, a cancel, or a lease that expired and went to another attempt: its late result
    is discarded, never applied twice)."""
    values: dict = {"state": state, "error": error, "lease_token": None, "lease_until": None}
    if state == "queued":
        values.update(progress=0.0, queued_at=now())
    else:
        values.update(finished_at=now(), seconds=seconds)
        if state == "done":
            values["progress"] = 1.0
    if result is not None:
        values.update(result_key=result, stats=stats)
    where = [CellRow.id == cell_id, CellRow.state == "running", CellRow.attempts == attempt]
    if token is not None:
        where.append(CellRow.lease_token == token)
    with db.session() as s:
        return s.execute(update(CellRow).where(*where).values(**values)).rowcount == 1


def has_open_cells(job_id: str) -> Select:
    """The query (one boolean) of whether the job has a cell queued or running.  Whether one is, not
    how many: the index on ``(job_id, state)`` (migration 0009) answers it from its first entry, and
    from the index alone, where a count reads every open cell's entry (a 10,000-cell job's, after
    each of its cells) and, with ``job_id`` alone indexed, every cell's row."""
    open_cell = select(CellRow.job_id).where(CellRow.job_id == job_id, CellRow.state.in_(("queued", "running")))
    return select(open_cell.exists())


def finish_job_if_complete(db: Database, blobs: BlobStore, job_id: str) -> bool:
    """End the job when no cell is left to run; True if this call ended it.

    The index is written before the state flips, so a ``done`` job always has one; workers that
    finish at once may both write it (the same document), and the conditional update lets one win.
    """
    with db.reading() as s:  # no write lock: a worker ends a cell while others commit theirs
        if s.scalar(has_open_cells(job_id)):
            return False
        job = s.get(JobRow, job_id)
        states = set(s.scalars(select(CellRow.state).where(CellRow.job_id == job_id).distinct()))
    if job.state == "cancelled":
        if job.finished_at is None:
            with db.session() as s:
                s.execute(
                    update(JobRow)
                    .where(JobRow.id == job_id, JobRow.state == "cancelled", JobRow.finished_at.is_(None))
                    .values(finished_at=now())
                )
        return False
    if job.state not in ("queued", "running"):
        return False
    final = "failed" if "failed" in states else "done" if states <= {"done"} else "cancelled"
    if job.job_type == PLACEMENT_JOB:
        return end_round(db, job_id, final)
    key = write_index(db, blobs, job_id, final)
    with db.session() as s:
        won = s.execute(
            update(JobRow)
            .where(JobRow.id == job_id, JobRow.state.in_(("queued", "running")))
            .values(state=final, finished_at=now(), index_key=key)
        ).rowcount
    return bool(won)


# --- the API's side ----------------------------------------------------------------------------


def cancel_job(db: Database, blobs: BlobStore, tenant_id: str, job_id: str) -> JobRow:
    """Cancel: queued cells never run; running cells stop at their next layer (a running cell whose
    worker died is cancelled when its lease runs out)."""
    get_job_row(db, tenant_id, job_id)
    with db.session() as s:
        # Conditional, and the job row first (the lock order of claim_cell): a job that ended
        # meanwhile stays as it ended.
        changed = s.execute(
            update(JobRow).where(JobRow.id == job_id, JobRow.state.in_(OPEN_JOB_STATES)).values(state="cancelled")
        ).rowcount
        if changed:
            s.execute(
                update(CellRow)
                .where(CellRow.job_id == job_id, CellRow.state == "queued")
                .values(state="cancelled", finished_at=now())
            )
            # A running cell whose lease ran out has no worker left to see the cancel (its node died):
            # cancelled now (one whose lease runs out later is cancelled by the sweeper).
            s.execute(
                update(CellRow)
                .where(CellRow.job_id == job_id, CellRow.state == "running", CellRow.lease_until < now())
                .values(state="cancelled", finished_at=now(), lease_token=None, lease_until=None)
            )
    if not changed:
        raise ConflictError(f"job {job_id!r} is already {get_job_row(db, tenant_id, job_id).state}")
    finish_job_if_complete(db, blobs, job_id)
    job = get_job_row(db, tenant_id, job_id)
    if job.job_type == PLACEMENT_JOB and job.plan_worker is None:
        # No worker holds its planning (one that does deletes them when it sees the cancel), and a
        # check message still queued would only find the job cancelled: its planner states go now.
        drop_ended_planning(db, blobs, job_id)
    return job


def retry_job(db: Database, tenant_id: str, job_id: str, limits=None) -> list[str]:
    """Queue the failed cells of a failed job again (attempts reset); returns their ids (to send, unless
    the job is ``admitting`` again: when a cell failed its full check, the retried cells are checked
    again first, and the caller sends the job's admission instead).  A placement
    job that failed before its cells were baked (planning or checking) is not retried: submit it again.
    The cells count against the tenant's quota (``limits``, an
    :class:`~farfield.service.settings.AdmissionLimits`; None: from the environment): past it,
    :class:`~farfield.core.errors.QuotaError` (429) and nothing changes."""
    from farfield.service.quotas import reserve_tenant_work
    from farfield.service.settings import AdmissionLimits

    limits = AdmissionLimits.from_env() if limits is None else limits
    job = get_job_row(db, tenant_id, job_id)
    if job.job_type == PLACEMENT_JOB and job.state == "failed" and (job.planning or {}).get("phase") != "bake":
        raise ConflictError(f"job {job_id!r} failed while placing ({job.error}); submit it again")
    with db.session() as s:
        changed = s.execute(
            update(JobRow)
            .where(JobRow.id == job_id, JobRow.state == "failed")
            .values(state="running", finished_at=None, index_key=None)
        ).rowcount
        if changed:
            failed = list(
                s.execute(
                    select(CellRow.id, CellRow.attempts).where(CellRow.job_id == job_id, CellRow.state == "failed")
                )
            )
            ids = [cell_id for cell_id, _ in failed]
            reserve_tenant_work(s, tenant_id, len(ids), limits)  # raises: the session rolls the job back
            if job.job_type != PLACEMENT_JOB and any(attempts == 0 for _, attempts in failed):
                # A cell failed before it ran (its full check refused it): they are all checked again
                # (service.jobs.admitting), never baked past the limits.
                from farfield.service.jobs.admission import admission_record

                s.execute(
                    update(JobRow)
                    .where(JobRow.id == job_id)
                    .values(
                        state="admitting",
                        error=None,
                        planning=admission_record(len(ids), 0),
                        plan_worker=None,
                        lease_until=0.0,
                    )
                )
            s.execute(
                update(CellRow)
                .where(CellRow.id.in_(ids))
                .values(state="queued", attempts=0, error=None, progress=0.0, finished_at=None, queued_at=now())
            )
    if not changed:
        raise ConflictError(
            f"only a failed job can be retried; job {job_id!r} is {get_job_row(db, tenant_id, job_id).state}"
        )
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
    with db.reading() as s:
        candidates = list(
            s.scalars(
                select(CellRow.id)
                .join(JobRow, CellRow.job_id == JobRow.id)  # an admitting job's cells are sent when admitted
                .where(CellRow.state == "queued", CellRow.queued_at < cutoff, JobRow.state != "admitting")
                .limit(MAX_CELLS)
            )
        )
    claimed = []
    for cell_id in candidates:
        with db.session() as s:
            if s.execute(
                update(CellRow)
                .where(CellRow.id == cell_id, CellRow.state == "queued", CellRow.queued_at < cutoff)
                .values(queued_at=now())
            ).rowcount:
                claimed.append(cell_id)
    return claimed
