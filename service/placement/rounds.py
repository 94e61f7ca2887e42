"""A placement job's life: plan, bake, check and repair, round after round, for every algorithm of the registry.

A placement job (``POST /v1/jobs`` with ``"placement"``; SQL ``job_type`` ``"placement"``, the
impostors' technique in ``params["technique"]``, its algorithm in ``params["placement"]``) goes

    queued -> placing (plan) -> running (bake round 0) -> placing (check round 1) -> running (bake round 1) -> ... -> done | failed | cancelled

- **plan** (:func:`plan_job`, the worker task ``farfield.plan_placement``): the job's algorithm
  (:meth:`~farfield.service.placement.base.Algorithm.plan`) on the stored scene; its progress is the
  job's ``planning`` record (``GET /v1/jobs/{id}`` shows it as ``"placement"``), cancellation is
  looked at between progress calls, a :class:`~farfield.core.errors.FarfieldError` of bad input fails
  the job with its message, anything else as ``internal error: ...``.  The planner state is kept as a
  blob (:mod:`farfield.service.placement.states`) and every impostor becomes one cell that carries its own
  parameters (``cells.params``).  A placement of no impostors ends ``done`` at once with its
  database.  An attempt that finds its job cancelled or failed removes the index it wrote.
- **bake**: the cells go to the render workers as a grid job's do (:func:`farfield.service.jobs.runner.run_cell`
  bakes a placement cell with its algorithm's :meth:`~farfield.service.placement.base.Algorithm.bake_cell`;
  its result key is made of its own parameters, so equal impostors of another job are found, not baked again).
- **check** (:func:`check_job`, ``farfield.check_placement``), when the last cell of a round ends
  done (:func:`end_round`): the algorithm's :meth:`~farfield.service.placement.base.Algorithm.check`
  repairs the round (the impostors it adds become cells of the next round) or writes the database
  index (``jobs/<id>/index.json``) and the job ends done.

Planning and checking are held by one worker at a time (:mod:`farfield.service.placement.lease`).
"""

from __future__ import annotations

import logging
import time

from sqlalchemy import func, select, update

from farfield.core.errors import QuotaError
from farfield.service.blobs import BlobStore
from farfield.service.db import CellRow, Database, JobRow, SceneRow, now
from farfield.service.failures import BAD_INPUT, INTERNAL, TRANSIENT, failure_class, failure_message
from farfield.service.placement import algorithm_of
from farfield.service.placement.base import add_cells
from farfield.service.placement.lease import (
    PlanningCancelled,
    claim_planning,
    fail_planning,
    heartbeat,
    release_planning,
    set_planning,
)
from farfield.service.placement.states import drop_ended_planning, drop_planner_states
from farfield.service.quotas import reserve_tenant_work
from farfield.service.scenes import load_stored_scene
from farfield.service.settings import MAX_CELLS, AdmissionLimits, Settings

log = logging.getLogger("farfield.placement")

CANCEL_CHECK_S = 0.2  # a planning job looks at its state at the first progress call after this
PROGRESS_EVERY_S = 0.5  # and writes its progress record
# The planning record's seconds of each phase, summed over the attempts that committed one (written
# with the round, so a job is never seen ended without them): the job's timing (service.jobs.timing).
PHASE_SECONDS = {"plan": "planning_s", "check": "checking_s"}


def pending_check(db: Database, job_id: str) -> bool:
    """Whether the job waits for its check task (the caller sends it)."""
    with db.session() as s:
        job = s.get(JobRow, job_id)
    return (
        job is not None
        and job.state == "placing"
        and (job.planning or {}).get("phase") == "check"
        and job.plan_worker is None
    )


def begin_check(session, job: JobRow, requeue_after: float | None = None) -> None:
    """The job's last cell of a round ended done: back to ``placing`` for the check (in the
    caller's session, the job row locked).  Its check message, if lost, is sent again by the
    API's sweeper after ``requeue_after`` seconds: by default ``FARFIELD_REQUEUE_AFTER`` of this
    process's settings (every process of a service has the same), as a queued plan's."""
    if requeue_after is None:
        requeue_after = Settings.from_env().requeue_after
    k = int((job.planning or {}).get("round", 0)) + 1
    job.state, job.plan_worker, job.plan_attempts, job.lease_until = "placing", None, 0, now() + requeue_after
    job.planning = {
        **(job.planning or {}),
        "phase": "check",
        "step": f"check round {k}",
        "done": 0,
        "total": 1,
        "check_round": k,
    }


