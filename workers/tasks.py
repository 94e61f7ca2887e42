"""Celery tasks: each is a few lines around a function of ``service``.

:func:`bake_cell` runs :func:`farfield.service.jobs.runner.run_cell`, which sorts a failed attempt into one of
three classes and counts it on the cell:

- **transient** (the database, broker, blob store or renderer failed; any OSError): retried with
  backoff (2, 4, 8, ... s, capped at 60) until ``FARFIELD_MAX_ATTEMPTS`` attempts, then failed;
- **bad input** (a :class:`~farfield.core.errors.FarfieldError` of kind BAD_INPUT or MISSING): failed at
  once with its message;
- **internal** (a bug: any other exception; or an :class:`~farfield.core.errors.InternalError`): retried
  like a transient failure with its traceback logged, then failed as ``internal error: ...``.

A failure outside the attempt (``claim_cell`` could not reach the database, or a bug there; the
outcome could not be recorded) leaves nothing on the cell, so this task counts it in the message's
Celery retries (``self.request.retries``) and retries it with the same backoff: a transient one while
retries stay under :func:`max_retries` (10 per attempt: with the 60 s cap, a database or broker
outage of some 25 minutes at the default 3 attempts), an internal one for ``FARFIELD_MAX_ATTEMPTS``
deliveries, a bad-input one never.  Then the task gives up and fails the cell with the error if the
database takes the write (else it logs that it could not).  No message is retried forever: the task's
``max_retries`` is :func:`max_retries` of the attempt limit.

Limits per cell (:mod:`farfield.service.cell_limits`): the decorator's soft and hard time limits are
``FARFIELD_CELL_TIME_LIMIT`` and that plus ``CELL_TIME_GRACE`` seconds; the soft one fails the cell
(no retry), and the hard one, where the pool process did not stop, is recorded by
:meth:`CellTask.on_failure` in the worker's main process.  Each pool process runs a
:class:`~farfield.service.cell_limits.MemoryGuard` of ``FARFIELD_CELL_MEMORY_MB``.

A placement job's :func:`plan_placement` and :func:`check_placement` run
:func:`farfield.service.placement.rounds.run_planning` (plan, or check and repair) under the same time limits and
memory guard (past it the job fails, naming the limit) and send the cells it made; a bake whose cell ended the last open cell of a placement job's round sends
the job's check.  A pool process that dies while it plans frees the job's hold from the worker's
main process at once (:class:`PlanningRequest`), so the redelivery plans again (each time an
attempt, ``FARFIELD_MAX_ATTEMPTS`` at most); a whole worker that dies leaves its hold to expire and
the API's sweeper sends the task again.

When a worker starts, :func:`warm_worker` compiles every registered technique's numba kernels
(:func:`farfield.core.techniques.warm_techniques`) in its main process before the pool processes
fork, so no cell pays the compilation.
"""

from __future__ import annotations

import logging
import os

from billiard.exceptions import WorkerLostError
from billiard.process import current_process
from celery import Task
from celery.exceptions import SoftTimeLimitExceeded, TimeLimitExceeded
from celery.signals import worker_init, worker_ready, worker_shutdown
from celery.worker import state as worker_state
from celery.worker.request import Request
from sqlalchemy import select, update

from farfield.core.errors import CellLimitError
from farfield.core.render.context import gl_context
from farfield.core.techniques import warm_techniques
from farfield.service.blobs import BlobStore, blob_store
from farfield.service.cell_limits import (
    PLANNING,
    MemoryGuard,
    hard_time_limit_message,
    memory_limit_message,
    time_limit_message,
)
from farfield.service.db import CellRow, Database, JobRow, now
from farfield.service.failures import BAD_INPUT, TRANSIENT, failure_class, failure_message
from farfield.service.jobs.admitting import admit_job, release_admission
from farfield.service.jobs.cells import finish_job_if_complete, release_lost_cells, resend_at_next_sweep
from farfield.service.jobs.leases import Heartbeat
from farfield.service.jobs.runner import RetryCell, backoff, run_cell
from farfield.service.placement import PLACEMENT_JOB
from farfield.service.placement.candidate_fanout import register_sender, run_part
from farfield.service.placement.lease import fail_planning, release_planning
from farfield.service.placement.rounds import after_cell, run_planning
from farfield.service.pools import QUEUES, QueueSwitch, cell_queues, pool_egl_device
from farfield.service.settings import CELL_TIME_GRACE, Settings
from farfield.workers.app import (
    ADMIT_JOB,
    BAKE_CELL,
    BROKER_ERRORS,
    CHECK_PLACEMENT,
    PLAN_PLACEMENT,
    RENDER_QUEUE,
    SEND_RETRY_POLICY,
    celery_app,
    send_admission,
    send_cells,
    send_planning,
)

