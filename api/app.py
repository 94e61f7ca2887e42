"""The FastAPI application: routes under ``/v1``, errors as JSON with their HTTP status, the dashboard.

``uvicorn farfield.api.app:app_from_env --factory`` serves it with the environment's settings (what
``farfield up`` does).
"""

from __future__ import annotations

import json
import logging
import math
from contextlib import asynccontextmanager

from celery import Celery
from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse

from farfield.core import __version__
from farfield.core.errors import ErrorKind, FarfieldError
from farfield.service.blobs import blob_store
from farfield.service.db import Database
from farfield.service.keys import ensure_admin_key
from farfield.service.settings import Settings
from farfield.workers.app import make_celery

from farfield.api import routes_dashboard, routes_jobs, routes_ops, routes_results, routes_scenes, routes_techniques
from farfield.api.deps import Services
from farfield.api.limits import BodyLimit
from farfield.api.sweeper import LostCellSweeper


def _shown(value) -> str | None:
    """A short, JSON-safe rendering of a rejected input value, or None when it is not worth showing."""
    if isinstance(value, float) and not math.isfinite(value):
        return "NaN" if math.isnan(value) else ("Infinity" if value > 0 else "-Infinity")
    if value is None or isinstance(value, (bool, int, float)):
        return json.dumps(value)
    if isinstance(value, str):
        return json.dumps(value if len(value) <= 60 else value[:57] + "...")
    return None


def validation_detail(errors) -> str:
    """One line per problem of a request's validation, ``field: message, got value``; the input is
    never echoed as JSON (a NaN or an infinity in it made FastAPI's own 422 body unencodable: 500).

    >>> validation_detail([{"loc": ("body", "resolution"), "msg": "Input should be a valid integer", "input": float("nan")}])
    'resolution: Input should be a valid integer, got NaN'
    """
    lines = []
    for problem in errors:
        where = ".".join(str(part) for part in problem.get("loc", ()) if part != "body")
        shown = _shown(problem.get("input"))
        lines.append(f"{where + ': ' if where else ''}{problem.get('msg', 'invalid')}{', got ' + shown if shown else ''}")
    return "; ".join(lines)


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

    app = FastAPI(title="farfield", version=__version__, description="Impostor baking service: scenes, placement jobs, impostor databases.", lifespan=lifespan)
    app.state.services = services

    @app.exception_handler(FarfieldError)
    async def farfield_error(_request: Request, error: FarfieldError) -> JSONResponse:
        if error.kind is ErrorKind.INTERNAL:  # a bug (HTTP 500): keep its traceback
            logging.getLogger("farfield.api").error("internal error: %s", error, exc_info=error)
        headers = {"WWW-Authenticate": "Bearer"} if error.kind is ErrorKind.UNAUTHORIZED else None
        return JSONResponse({"detail": str(error), "error": type(error).__name__}, status_code=error.kind.http_status, headers=headers)

    @app.exception_handler(RequestValidationError)
    async def validation_error(_request: Request, error: RequestValidationError) -> JSONResponse:
        return JSONResponse({"detail": validation_detail(error.errors()), "error": "ValidationError"}, status_code=422)

    app.add_middleware(BodyLimit, services=app.state.services)

    for module in (routes_scenes, routes_jobs, routes_results, routes_techniques, routes_ops, routes_dashboard):
        app.include_router(module.router)
    return app


def app_from_env() -> FastAPI:
    """The app for the environment's settings (uvicorn factory)."""
    settings = Settings.from_env()
    if settings.redis_url is None:
        raise SystemExit("REDIS_URL is not set: start the service with 'farfield up', which starts Redis and sets it")
    return create_app(settings)
