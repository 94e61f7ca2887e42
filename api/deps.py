"""What every route needs: the process's services and the caller's tenant."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated

from celery import Celery
from fastapi import Request, Security
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from farfield.service.blobs import BlobStore
from farfield.service.db import Database
from farfield.service.keys import authenticate, bearer_key
from farfield.service.scene_check import SceneCheckGate
from farfield.service.settings import Settings
from farfield.workers.app import BAKE_CELL, RENDER_QUEUE

RETRY_POLICY = {"max_retries": 30, "interval_start": 0.2, "interval_step": 0.5, "interval_max": 2.0}


@dataclass
class Services:
    settings: Settings
    db: Database
    blobs: BlobStore
    celery: Celery
    # Bounds the scene checks of uploads in this process (service/scene_check.py).
    scene_checks: SceneCheckGate = field(init=False)

    def __post_init__(self) -> None:
        self.scene_checks = SceneCheckGate(self.settings.scene_checks, self.settings.scene_check_queue)

    def enqueue(self, cell_ids: list[str]) -> None:
        """Send one bake task per cell to the render queue (retrying while Redis is away)."""
        for cell_id in cell_ids:
            self.celery.send_task(BAKE_CELL, args=[cell_id], queue=RENDER_QUEUE, retry=True, retry_policy=RETRY_POLICY)


def services(request: Request) -> Services:
    return request.app.state.services


# Declares the key in the OpenAPI document (the security of every route that depends on `tenant`);
# its absence is our 401 with our message, not the 403 of FastAPI's auto_error.
BEARER_KEY = HTTPBearer(
    auto_error=False,
    scheme_name="BearerKey",
    description="an API key: 'Authorization: Bearer <key>' (farfield keys create)",
)


def tenant(request: Request, credentials: Annotated[HTTPAuthorizationCredentials | None, Security(BEARER_KEY)]) -> str:
    """The tenant id of the request's Bearer key (401 without a valid one).  ``credentials`` only
    documents the scheme in the OpenAPI document; the key is read by :func:`bearer_key`, as the
    upload's early check reads it."""
    return authenticate(services(request).db, bearer_key(request.headers.getlist("authorization")))
