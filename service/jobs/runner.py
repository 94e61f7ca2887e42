"""One cell of a job, start to end: claim it, bake its impostor, store the bundle, evaluate it, record the outcome.

The job's technique (:func:`farfield.core.techniques.get_technique`) bakes the cell.  A cell of a technique
of one part (layered, tdm) is then evaluated against the part's real geometry from a few viewpoints
(:func:`farfield.core.techniques.part.report_part`), unless the job says ``evaluate: false``; the figures
and the time they took go in the cell's record (``stats.evaluation``), never in the bundle, beside
this attempt's bake timings (``stats.seconds``) and whether this attempt baked the bundle or found it
(``stats.baked``).  A placement job's cell (``cells.params``, :mod:`farfield.service.placement`) is of its
algorithm's kind: keyed (:meth:`~farfield.service.placement.base.Algorithm.cell_inputs`) and baked
(:meth:`~farfield.service.placement.base.Algorithm.bake_cell`) by the job's algorithm with its own
technique, objects and options, and not evaluated here (the walkthrough measures a placement).

This is everything a worker task does (``workers/tasks.py`` is a few lines around it).  The bundle
is published under a key derived from everything that determines its bytes
(:func:`farfield.service.jobs.cells.result_key`) all at once (the local store renames a staging folder into
place; S3 writes the manifest last), so a bundle whose manifest exists is complete, a redelivered
cell finds it and does not bake again, and two workers baking the same key never mix their files.
"""

from __future__ import annotations

import contextlib
import json
import logging
import tempfile
import time
from pathlib import Path

from celery.exceptions import SoftTimeLimitExceeded

from farfield.core.errors import BundleFormatError, CellLimitError, InternalError
from farfield.core.impostor.bundle import MANIFEST_NAME, write_bundle
from farfield.core.impostor.impostor import Impostor
from farfield.core.scene import Scene
from farfield.core.techniques import get_technique
from farfield.core.techniques.part import report_part
from farfield.core.viewcells import viewcell_from_dict
from farfield.service.blobs import BlobStore
from farfield.service.cell_limits import MemoryGuard, memory_limit_message, time_limit_message
from farfield.service.db import CellRow, Database, JobRow, SceneRow
from farfield.service.failures import BAD_INPUT, INTERNAL, failure_class, failure_message
from farfield.service.jobs.cells import (
    attempt_stopped,
    claim_cell,
    end_cell,
    finish_job_if_complete,
    result_key,
    set_progress,
)
from farfield.service.jobs.instances import bundle_stored, prototype_bake, publish_instance, read_cell_impostor
from farfield.service.placement import job_algorithm
from farfield.service.scenes import load_stored_scene
from farfield.service.settings import LEASE_S

# A running cell looks at its job's state at the first layer after CANCEL_CHECK_S since its last
# look (checking at every layer cost ~6% of a cell: ~1.7 ms a query against ~10 ms a layer at
# 1024 on llvmpipe), and writes its progress every PROGRESS_EVERY_S.
CANCEL_CHECK_S = 0.1
PROGRESS_EVERY_S = 0.5
# A cell's progress while it is evaluated (after its bundle is published).
EVALUATION_PROGRESS = 0.95


class CellCancelled(Exception):
    """The cell's job was cancelled while it ran."""


class LeaseLost(Exception):
    """The attempt no longer holds the cell: its lease expired while it ran (its worker stopped
    renewing it: paused, cut off) and the cell was queued again, or the worker's main process ended
    the cell at its time limit.  This attempt stops, and records nothing."""


class RetryCell(Exception):
    """The attempt failed in a way worth retrying (transient or internal, attempts left), after
    ``countdown`` seconds; the attempt is counted on the cell, which is queued again."""

    def __init__(self, message: str, countdown: float) -> None:
        super().__init__(message)
        self.countdown = countdown


def backoff(attempt: int) -> float:
    """Seconds before attempt ``attempt + 1``: 2, 4, 8, ... capped at 60."""
    return float(min(2**attempt, 60))


log = logging.getLogger("farfield.cells")


def bake_cell(job: JobRow, scene: Scene, viewcell: dict, progress, cell: CellRow | None = None) -> Impostor:
    """The impostor of one cell of ``job``, baked by the job's technique (:mod:`farfield.core.techniques`);
    a placement job's cell by its algorithm, with the cell's own parameters
    (:meth:`~farfield.service.placement.base.Algorithm.bake_cell`)."""
    algorithm = job_algorithm(job)
    if algorithm is not None:
        return algorithm.bake_cell(scene, cell, progress)
    technique = get_technique(job.job_type)
    return technique.bake(
        scene, viewcell_from_dict(viewcell), technique.options_of(job.params), job.params.get("objects"), progress
    )


