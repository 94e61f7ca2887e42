"""The dashboard: static HTML, JavaScript and CSS (no build step), served without a key.

``GET /`` is the page; its files are under ``/dashboard/``.  The page asks for an API key and
sends it as ``Authorization: Bearer <key>`` on every ``/v1`` call.
"""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter
from fastapi.responses import FileResponse

from farfield.core.errors import NotFoundError

DASHBOARD_DIR = Path(__file__).resolve().parent / "dashboard"
MEDIA_TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8", ".css": "text/css; charset=utf-8", ".svg": "image/svg+xml", ".png": "image/png"}
# The files change with the service: the browser asks again each time (cheap: they are small).
NO_CACHE = {"Cache-Control": "no-cache"}

router = APIRouter(tags=["dashboard"], include_in_schema=False)


def _file(name: str) -> FileResponse:
    path = (DASHBOARD_DIR / name).resolve()
    if not path.is_relative_to(DASHBOARD_DIR) or not path.is_file() or path.suffix not in MEDIA_TYPES:
        raise NotFoundError(f"no dashboard file {name!r}")
    return FileResponse(path, media_type=MEDIA_TYPES[path.suffix], headers=NO_CACHE)


@router.get("/", summary="The dashboard")
@router.get("/dashboard", summary="The dashboard")
@router.get("/dashboard/", summary="The dashboard")
def dashboard() -> FileResponse:
    return _file("index.html")


@router.get("/dashboard/{name:path}", summary="A dashboard file")
def dashboard_file(name: str) -> FileResponse:
    return _file(name)