def end_round(db: Database, job_id: str, final: str) -> bool:
    """A placement job's round ended (:func:`farfield.service.jobs.cells.finish_job_if_complete`): all done ->
    placing, to be checked (its worker sends the check task, :func:`pending_check`); else the job ends
    ``final`` (no database: it is written by the check).  True if this call ended the job."""
    with db.session() as s:
        job = s.get(JobRow, job_id, with_for_update=True)
        if job.state != "running":
            return False
        if final == "done":
            begin_check(s, job)
            return False
        job.state, job.finished_at = final, now()
        return True


def after_cell(db: Database, blobs: BlobStore, job_id: str) -> bool:
    """After a cell of the job ended: whether the job waits for its check task (the caller sends
    it); otherwise a placement job that has ended drops its planner states."""
    if pending_check(db, job_id):
        return True
    drop_ended_planning(db, blobs, job_id)
    return False


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


def plan_job(db: Database, blobs: BlobStore, job_id: str, worker: str, max_attempts: int) -> tuple[str, list[str]]:
    """Plan a placement job (see the module docstring): (its state after, cell ids to send)."""
    started = time.perf_counter()
    claim = claim_planning(db, blobs, job_id, "plan", worker, max_attempts)
    if claim.job is None:
        drop_ended_planning(db, blobs, job_id)
        return ("failed" if claim.ended else "skipped"), []
    job, attempt = claim.job, claim.attempt
    algorithm = algorithm_of(job.params)
    try:
        with heartbeat(db, job_id, worker, attempt):
            with db.session() as s:
                scene_row = s.get(SceneRow, job.scene_id)
            scene = load_stored_scene(blobs, scene_row)
            progress = _progress(db, job_id, worker, attempt, 0)
            state_key, doc, cells = algorithm.plan(blobs, job, scene, progress)
            index_key = algorithm.write_index(db, blobs, job, doc, []) if not cells else None
    except PlanningCancelled:
        return _end_cancelled(db, blobs, job_id), []
    return _commit_round(
        db,
        blobs,
        job_id,
        worker,
        attempt,
        state_key,
        cells,
        algorithm.impostors(doc),
        doc.get("summary"),
        0,
        index_key,
        [],
        timed=("plan", started),
    )


def _end_cancelled(db: Database, blobs: BlobStore, job_id: str) -> str:
    """After :class:`PlanningCancelled`: end a cancelled job's planning ("cancelled") and delete its
    planner states, or leave the job alone when this attempt only lost its hold ("skipped"): a newer
    attempt holds it, and clearing the hold would leave the job ``placing`` with nothing to send it again."""
    with db.session() as s:
        s.execute(
            update(JobRow)
            .where(JobRow.id == job_id, JobRow.state == "cancelled", JobRow.finished_at.is_(None))
            .values(finished_at=now())
        )
        ended = s.execute(
            update(JobRow)
            .where(JobRow.id == job_id, JobRow.state == "cancelled")
            .values(plan_worker=None, lease_until=None)
        ).rowcount
    if not ended:
        return "skipped"
    drop_ended_planning(db, blobs, job_id)
    return "cancelled"


def _commit_round(
    db, blobs, job_id, worker, attempt, state_key, cells: list[dict], impostors: int, summary, round_, index_key, rounds,
    timed: tuple[str, float] | None = None,
) -> tuple[str, list[str]]:  # fmt: skip
    """Store a planned or repaired round: its ``cells`` (queued), or the database when none was added.
    Then only the state the next check loads is kept (all are deleted when the job ended).  An
    attempt that finds its job cancelled or failed meanwhile removes the index it wrote (a newer
    attempt that only took its hold writes its own under the same key: that one is left alone).
    ``timed``: (the phase, its ``time.perf_counter()`` at the start), its seconds added to the record."""
    committed, state, made = _commit_round_row(
        db, job_id, worker, attempt, state_key, cells, impostors, summary, round_, index_key, rounds, timed
    )
    if committed and state == "running":
        drop_planner_states(blobs, job_id, keep=state_key)
    elif state in ("failed", "cancelled") or (committed and state == "done"):
        if not committed and index_key is not None:
            blobs.delete_prefix(index_key)
        drop_ended_planning(db, blobs, job_id)
    return state, made