def cell_key(scene_hash: str, job: JobRow, cell: CellRow) -> str:
    """The blob prefix of a cell's bundle (:func:`~farfield.service.jobs.cells.result_key`): of the job's
    technique and params, or, a placement job's cell, of what its algorithm says makes its bytes (its
    own parameters: equal impostors of another job are found), within the job's tenant."""
    algorithm = job_algorithm(job)
    if algorithm is not None:
        kind, own = algorithm.cell_inputs(cell)
        return result_key(scene_hash, kind, own, cell.viewcell, job.tenant_id)
    return result_key(scene_hash, job.job_type, job.params, cell.viewcell, job.tenant_id)


def evaluate_cell(
    blobs: BlobStore, scene_row: SceneRow, key: str, scene: Scene | None = None, impostor: Impostor | None = None
) -> dict:
    """The job report's evaluation of the bundle under ``key`` (:func:`farfield.core.techniques.part.report_part`):
    of ``impostor`` when this attempt baked it, else of the stored bundle read back (a redelivered
    cell, or equal inputs another job baked); ``scene`` is loaded when not given."""
    if scene is None:
        scene = load_stored_scene(blobs, scene_row)
    if impostor is None:
        with tempfile.TemporaryDirectory(prefix="farfield-cell-") as tmp:
            try:
                impostor = read_cell_impostor(blobs, key, Path(tmp) / "bundle")
            except BundleFormatError as error:  # a bundle this service published: a bug, not bad input
                raise InternalError(f"the stored bundle {key} could not be read: {error}") from error
    return report_part(scene, impostor)


def _raised_by_time_limit(error: BaseException) -> bool:
    """Whether ``error`` is Celery's soft time limit, or was raised while handling it: a library that
    wraps every exception (moderngl's context creation: ``RenderBackendError: no usable EGL OpenGL 3.3
    context: SoftTimeLimitExceeded()``) would otherwise turn the limit into a transient failure, and
    the cell past its limit would be retried up to the attempt limit."""
    seen: set[int] = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, SoftTimeLimitExceeded):
            return True
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return False