_STATE: dict = {}
_MAIN: dict = {}  # the worker's main process: its heartbeat (apart from _STATE, which a fork clears)
TRANSIENT_RETRIES_PER_ATTEMPT = 10
_DECLARED = Settings.from_env()  # the settings the task is declared with (retries, time limits)

log = logging.getLogger("farfield.worker")


@worker_init.connect
def warm_worker(**_) -> None:
    """Compile every registered technique's numba kernels (:meth:`farfield.core.techniques.base.Technique.warm`) in the worker's main process, before its pool processes fork
    (they inherit them): the first cell a worker bakes does not pay the compilation.  A failure
    here is logged and left to the first bake to meet again."""
    try:
        log.info("numba kernels ready in %.1f s", warm_techniques())
    except Exception:  # noqa: BLE001 - a bake reports the same failure with its cell
        log.exception("could not warm the numba kernels")


def active_cells() -> list[str]:
    """Ids of the cells this worker's pool processes are running now (the main process's view)."""
    for _ in range(3):  # the consumer's thread may change the set while it is copied
        try:
            requests = list(worker_state.active_requests)
            break
        except RuntimeError:
            continue
    else:
        return []
    return [str(r.args[0]) for r in requests if r.name == BAKE_CELL and r.args]


@worker_ready.connect
def start_heartbeat(sender=None, **_) -> None:
    """The worker's heartbeat thread (:class:`farfield.service.jobs.leases.Heartbeat`), in its main
    process: renews the leases of the cells its pool runs and its row in ``workers``."""
    settings = Settings.from_env()
    hostname = getattr(sender, "hostname", None) or celery_app.conf.get("worker_hostname") or "worker"
    concurrency = getattr(getattr(sender, "controller", None), "concurrency", None) or 1
    # The queues of its kind (service.pools), switched in the consumer's thread (sender: the Consumer).
    switch = None
    if hasattr(sender, "call_soon") and hasattr(sender, "add_task_queue"):
        consumed = tuple(q for q in QUEUES if q in celery_app.amqp.queues.consume_from)
        switch = QueueSwitch(sender.call_soon, sender.add_task_queue, sender.cancel_task_queue, consumed)
    beat = Heartbeat(
        Database(settings.database_url), hostname, int(concurrency), settings.lease_s, settings.heartbeat_s,
        active_cells, settings.worker_kind, switch,
    )  # fmt: skip
    _MAIN["heartbeat"] = beat.start()


@worker_shutdown.connect
def stop_heartbeat(**_) -> None:
    beat = _MAIN.pop("heartbeat", None)
    if beat is not None:
        beat.stop()


def max_retries(max_attempts: int) -> int:
    """The most Celery retries of one cell's message: ``TRANSIENT_RETRIES_PER_ATTEMPT`` per attempt.

    >>> max_retries(3)
    30
    """
    return TRANSIENT_RETRIES_PER_ATTEMPT * max(max_attempts, 1)


def _records() -> tuple[Settings, Database, BlobStore]:
    """Settings, database and blob store of this process, made after any fork (never inherited);
    no GL context, so the worker's main process may use it too."""
    if _STATE.get("pid") != os.getpid():
        settings = Settings.from_env()
        if "db" in _STATE:  # inherited through a fork: drop its pool without closing the parent's connections
            _STATE["db"].engine.dispose(close=False)
        _STATE.clear()
        _STATE.update(
            pid=os.getpid(),
            settings=settings,
            db=Database(settings.database_url),
            blobs=blob_store(settings, outage_s=settings.s3_outage_s),
        )
    return _STATE["settings"], _STATE["db"], _STATE["blobs"]


