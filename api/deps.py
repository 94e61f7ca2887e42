"""What every route needs: the process's services and the caller's tenant."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Annotated

from celery import Celery
from fastapi import Request, Security
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from farfield.api.auth_failures import FailedAuthLimiter
from farfield.api.broker_probe import BrokerProbe
from farfield.core.errors import AuthError
from farfield.service.blobs import BlobStore
from farfield.service.db import Database
from farfield.service.jobs.admitting import resend_admission_at_next_sweep
from farfield.service.jobs.cells import resend_at_next_sweep
from farfield.service.keys import authenticate, bearer_key
from farfield.service.placement.lease import resend_planning_at_next_sweep
from farfield.service.pools import cell_queues
from farfield.service.scene_check import SceneCheckGate
from farfield.service.settings import Settings
from farfield.workers.app import BROKER_ERRORS, SEND_RETRY_POLICY, send_admission, send_cells, send_planning

log = logging.getLogger("farfield.api")


@dataclass
class Services:
    settings: Settings
    db: Database
    blobs: BlobStore
    celery: Celery
    # Bounds the scene checks of uploads in this process (service/scene_check.py).
    scene_checks: SceneCheckGate = field(init=False)
    # Counts failed authentication per client (api/auth_failures.py).
    auth_failures: FailedAuthLimiter = field(init=False)
    # The broker's reachability for the health check, on kept connections (api/broker_probe.py).
    broker: BrokerProbe = field(init=False)
    # How a send to Redis is retried while it is away (workers/app.py); past it the send fails.
    send_retry_policy: dict = field(default_factory=lambda: dict(SEND_RETRY_POLICY))

    def __post_init__(self) -> None:
        self.scene_checks = SceneCheckGate(self.settings.scene_checks, self.settings.scene_check_queue)
        self.auth_failures = FailedAuthLimiter(self.settings.auth_failures)
        self.broker = BrokerProbe(self.celery.conf.broker_url)

    def authenticate(self, client: str, values: list[str]) -> str:
        """The tenant of a request from ``client`` (its address) with these ``Authorization`` header
        values: the one path every route and the upload's early check take.  A key that does not
        authenticate is :class:`AuthError` (401), or, past the client's allowance of failures,
        :class:`~farfield.core.errors.AuthRateError` (429, api/auth_failures.py); a valid key
        always passes."""
        try:
            return authenticate(self.db, bearer_key(values))
        except AuthError:
            if values:  # credentials were presented: a guess
                self.auth_failures.failed(client)
            raise

    def enqueue(self, cell_ids: list[str]) -> bool:
        """Send one bake task per cell to its queue (its planned texels': service/pools.py), retrying
        while Redis is away; where a send fails past its retries, the cells it left unsent are marked
        for the next sweep (:func:`~farfield.service.jobs.cells.resend_at_next_sweep`) and False is
        returned (the cells are stored: the sweep sends them)."""
        queues = cell_queues(self.db, cell_ids, self.settings.heavy_texels)
        try:
            send_cells(
                self.celery,
                cell_ids,
                queues,
                unsent=lambda ids: resend_at_next_sweep(self.db, ids),
                retry_policy=self.send_retry_policy,
            )
            return True
        except BROKER_ERRORS as error:  # marked above: the next sweep sends them
            log.warning("%d cells not sent (%s); the next sweep sends them", len(cell_ids), error)
            return False

    def send_planning(self, job_id: str, phase: str = "plan") -> bool:
        """Send a placement job's planning (``phase`` "plan") or check task, retrying while Redis is away;
        where the send fails past its retries, the job (stored) is left to the next sweep
        (:func:`~farfield.service.placement.lease.resend_planning_at_next_sweep`) and False returned."""
        try:
            send_planning(self.celery, job_id, phase, self.send_retry_policy)
            return True
        except BROKER_ERRORS as error:  # the job is stored: the sweep sends its planning
            log.warning("job %s: its planning was not sent (%s); the next sweep sends it", job_id, error)
            resend_planning_at_next_sweep(self.db, job_id)
            return False

    def send_admission(self, job_id: str) -> bool:
        """Send the admitting job's admission task, retrying while Redis is away; where the send fails
        past its retries, the job (stored) is left to the next sweep
        (:func:`~farfield.service.jobs.admitting.resend_admission_at_next_sweep`) and False returned."""
        try:
            send_admission(self.celery, job_id, self.send_retry_policy)
            return True
        except BROKER_ERRORS as error:  # the job is stored: the sweep sends its admission
            log.warning("job %s: its admission was not sent (%s); the next sweep sends it", job_id, error)
            resend_admission_at_next_sweep(self.db, job_id)
            return False


async def services(request: Request) -> Services:
    """The process's services.  ``async`` though it awaits nothing: FastAPI runs a plain function
    dependency in its thread pool, one more hop between the event loop and a thread (each waiting
    for the GIL) on every request, ``GET /v1/health`` included (issue 58, item 5)."""
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
    return request.app.state.services.authenticate(
        client_address(request.scope), request.headers.getlist("authorization")
    )


def client_address(scope) -> str:
    """The client's address of an ASGI ``scope`` (what failed authentication is counted by)."""
    client = scope.get("client")
    return str(client[0]) if client else "unknown"