def run_cell(
    db: Database, blobs: BlobStore, cell_id: str, max_attempts: int, worker: str | None = None,
    *, time_limit: int | None = None, memory: MemoryGuard | None = None, lease_s: float = LEASE_S,
) -> str:  # fmt: skip
    """Run one cell; returns its new state ("done", "failed", "cancelled"), "skipped", or "lost"
    (the cell went on without this attempt: its lease expired while it ran,
    :mod:`farfield.service.jobs.leases`, or the worker's main process failed it at the time limit;
    nothing recorded).

    A failed attempt is counted on the cell and falls in one of three classes
    (:func:`failure_class`):

    - **transient**: the infrastructure failed (database: SQLAlchemy OperationalError and the like;
      broker/Redis connection errors; blob store errors; any OSError; no renderer).  The cell is
      queued again and :class:`RetryCell` raised with :func:`backoff`, until ``max_attempts``
      attempts, then it is failed with the error.
    - **bad input**: a :class:`~farfield.core.errors.FarfieldError` of kind BAD_INPUT or MISSING.  The
      cell is failed at once with its message; no retry can help.
    - **internal**: a bug (any other exception) or a broken invariant
      (:class:`~farfield.core.errors.InternalError`).  Retried like a transient failure (it may depend on
      the worker), its traceback logged at each attempt; after ``max_attempts`` the cell is failed
      with ``internal error: Type: message``.

    Past the worker's limits (:mod:`farfield.service.cell_limits`) the cell is failed at once, as bad input
    (a :class:`~farfield.core.errors.CellLimitError`): Celery's soft time limit (``time_limit``
    seconds, named in the message) raises ``SoftTimeLimitExceeded`` here, and ``memory``, armed
    while the cell bakes and is evaluated, fails the cell and ends the process past its limit.

    Every state change names the attempt it ends and its lease token, so a stale duplicate delivery,
    or an attempt whose lease expired meanwhile, changes nothing.
    An exception that escapes (claiming the cell or recording its outcome failed, so no attempt or
    not its end was recorded) is the caller's to retry and count: the worker task
    (:mod:`farfield.workers.tasks`) counts it in the Celery message's retries, within a bounded limit.
    """
    claim = claim_cell(db, cell_id, max_attempts, worker, lease_s)
    if claim.cell is None and claim.job_id is not None:
        # Ended here, or found ended: a redelivery after the outcome was recorded but its job's end
        # was not (the database failed between them) ends the job now (idempotent).
        finish_job_if_complete(db, blobs, claim.job_id)
    if claim.cell is None:
        return "skipped"
    cell, attempt, token = claim.cell, claim.cell.attempts, claim.cell.lease_token
    start = time.perf_counter()
    last_check, last_progress = [start], [start]

    def end(state: str, **values) -> bool:
        ended = end_cell(db, cell_id, attempt, state, seconds=time.perf_counter() - start, token=token, **values)
        if ended and state != "queued":
            finish_job_if_complete(db, blobs, cell.job_id)
        if not ended:
            log.warning(
                "cell %s attempt %d: the cell went on without it (its lease was lost, or its time limit or job ended it); "
                "its outcome (%s) is discarded", cell_id, attempt, state,
            )  # fmt: skip
        return ended

    def progress(stage: str, done: int, total: int) -> None:
        # Called after each recorded layer: a cancelled job's running cells stop within
        # CANCEL_CHECK_S and a layer.
        if stage != "record":
            return
        clock = time.perf_counter()
        if clock - last_check[0] >= CANCEL_CHECK_S:
            last_check[0] = clock
            stopped = attempt_stopped(db, cell)
            if stopped == "cancelled":
                raise CellCancelled(f"job {cell.job_id} was cancelled")
            if stopped == "lost":
                raise LeaseLost(f"cell {cell_id} attempt {attempt} no longer holds the cell")
        if clock - last_progress[0] >= PROGRESS_EVERY_S:
            last_progress[0] = clock
            set_progress(db, cell_id, 0.9 * done / max(total, 1), token)  # recording is most of a cell

    def over_memory(resident: int) -> None:  # the guard's thread, just before it ends this process
        end("failed", error=f"{CellLimitError.__name__}: {memory_limit_message(resident, memory.limit_mb)}")

    guard = memory.armed(over_memory) if memory is not None else contextlib.nullcontext()
    try:
        with guard:
            job, scene_row = claim.job, claim.scene
            key = cell_key(scene_row.content_hash, job, cell)
            seconds = None  # this attempt's bake timings (a bundle stores none: its bytes depend on its inputs alone)
            scene = impostor = None
            baked = not bundle_stored(blobs, key)
            prototype = None  # (key, whether this attempt baked it) of an instance's shared prototype
            if baked:
                scene = load_stored_scene(blobs, scene_row)
                shared = None if job_algorithm(job) else prototype_bake(blobs, job, scene, cell.viewcell, progress)
                if shared is not None:  # an instance's bundle: its own manifest and payload, its prototype's pages
                    impostor, prototype = shared.impostor, (shared.key, shared.baked)
                    publish_instance(blobs, key, shared)
                else:
                    impostor = bake_cell(job, scene, cell.viewcell, progress, cell)
                    with tempfile.TemporaryDirectory(prefix="farfield-cell-") as tmp:
                        try:
                            # Not synced: the blob store's copy is what counts (a local store links these files).
                            write_bundle(impostor, Path(tmp) / "bundle", sync=False)
                        except (
                            BundleFormatError
                        ) as error:  # the bake's own output does not fit its format: a bug, not bad input
                            raise InternalError(f"the baked impostor could not be written: {error}") from error
                        blobs.publish_directory(key, Path(tmp) / "bundle", last=MANIFEST_NAME)
                seconds = impostor.stats.get("seconds")
            stats = json.loads(blobs.read_bytes(f"{key}/{MANIFEST_NAME}"))["stats"]
            if seconds is not None:
                stats["seconds"] = seconds
            stats["baked"] = baked  # False: the bundle was found (a redelivery, or equal inputs of another job)
            if prototype is not None:  # an instance's bundle: its prototype's impostor moved (jobs/instances.py)
                stats["prototype"], stats["baked"] = prototype
            if job.evaluate and job_algorithm(job) is None and get_technique(job.job_type).scope == "part":
                set_progress(db, cell_id, EVALUATION_PROGRESS, token)
                stats["evaluation"] = evaluate_cell(blobs, scene_row, key, scene, impostor)
    except CellCancelled:
        end("cancelled")
        return "cancelled"
    except LeaseLost:
        log.warning(
            "cell %s attempt %d: the cell went on without it (its lease was lost, or its time limit ended it); stopped, "
            "nothing recorded", cell_id, attempt,
        )  # fmt: skip
        return "lost"
    except Exception as error:  # noqa: BLE001 - every failure is classified and recorded on the cell
        if _raised_by_time_limit(error):  # Celery's soft time limit: bad input, never retried
            error = CellLimitError(
                time_limit_message(time_limit) if time_limit else "the cell ran past the worker's time limit"
            )
        klass = failure_class(error)
        message = failure_message(error, klass)
        final = klass == BAD_INPUT or attempt >= max_attempts
        outcome = "failed" if final else f"retried in {backoff(attempt):g} s"
        if klass == INTERNAL:  # a bug: the traceback is what fixes it
            log.error(
                "cell %s attempt %d of %d: %s (%s)", cell_id, attempt, max_attempts, message, outcome, exc_info=error
            )
        else:
            log.warning(
                "cell %s attempt %d of %d: %s failure: %s (%s)", cell_id, attempt, max_attempts, klass, message, outcome
            )
        if final:
            return "failed" if end("failed", error=message) else "lost"
        if not end("queued", error=message):
            return "lost"  # the cell went on without this attempt: no retry of its own
        raise RetryCell(message, backoff(attempt)) from error
    return "done" if end("done", result=key, stats=stats) else "lost"