def _memory_guard(settings: Settings) -> MemoryGuard:
    """This pool process's memory guard (made once; its thread starts when first armed)."""
    if "memory" not in _STATE:
        _STATE["memory"] = MemoryGuard(settings.cell_memory_mb)
    return _STATE["memory"]


def _services() -> tuple[Settings, Database, BlobStore]:
    """:func:`_records`, and in a pool process that bakes: its GL device and its memory guard."""
    settings, db, blobs = _records()
    _memory_guard(settings)
    if "gl" not in _STATE:
        _STATE["gl"] = True
        # One cell per EGL device: this pool process's own device (service.pools.pool_egl_device).
        device = pool_egl_device(os.environ, getattr(current_process(), "index", 0) or 0)
        if device is not None:
            gl_context(device)
    return settings, db, blobs


def _give_up(db: Database, blobs: BlobStore, cell_id: str, message: str) -> str:
    """Fail the cell (if still queued or running) with ``message`` and end its job if that was its
    last open cell.  Returns "failed", "skipped" (the cell had ended), or "unrecorded" when the
    database does not take the write either: the cell then stays as it is (a queued one is sent again
    by the API's sweeper after FARFIELD_REQUEUE_AFTER)."""
    try:
        with db.session() as s:
            job_id = s.scalar(select(CellRow.job_id).where(CellRow.id == cell_id))
            changed = s.execute(
                update(CellRow)
                .where(CellRow.id == cell_id, CellRow.state.in_(("queued", "running")))
                .values(state="failed", error=message, finished_at=now(), lease_token=None, lease_until=None)
            ).rowcount
    except Exception:  # noqa: BLE001 - nothing more this message can do
        log.exception("cell %s: could not record its failure either: %s", cell_id, message)
        return "unrecorded"
    if not changed:
        return "skipped"
    try:
        finish_job_if_complete(db, blobs, job_id)
    except Exception:  # noqa: BLE001 - the cell's failure is recorded; its job is what is broken
        log.exception("cell %s failed, but its job %s could not be ended", cell_id, job_id)
    return "failed"


class CellRequest(Request):
    """A bake request as the worker's main process sees it: when the pool process running it dies
    (killed, out of memory, a driver crash), the cell is queued again (or failed, if that was its
    last attempt) at once, before Celery puts the message back on the queue; without this it would
    show ``running`` until its redelivery came up, behind every cell queued meanwhile.

    At the soft time limit the main process fails the cell itself (:meth:`on_timeout`), before the
    pool process is signalled: the limit then ends the cell once wherever the signal lands in the
    pool process.  (Before, the pool process alone recorded it, and on a loaded machine the limit
    could strike where that failed: while the cell was claimed, its transaction left open and the
    failure not recordable, or while the process set up its GL context, a crash there losing the
    worker process, so that the cell was released and ran a second attempt; issue 58.)"""

    def on_timeout(self, soft, timeout):
        if soft and self.args:
            fail_at_time_limit(str(self.args[0]))
        return super().on_timeout(soft, timeout)

    def on_failure(self, exc_info, send_failed_event=True, return_ok=False):
        lost = getattr(exc_info.exception, "exc", exc_info.exception)  # ExceptionWithTraceback wraps it
        if isinstance(lost, WorkerLostError) and self.args:
            release_in_main_process(str(self.args[0]), f"its worker process died: {lost}", self.hostname)
        return super().on_failure(exc_info, send_failed_event=send_failed_event, return_ok=return_ok)


def _give_up_in_main_process(cell_id: str, message: str) -> str:
    """:func:`_give_up` on ``cell_id`` with a :class:`CellLimitError` saying ``message``, from the
    worker's main process, on connections of its own that are closed again (pool processes forked
    later must not inherit them)."""
    settings = Settings.from_env()
    db = Database(settings.database_url)
    try:
        return _give_up(db, blob_store(settings), cell_id, f"{CellLimitError.__name__}: {message}")
    finally:
        db.dispose()


