"""Celery tasks: each is a few lines around a function of ``service``."""

from __future__ import annotations

import os

from core.render.context import gl_context
from service.blobs import BlobStore, blob_store
from service.cell_runner import RetryCell, run_cell
from service.db import Database
from service.settings import Settings
from workers.app import BAKE_CELL, celery_app

_STATE: dict = {}
INFRASTRUCTURE_RETRY_S = 10  # the cell itself counts attempts; claim_cell fails it past the limit


def _services() -> tuple[Settings, Database, BlobStore]:
    """Settings, database and blob store of this process, made after any fork (never inherited)."""
    if _STATE.get("pid") != os.getpid():
        settings = Settings.from_env()
        _STATE.update(pid=os.getpid(), settings=settings, db=Database(settings.database_url), blobs=blob_store(settings))
        if os.environ.get("FARFIELD_EGL_DEVICE"):  # one worker per GPU: farfield up pins each to its device
            gl_context(int(os.environ["FARFIELD_EGL_DEVICE"]))
    return _STATE["settings"], _STATE["db"], _STATE["blobs"]


@celery_app.task(bind=True, name=BAKE_CELL, max_retries=None)
def bake_cell(self, cell_id: str) -> str:
    """Bake one cell of a job (service.cell_runner.run_cell), retrying with backoff."""
    settings, db, blobs = _services()
    try:
        return run_cell(db, blobs, cell_id, settings.max_attempts, worker=self.request.hostname)
    except RetryCell as retry:
        raise self.retry(countdown=retry.countdown, exc=None) from None
    except Exception as error:  # the database or blob store failed around the cell: try again later
        raise self.retry(countdown=INFRASTRUCTURE_RETRY_S, exc=error) from error