def _commit_round_row(
    db, job_id, worker, attempt, state_key, cells: list[dict], impostors: int, summary, round_, index_key, rounds,
    timed: tuple[str, float] | None = None,
) -> tuple[bool, str, list[str]]:  # fmt: skip
    """:func:`_commit_round`'s change of the job's row: (whether this attempt committed, the job's
    state, the cells made)."""
    with db.session() as s:
        job = s.get(JobRow, job_id, with_for_update=True)
        if job.state != "placing" or job.plan_worker != worker or job.plan_attempts != attempt:
            return False, job.state, []  # cancelled meanwhile (or the hold was lost): nothing stored
        if index_key is None:
            have = s.scalar(select(func.count()).select_from(CellRow).where(CellRow.job_id == job_id))
            if have + len(cells) > MAX_CELLS:
                job.state, job.finished_at, job.plan_worker, job.lease_until = "failed", now(), None, None
                job.error = algorithm_of(job.params).too_many_cells(have + len(cells), MAX_CELLS)
                return True, job.state, []
        if index_key is None and cells:
            try:  # the placement's cells count against the tenant's quota as any job's (issue 59, item 6)
                reserve_tenant_work(s, job.tenant_id, len(cells), AdmissionLimits.from_env())
            except QuotaError as error:
                job.state, job.finished_at, job.plan_worker, job.lease_until = "failed", now(), None, None
                job.error = f"the planned impostors were not queued: {error}; submit the job again then"
                return True, job.state, []
        made = add_cells(s, job, cells) if index_key is None else []
        record = {
            **job.planning, "phase": "bake", "step": f"bake round {round_}" if made else "done", "round": round_, "state_key": state_key,
            "impostors": impostors, "summary": _summary_of(summary), "rounds": rounds, "done": 0, "total": 0,
        }  # fmt: skip
        record.pop("worker", None)
        if timed is not None:
            key = PHASE_SECONDS[timed[0]]
            record[key] = float(record.get(key, 0.0)) + time.perf_counter() - timed[1]
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
        "by_technique",  # mixed candidates: impostors and memory of each technique (and lod) chosen
    )  # fmt: skip
    return {k: summary[k] for k in keep if k in summary}


def check_job(db: Database, blobs: BlobStore, job_id: str, worker: str, max_attempts: int) -> tuple[str, list[str]]:
    """Check a placement job's baked round and repair it (see the module docstring): (its state
    after, the cell ids of the added impostors, to send)."""
    started = time.perf_counter()
    claim = claim_planning(db, blobs, job_id, "check", worker, max_attempts)
    if claim.job is None:
        drop_ended_planning(db, blobs, job_id)
        return ("failed" if claim.ended else "skipped"), []
    job, attempt = claim.job, claim.attempt
    planning = job.planning
    round_ = int(planning.get("check_round", planning.get("round", 0) + 1))
    with heartbeat(db, job_id, worker, attempt):
        done = algorithm_of(job.params).check(db, blobs, job, round_, list(planning.get("rounds", [])))
    return _commit_round(
        db,
        blobs,
        job_id,
        worker,
        attempt,
        done.state_key,
        done.cells,
        done.impostors,
        done.summary,
        done.round,
        done.index_key,
        done.rounds,
        timed=("check", started),
    )


def run_planning(
    db: Database, blobs: BlobStore, job_id: str, phase: str, worker: str, max_attempts: int
) -> tuple[str, list[str]]:
    """:func:`plan_job` or :func:`check_job`, a failure sorted as a cell's is
    (:func:`farfield.service.failures.failure_class`): bad input fails the job with its message at once;
    a bug fails it as ``internal error: ...`` (a plan is deterministic: running it again would fail
    again); a transient failure frees the hold and is raised for the task to retry."""
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
