"""The FastAPI application: routes under ``/v1``, errors as JSON with their HTTP status (:mod:`farfield.api.errors`),
the dashboard, and its OpenAPI document (:mod:`farfield.api.openapi`).

``uvicorn farfield.api.app:app_from_env --factory`` serves it with the environment's settings (what
``farfield up`` does).
"""

from __future__ import annotations

from contextlib import asynccontextmanager

from celery import Celery
from fastapi import Depends, FastAPI

from farfield.api import (
    routes_dashboard,
    routes_jobs,
    routes_ops,
    routes_placement_algorithms,
    routes_results,
    routes_scenes,
    routes_techniques,
)
from farfield.api.deps import Services
from farfield.api.errors import install_error_handlers
from farfield.api.forms import one_value_per_field, require_closing_boundary
from farfield.api.limits import FORM_LIMITS, BodyLimit
from farfield.api.openapi import openapi_document
from farfield.api.security_headers import SecurityHeaders
from farfield.api.sweeper import LostCellSweeper
from farfield.core import __version__
from farfield.service.blobs import blob_store
from farfield.service.db import Database
from farfield.service.keys import ensure_admin_key
from farfield.service.settings import Settings
from farfield.workers.app import make_celery


def create_app(settings: Settings, celery: Celery | None = None, migrate: bool = True) -> FastAPI:
    """The API for ``settings`` (the database is migrated and the admin key stored on creation)."""
    db = Database(settings.database_url)
    if migrate:
        db.migrate()
    if settings.admin_key:
        ensure_admin_key(db, settings.admin_key)
    services = Services(settings, db, blob_store(settings), celery or make_celery(settings))

    @asynccontextmanager
    async def lifespan(_app: FastAPI):
        sweeper = LostCellSweeper(services)
        sweeper.start()
        yield
        sweeper.stop()

    app = FastAPI(
        title="farfield",
        version=__version__,
        description="Impostor baking service: scenes, placement jobs, impostor databases.",
        lifespan=lifespan,
        form_limits=FORM_LIMITS,  # parts and fields of a multipart request (api/limits.py)
        dependencies=[Depends(one_value_per_field)],  # a form field a route takes once is sent once (api/forms.py)
    )
    require_closing_boundary()  # a multipart body cut before its closing boundary is a 400 (api/forms.py)
    app.state.services = services

    install_error_handlers(app)
    app.add_middleware(BodyLimit, services=app.state.services)
    app.add_middleware(SecurityHeaders)  # outermost: on every response, refusals included

    for module in (
        routes_scenes,
        routes_jobs,
        routes_results,
        routes_techniques,
        routes_placement_algorithms,
        routes_ops,
        routes_dashboard,
    ):
        app.include_router(module.router)
    app.openapi = lambda: openapi_document(app)
    return app


def app_from_env() -> FastAPI:
    """The app for the environment's settings (uvicorn factory)."""
    settings = Settings.from_env()
    if settings.redis_url is None:
        raise SystemExit("REDIS_URL is not set: start the service with 'farfield up', which starts Redis and sets it")
    return create_app(settings)