def fail_at_time_limit(cell_id: str) -> str:
    """Fail the cell (if still queued or running) naming ``FARFIELD_CELL_TIME_LIMIT``, from the worker's
    main process, on connections of its own that are closed again; "failed", "skipped" (it had
    ended) or "unrecorded"."""
    settings = Settings.from_env()
    outcome = _give_up_in_main_process(cell_id, time_limit_message(settings.cell_time_limit))
    log.warning("cell %s: past FARFIELD_CELL_TIME_LIMIT (%d s): %s", cell_id, settings.cell_time_limit, outcome)
    return outcome


def release_in_main_process(cell_id: str, why: str, worker: str) -> None:
    """:func:`release_lost_cells` from the worker's main process, on connections of its own that
    are closed again (pool processes forked later must not inherit them)."""
    settings = Settings.from_env()
    db = Database(settings.database_url)
    try:
        changed = release_lost_cells(db, blob_store(settings), [cell_id], settings.max_attempts, why, worker=worker)
        log.warning("cell %s: %s; now %s", cell_id, why, changed.get(cell_id, "unchanged (it had moved on)"))
    except Exception:  # noqa: BLE001 - the redelivery still finds the cell running and counts it
        log.exception("cell %s: %s, and could not be released", cell_id, why)
    finally:
        db.dispose()


class CellTask(Task):
    """The bake task's class: a hard time limit fails the cell it killed."""

    def on_failure(self, exc, task_id, args, kwargs, einfo) -> None:
        # Celery calls this in the worker's main process when a pool process is killed at the hard
        # time limit (its cell could record nothing); other failures end in the task body.
        if isinstance(exc, TimeLimitExceeded) and args:
            outcome = _give_up_in_main_process(args[0], hard_time_limit_message(_DECLARED.cell_hard_time_limit))
            log.error(
                "cell %s: killed at the hard time limit of %d s (%s)", args[0], _DECLARED.cell_hard_time_limit, outcome
            )


@celery_app.task(
    bind=True, base=CellTask, Request=CellRequest, name=BAKE_CELL, max_retries=max_retries(_DECLARED.max_attempts),
    soft_time_limit=_DECLARED.cell_time_limit, time_limit=_DECLARED.cell_hard_time_limit,
)  # fmt: skip
def bake_cell(self, cell_id: str) -> str:
    """Bake one cell of a job (service.jobs.runner.run_cell), retrying with backoff (see the module docstring)."""
    settings, db, blobs = _services()
    limit, retries = max_retries(settings.max_attempts), self.request.retries
    try:
        state = run_cell(
            db,
            blobs,
            cell_id,
            settings.max_attempts,
            worker=self.request.hostname,
            time_limit=settings.cell_time_limit,
            memory=_STATE["memory"],
            lease_s=settings.lease_s,
        )
        # Every outcome: a done cell (or a redelivery of one, "skipped") may end its round; a
        # cancelled or failed one may have ended its placement job.
        _send_check_if_due(db, blobs, cell_id)
        return state
    except SoftTimeLimitExceeded:  # outside the attempt (claiming or recording it): the cell is as slow next time
        return _give_up(
            db, blobs, cell_id, f"{CellLimitError.__name__}: {time_limit_message(settings.cell_time_limit)}"
        )
    except RetryCell as retry:  # the attempt is counted on the cell, which is queued again
        if retries < limit:
            raise self.retry(countdown=retry.countdown, exc=None, max_retries=limit) from None
        return _give_up(db, blobs, cell_id, f"{retry} (gave up: {retries + 1} deliveries, the limit)")
    except Exception as error:  # noqa: BLE001 - outside the attempt: nothing on the cell counts it
        klass = failure_class(error)
        message = failure_message(error, klass)
        allowed = limit if klass == TRANSIENT else 0 if klass == BAD_INPUT else max(settings.max_attempts - 1, 0)
        delivery = retries + 1
        if retries < allowed:
            countdown = backoff(delivery)
            log.warning(
                "cell %s delivery %d: %s failure outside the attempt: %s (retried in %g s)",
                cell_id,
                delivery,
                klass,
                message,
                countdown,
                exc_info=klass != TRANSIENT,
            )
            raise self.retry(countdown=countdown, exc=error, max_retries=limit) from error
        log.error(
            "cell %s delivery %d: %s failure outside the attempt: %s (giving up)",
            cell_id,
            delivery,
            klass,
            message,
            exc_info=error,
        )
        return _give_up(
            db, blobs, cell_id, f"{message} (gave up after {delivery} deliveries that failed outside the attempt)"
        )


