"""One worker at a time plans or checks a placement job: its hold (the lease) and the heartbeat that renews it.

Planning and checking are held by one worker at a time under a lease (``jobs.plan_worker``,
``jobs.lease_until``) that a heartbeat thread renews every ``HEARTBEAT_S``.  A worker process that
dies loses it: its worker's main process releases it at once (a pool process killed), else it
expires after ``LEASE_S`` (the whole worker gone) and the API's sweeper
(:func:`lost_planning_jobs`) sends the task again; each claim counts an attempt, and a phase whose
``max_attempts`` attempts never reported back fails the job.  So a job is never left ``placing``.
"""

from __future__ import annotations

import contextlib
import logging
import threading
from dataclasses import dataclass

from sqlalchemy import select, update

from farfield.service.blobs import BlobStore
from farfield.service.db import Database, JobRow, now
from farfield.service.placement.base import PLACEMENT_JOB
from farfield.service.placement.states import drop_ended_planning

log = logging.getLogger("farfield.placement")

LEASE_S = 20.0  # a held planning not renewed for this long is lost (its worker died)
HEARTBEAT_S = 3.0  # how often the holder renews it


class PlanningCancelled(Exception):
    """The job was cancelled (or its hold lost) while it was planned or checked."""


@dataclass(frozen=True)
class PlanClaim:
    job: JobRow | None
    attempt: int = 0
    ended: bool = False  # this claim ended the job (attempts used up)


def claim_planning(
    db: Database, blobs: BlobStore, job_id: str, phase: str, worker: str, max_attempts: int
) -> PlanClaim:
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
    return (
        JobRow.id == job_id,
        JobRow.state == "placing",
        JobRow.plan_worker == worker,
        JobRow.plan_attempts == attempt,
    )


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


def fail_planning(
    db: Database,
    job_id: str,
    message: str,
    worker: str | None = None,
    attempt: int | None = None,
    blobs: BlobStore | None = None,
) -> bool:
    """Fail the job (if still held by ``worker``'s ``attempt``, when given) with ``message``; given
    ``blobs``, then delete its planner states (:func:`drop_ended_planning`)."""
    where = [JobRow.id == job_id, JobRow.state.in_(("queued", "placing"))]
    if worker is not None:
        where.append(JobRow.plan_worker == worker)
    if attempt is not None:
        where.append(JobRow.plan_attempts == attempt)
    with db.session() as s:
        failed = bool(
            s.execute(
                update(JobRow)
                .where(*where)
                .values(state="failed", error=message, finished_at=now(), plan_worker=None, lease_until=None)
            ).rowcount
        )
    if failed and blobs is not None:
        drop_ended_planning(db, blobs, job_id)
    return failed


def release_planning(
    db: Database, job_id: str, why: str, worker: str | None, max_attempts: int, blobs: BlobStore | None = None
) -> str:
    """A planning whose worker process died: free it for the next delivery (or fail the job when
    that was its last attempt, and then, given ``blobs``, delete its planner states).  Returns the
    job's state, or "unchanged"."""
    with db.session() as s:
        job = s.get(JobRow, job_id, with_for_update=True)
        if (
            job is None
            or job.state != "placing"
            or job.plan_worker is None
            or (worker is not None and job.plan_worker != worker)
        ):
            return "unchanged"
        phase = (job.planning or {}).get("phase", "plan")
        if job.plan_attempts >= max_attempts:
            job.state, job.finished_at = "failed", now()
            job.error = f"{phase} attempt {job.plan_attempts} of {max_attempts} never reported back ({why})"
        else:
            job.planning = {
                **job.planning,
                "error": f"{phase} attempt {job.plan_attempts} of {max_attempts} was lost ({why}); sent again",
            }
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


def resend_planning_at_next_sweep(db: Database, job_id: str) -> bool:
    """A placement job whose planning task could not be sent (the broker away longer than the send's
    retries) and that no worker holds: its lease ended now, so that the API's next sweep
    (:func:`lost_planning_jobs`) sends it again, not ``FARFIELD_REQUEUE_AFTER`` (an hour by default)
    after the job was created.  False when it had moved on."""
    with db.session() as s:
        return bool(
            s.execute(
                update(JobRow)
                .where(
                    JobRow.id == job_id,
                    JobRow.job_type == PLACEMENT_JOB,
                    JobRow.state.in_(("queued", "placing")),
                    JobRow.plan_worker.is_(None),
                )
                .values(lease_until=0.0)
            ).rowcount
        )


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
