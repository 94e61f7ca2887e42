"""The FastAPI application: routes under ``/v1``, errors as JSON with their HTTP status, the dashboard.

``uvicorn api.app:app_from_env --factory`` serves it with the environment's settings (what
``farfield up`` does).
"""

from __future__ import annotations

from celery import Celery
from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse

from core import __version__
from core.errors import ErrorKind, FarfieldError
from service.blobs import blob_store
from service.db import Database
from service.keys import ensure_admin_key
from service.settings import Settings
from workers.app import make_celery

from api import routes_dashboard, routes_jobs, routes_ops, routes_results, routes_scenes
from api.deps import Services


def create_app(settings: Settings, celery: Celery | None = None, migrate: bool = True) -> FastAPI:
    """The API for ``settings`` (the database is migrated and the admin key stored on creation)."""
    db = Database(settings.database_url)
    if migrate:
        db.migrate()
    if settings.admin_key:
        ensure_admin_key(db, settings.admin_key)
    app = FastAPI(title="farfield", version=__version__, description="Impostor baking service: scenes, placement jobs, impostor databases.")
    app.state.services = Services(settings, db, blob_store(settings), celery or make_celery(settings))

    @app.exception_handler(FarfieldError)
    async def farfield_error(_request: Request, error: FarfieldError) -> JSONResponse:
        headers = {"WWW-Authenticate": "Bearer"} if error.kind is ErrorKind.UNAUTHORIZED else None
        return JSONResponse({"detail": str(error), "error": type(error).__name__}, status_code=error.kind.http_status, headers=headers)

    @app.middleware("http")
    async def upload_limit(request: Request, call_next):
        # Before the multipart body is read: refuse a declared size over the limit, and a request
        # without a key, so neither is spooled to disk first.
        if request.method == "POST" and request.url.path == "/v1/scenes":
            length = request.headers.get("content-length")
            limit = settings.max_upload_bytes + 64 * 1024  # room for the multipart envelope
            if length and length.isdigit() and int(length) > limit:
                return JSONResponse({"detail": f"upload of {int(length)} bytes is larger than the limit of {settings.max_upload_bytes // 2**20} MiB", "error": "UploadTooLargeError"}, status_code=413)
            if not request.headers.get("authorization"):
                return JSONResponse({"detail": "missing API key: send 'Authorization: Bearer <key>'", "error": "AuthError"}, status_code=401, headers={"WWW-Authenticate": "Bearer"})
        return await call_next(request)

    for module in (routes_scenes, routes_jobs, routes_results, routes_ops, routes_dashboard):
        app.include_router(module.router)
    return app


def app_from_env() -> FastAPI:
    """The app for the environment's settings (uvicorn factory)."""
    settings = Settings.from_env()
    if settings.redis_url is None:
        raise SystemExit("REDIS_URL is not set: start the service with 'farfield up', which starts Redis and sets it")
    return create_app(settings)