def _send_check_if_due(db: Database, blobs: BlobStore, cell_id: str) -> None:
    """The cell ended its placement job's round: send the job's check (a duplicate is harmless; a
    lost one is sent again by the API's sweeper); a placement job that has ended (cancelled while
    its cells ran, failed) drops its planner states (:func:`farfield.service.placement.rounds.after_cell`)."""
    with db.reading() as s:
        found = s.execute(
            select(CellRow.job_id, JobRow.job_type)
            .join(JobRow, CellRow.job_id == JobRow.id)
            .where(CellRow.id == cell_id)
        ).first()
    if found is None or found.job_type != PLACEMENT_JOB:  # rounds are a placement job's alone
        return
    job_id = found.job_id
    if after_cell(db, blobs, job_id):
        send_planning(celery_app, job_id, "check")


class PlanningRequest(Request):
    """A plan or check request as the worker's main process sees it: when the pool process running
    it dies, the job's hold is freed at once (or the job failed, at its last attempt), so the
    redelivery Celery sends plans again instead of waiting for the lease to expire."""

    def on_failure(self, exc_info, send_failed_event=True, return_ok=False):
        lost = getattr(exc_info.exception, "exc", exc_info.exception)
        if isinstance(lost, WorkerLostError) and self.args:
            settings = Settings.from_env()
            db = Database(settings.database_url)
            try:
                state = release_planning(
                    db,
                    str(self.args[0]),
                    f"its worker process died: {lost}",
                    self.hostname,
                    settings.max_attempts,
                    blob_store(settings),
                )
                log.warning("job %s: its planning process died (%s); now %s", self.args[0], lost, state)
            except Exception:  # noqa: BLE001 - the lease expires and the sweeper sends it again
                log.exception("job %s: its planning process died, and its hold could not be freed", self.args[0])
            finally:
                db.dispose()
        return super().on_failure(exc_info, send_failed_event=send_failed_event, return_ok=return_ok)


class PlanningTask(Task):
    """A hard time limit fails the job it killed."""

    def on_failure(self, exc, task_id, args, kwargs, einfo) -> None:
        if isinstance(exc, TimeLimitExceeded) and args:
            settings = Settings.from_env()
            db = Database(settings.database_url)
            try:
                fail_planning(
                    db,
                    args[0],
                    f"{CellLimitError.__name__}: {hard_time_limit_message(_DECLARED.cell_hard_time_limit)}",
                    blobs=blob_store(settings),
                )
            finally:
                db.dispose()


def _planning(task, job_id: str, phase: str) -> str:
    settings, db, blobs = _records()
    limit, retries = max_retries(settings.max_attempts), task.request.retries
    guard = _memory_guard(settings)

    def over_memory(resident: int) -> None:  # the guard's thread, just before it ends this process
        # Only while this worker holds the job (a stale attempt must not fail a newer one's); no blob
        # deletion here, on the way to the kill: the redelivery finds the job failed and drops them.
        fail_planning(
            db,
            job_id,
            f"{CellLimitError.__name__}: {memory_limit_message(resident, guard.limit_mb, PLANNING)}",
            task.request.hostname,
        )

    try:
        with guard.armed(over_memory):
            state, cell_ids = run_planning(db, blobs, job_id, phase, task.request.hostname, settings.max_attempts)
    except SoftTimeLimitExceeded:
        fail_planning(
            db, job_id, f"{CellLimitError.__name__}: {time_limit_message(settings.cell_time_limit)}", blobs=blobs
        )
        return "failed"
    except Exception as error:  # noqa: BLE001 - transient (run_planning freed the hold): retried with backoff
        if retries < limit:
            raise task.retry(countdown=backoff(retries + 1), exc=error, max_retries=limit) from error
        fail_planning(
            db,
            job_id,
            f"{failure_message(error, failure_class(error))} (gave up after {retries + 1} deliveries)",
            blobs=blobs,
        )
        return "failed"
    _send_cells(db, cell_ids)
    return state


