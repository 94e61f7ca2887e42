"""One cell of a job, start to end: claim it, bake its impostor, store the bundle, record the outcome.

The job's type picks the bake: ``layered`` -> :func:`core.bake.bake_layered` of the job's objects,
``envmap`` -> :func:`core.envmap.bake_envmap` of the whole scene, ``tdm`` -> :func:`core.tdm.bake_tdm`
of the job's objects.

This is everything a worker task does (``workers/tasks.py`` is a few lines around it).  The bundle
is published under a key derived from everything that determines its bytes
(:func:`service.jobs.result_key`) all at once (the local store renames a staging folder into
place; S3 writes the manifest last), so a bundle whose manifest exists is complete, a redelivered
cell finds it and does not bake again, and two workers baking the same key never mix their files.
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

from core.bake import bake_layered
from core.bundle import MANIFEST_NAME, write_bundle
from core.envmap import bake_envmap
from core.errors import ErrorKind, FarfieldError, LayerPlanError
from core.impostor import Impostor
from core.scene import Scene
from core.tdm import bake_tdm
from core.viewcells import viewcell_from_dict
from service.blobs import BlobStore
from service.db import Database, JobRow, SceneRow
from service.jobs import bake_options, claim_cell, end_cell, envmap_options, finish_job_if_complete, job_cancelled, result_key, set_progress, tdm_options
from service.scenes import load_stored_scene

# A running cell looks at its job's state at the first layer after CANCEL_CHECK_S since its last
# look (checking at every layer cost ~6% of a cell: ~1.7 ms a query against ~10 ms a layer at
# 1024 on llvmpipe), and writes its progress every PROGRESS_EVERY_S.
CANCEL_CHECK_S = 0.1
PROGRESS_EVERY_S = 0.5


class CellCancelled(Exception):
    """The cell's job was cancelled while it ran."""


class RetryCell(Exception):
    """The attempt failed in a way worth retrying, after ``countdown`` seconds."""

    def __init__(self, message: str, countdown: float) -> None:
        super().__init__(message)
        self.countdown = countdown


def backoff(attempt: int) -> float:
    """Seconds before attempt ``attempt + 1``: 2, 4, 8, ... capped at 60."""
    return float(min(2**attempt, 60))


def bake_cell(job: JobRow, scene: Scene, viewcell: dict, progress) -> Impostor:
    """The impostor of one cell of ``job`` (its type picks the technique)."""
    cell = viewcell_from_dict(viewcell)
    if job.job_type == "layered":
        return bake_layered(scene, cell, bake_options(job.params), job.params["objects"], progress)
    if job.job_type == "envmap":
        return bake_envmap(scene, cell, envmap_options(job.params), progress)
    if job.job_type == "tdm":
        return bake_tdm(scene, cell, tdm_options(job.params), job.params["objects"], progress)
    raise LayerPlanError(f"job {job.id} has an unknown job type {job.job_type!r}")


def run_cell(db: Database, blobs: BlobStore, cell_id: str, max_attempts: int, worker: str | None = None) -> str:
    """Run one cell; returns its new state ("done", "failed", "cancelled") or "skipped".

    Raises :class:`RetryCell` when the attempt failed for a reason other than bad input and
    attempts are left; the cell is queued again and the caller schedules the retry.  Every state
    change names the attempt it ends, so a stale duplicate delivery changes nothing.
    """
    claim = claim_cell(db, cell_id, max_attempts, worker)
    if claim.ended:
        finish_job_if_complete(db, blobs, claim.job_id)
    if claim.cell is None:
        return "skipped"
    cell, attempt = claim.cell, claim.cell.attempts
    start = time.perf_counter()
    last_check, last_progress = [start], [start]

    def end(state: str, **values) -> None:
        if end_cell(db, cell_id, attempt, state, seconds=time.perf_counter() - start, **values) and state != "queued":
            finish_job_if_complete(db, blobs, cell.job_id)

    def progress(stage: str, done: int, total: int) -> None:
        # Called after each recorded layer: a cancelled job's running cells stop within
        # CANCEL_CHECK_S and a layer.
        if stage != "record":
            return
        clock = time.perf_counter()
        if clock - last_check[0] >= CANCEL_CHECK_S:
            last_check[0] = clock
            if job_cancelled(db, cell.job_id):
                raise CellCancelled(f"job {cell.job_id} was cancelled")
        if clock - last_progress[0] >= PROGRESS_EVERY_S:
            last_progress[0] = clock
            set_progress(db, cell_id, 0.9 * done / max(total, 1))  # recording is most of a cell

    try:
        with db.session() as s:
            job = s.get(JobRow, cell.job_id)
            scene_row = s.get(SceneRow, job.scene_id)
        key = result_key(scene_row.content_hash, job.job_type, job.params, cell.viewcell)
        if not blobs.exists(f"{key}/{MANIFEST_NAME}"):
            scene = load_stored_scene(blobs, scene_row)
            impostor = bake_cell(job, scene, cell.viewcell, progress)
            with tempfile.TemporaryDirectory(prefix="farfield-cell-") as tmp:
                write_bundle(impostor, Path(tmp) / "bundle")
                blobs.publish_directory(key, Path(tmp) / "bundle", last=MANIFEST_NAME)
        stats = json.loads(blobs.read_bytes(f"{key}/{MANIFEST_NAME}"))["stats"]
    except CellCancelled:
        end("cancelled")
        return "cancelled"
    except Exception as error:  # noqa: BLE001 - every failure is recorded on the cell
        message = f"{type(error).__name__}: {error}"
        permanent = isinstance(error, FarfieldError) and error.kind in (ErrorKind.BAD_INPUT, ErrorKind.MISSING)
        if permanent or attempt >= max_attempts:
            end("failed", error=message)
            return "failed"
        end("queued", error=message)
        raise RetryCell(message, backoff(attempt)) from error
    end("done", result=key, stats=stats)
    return "done"