_PLANNING_LIMITS = {
    "soft_time_limit": _DECLARED.cell_time_limit,
    "time_limit": _DECLARED.cell_hard_time_limit,
    "max_retries": max_retries(_DECLARED.max_attempts),
}


@celery_app.task(bind=True, base=PlanningTask, Request=PlanningRequest, name=PLAN_PLACEMENT, **_PLANNING_LIMITS)
def plan_placement(self, job_id: str) -> str:
    """Plan a placement job and send its cells (service.placement.rounds.plan_job)."""
    return _planning(self, job_id, "plan")


@celery_app.task(bind=True, base=PlanningTask, Request=PlanningRequest, name=CHECK_PLACEMENT, **_PLANNING_LIMITS)
def check_placement(self, job_id: str) -> str:
    """Check a placement job's baked round, repair it and send the additions, or end it with its database."""
    return _planning(self, job_id, "check")


# A part of a placement job's candidate step (FARFIELD_PLANNING_PARTS > 1): claimed, computed and
# stored for the planning task that sent it, which merges the parts (service.placement.candidate_fanout).
PLAN_CANDIDATE_PART = "farfield.plan_candidate_part"


@celery_app.task(name=PLAN_CANDIDATE_PART, **{k: v for k, v in _PLANNING_LIMITS.items() if k != "max_retries"})
def plan_candidate_part(prefix: str, part: int, start: int, stop: int) -> str:
    """Compute part ``part`` (hierarchy nodes ``start``..``stop``) of the planning at ``prefix``, unless
    another process claimed it or the planning ended (its planning task then plans it itself)."""
    _, _, blobs = _records()
    return run_part(blobs, prefix, part, start, stop)


register_sender(
    lambda prefix, part, start, stop: celery_app.send_task(
        PLAN_CANDIDATE_PART,
        args=[prefix, part, start, stop],
        queue=RENDER_QUEUE,
        retry=True,
        retry_policy=SEND_RETRY_POLICY,
    )
)


# An admission's delivery stops after ADMISSION_DELIVERY_S and sends itself again, its progress kept.
# Its time limits are its own, not a cell's (a cell limit of seconds must not end an admission of
# 10,000 cells, whose checks the request ran before issue 58 with no limit): one check is bounded by
# its texel budget (service.jobs.admission.PLAN_BEYOND_LIMIT), these only catch a hang.
ADMISSION_DELIVERY_S = 30.0
ADMISSION_TIME_LIMIT = max(_DECLARED.cell_time_limit, 300)


@celery_app.task(
    bind=True, name=ADMIT_JOB, soft_time_limit=ADMISSION_TIME_LIMIT, time_limit=ADMISSION_TIME_LIMIT + CELL_TIME_GRACE,
    max_retries=max_retries(_DECLARED.max_attempts),
)  # fmt: skip
def admit_job_task(self, job_id: str, held_by: list | None = None) -> str:
    """Check every cell of an admitting job and send those that pass (service.jobs.admitting.admit_job).
    Each delivery stops after ``ADMISSION_DELIVERY_S`` and sends itself again, its progress kept; a delivery
    that fails frees its hold, and the API's sweeper sends it again (a run of ``FARFIELD_MAX_ATTEMPTS``
    deliveries without progress fails the job).  Where the hold cannot be freed either (the database is
    down), the task is retried with backoff (2, 4, 8, ... s: :func:`~farfield.service.jobs.runner.backoff`),
    ``held_by`` naming the holds of the failed deliveries (``[worker, attempt]``; a bare worker name, from an
    older release, frees that host's hold whatever its attempt), which the retry frees first: the admission goes
    on within a backoff of the database's return, not when the hold's lease (``FARFIELD_ADMISSION_LEASE_S``)
    or, had the claim itself failed, the job's first ``FARFIELD_REQUEUE_AFTER`` runs out."""
    settings, db, blobs = _records()
    worker = self.request.hostname
    limit, retries = max_retries(settings.max_attempts), self.request.retries
    claimed: list[int] = []  # the attempt this delivery holds, once it holds one
    # [worker, attempt]; a bare worker name (an older release's message) frees the host's hold whatever its
    # attempt, and is passed on to a further retry as [worker, None]
    earlier = [
        [h, None] if isinstance(h, str) else [str(h[0]), None if h[1] is None else int(h[1])] for h in held_by or ()
    ]
    try:
        for holder, attempt in earlier:
            release_admission(db, job_id, holder, attempt)
        state, cell_ids = admit_job(
            db,
            blobs,
            job_id,
            worker,
            settings.max_attempts,
            settings.admission,
            deadline_s=ADMISSION_DELIVERY_S,
            lease_s=settings.admission_lease_s,
            claimed=claimed,
        )
    except Exception as error:  # noqa: BLE001 - the sweeper sends it again; stalled deliveries are counted
        log.warning("job %s: admission failed (%s); freeing its hold", job_id, error, exc_info=True)
        # This delivery's hold, if it took one (one whose claim failed holds nothing; a claim whose
        # commit was lost with the database is left to its lease), and the earlier ones'.
        holders = earlier + [[worker, attempt] for attempt in claimed]
        try:
            for holder, attempt in holders:
                release_admission(db, job_id, holder, attempt)
            if not claimed:
                # Its claim failed, so it holds nothing to free; with the database away it is retried all
                # the same, or the job would wait for the sweeper's FARFIELD_REQUEUE_AFTER.
                db.ping()
        except Exception:  # noqa: BLE001 - the database is away: retried, freeing the hold first
            if retries < limit:
                countdown = backoff(retries + 1)
                log.warning("job %s: its hold could not be freed either; admission retried in %g s", job_id, countdown)
                raise self.retry(
                    countdown=countdown,
                    args=[job_id],
                    kwargs={"held_by": holders},
                    exc=error,
                    max_retries=limit,
                ) from error
            log.warning("job %s: its hold could not be freed and no retry is left; its lease ends it", job_id)
            return "held"
        return "released"
    if state == "continue":
        send_admission(celery_app, job_id)
    try:  # by cost: service.pools
        queues = cell_queues(db, cell_ids, settings.heavy_texels)
    except Exception as error:  # noqa: BLE001 - admitted cells must be sent now, not at the sweeper's requeue (an hour)
        log.warning("job %s: cell queues not read (%s); its cells go to the render queue", job_id, error)
        queues = None
    _send_cells(db, cell_ids, queues)
    return state


def _send_cells(db: Database, cell_ids: list[str], queues: dict[str, str] | None = None) -> None:
    """:func:`send_cells`; where Redis stays away past the sends' retries (``SEND_RETRY_POLICY``, about
    a minute), the cells not sent are left to the API's next sweep
    (:func:`~farfield.service.jobs.cells.resend_at_next_sweep`), not to ``FARFIELD_REQUEUE_AFTER``."""

    def unsent(ids: list[str]) -> None:
        try:
            log.warning("%d cells not sent; the API's next sweep sends them", resend_at_next_sweep(db, ids))
        except Exception:  # noqa: BLE001 - then FARFIELD_REQUEUE_AFTER brings them back
            log.exception("%d cells not sent, and not marked for the next sweep either", len(ids))

    try:
        send_cells(celery_app, cell_ids, queues, unsent=unsent)
    except BROKER_ERRORS as error:  # the cells are queued in the database: the sweep sends them
        log.warning("sending %d cells failed past its retries: %s", len(cell_ids), error)
