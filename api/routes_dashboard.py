"""The dashboard: static HTML, JavaScript and CSS (no build step), served without a key.

``GET /`` is the page; its files are under ``/dashboard/``.  The page asks for an API key and
sends it as ``Authorization: Bearer <key>`` on every ``/v1`` call.  Its JavaScript is ES modules
(``text/javascript``, which a module script needs), loaded by the pages' one ``<script
type="module">`` each: ``app.js`` (the dashboard: routing, polling, the controls) imports one
module per part of the page (``scenes.js``, ``job-form.js``, ``jobs.js``, ``workers.js``, ``job.js``,
``placement.js``, ``key.js``) and the shared ``api.js`` (the key and the request helpers, which
the 3D view's ``viewer.js`` imports too), ``state.js``, ``dom.js`` and ``format.js``.

The 3D view (``/dashboard/viewer.html``) imports three.js from ``/dashboard/three/``: the files of
the npm package ``three`` (its ``build/`` and ``examples/jsm/`` folders), from
``$FARFIELD_THREE_DIR`` or else the checkout's pinned install in ``tests/js/node_modules/three``
(``scripts/install-js``, which ``farfield up`` runs).  Without it the view says how to install it.
"""

from __future__ import annotations

import os
from pathlib import Path

from fastapi import APIRouter
from fastapi.responses import FileResponse

from farfield.core.errors import NotFoundError

DASHBOARD_DIR = Path(__file__).resolve().parent / "dashboard"
PINNED_THREE = Path(__file__).resolve().parent.parent / "tests" / "js" / "node_modules" / "three"
THREE_FOLDERS = ("build", "examples/jsm")  # what the view imports; the package's other files are not served
MEDIA_TYPES = {
    ".html": "text/html; charset=utf-8",
    ".js": "text/javascript; charset=utf-8",
    ".css": "text/css; charset=utf-8",
    ".svg": "image/svg+xml",
    ".png": "image/png",
}
# The files change with the service: the browser asks again each time (cheap: they are small).
NO_CACHE = {"Cache-Control": "no-cache"}

router = APIRouter(tags=["dashboard"], include_in_schema=False)


def _file(name: str) -> FileResponse:
    if "\0" in name:  # resolve() raises on a NUL: not a file name
        raise NotFoundError(f"no dashboard file {name!r}")
    path = (DASHBOARD_DIR / name).resolve()
    if not path.is_relative_to(DASHBOARD_DIR) or not path.is_file() or path.suffix not in MEDIA_TYPES:
        raise NotFoundError(f"no dashboard file {name!r}")
    return FileResponse(path, media_type=MEDIA_TYPES[path.suffix], headers=NO_CACHE)


@router.get("/", summary="The dashboard")
@router.get("/dashboard", summary="The dashboard")
@router.get("/dashboard/", summary="The dashboard")
def dashboard() -> FileResponse:
    return _file("index.html")


def three_dir() -> Path:
    """Where three.js is installed: ``$FARFIELD_THREE_DIR``, else the checkout's pinned install."""
    return Path(os.environ.get("FARFIELD_THREE_DIR") or PINNED_THREE).resolve()


@router.get("/dashboard/three/{name:path}", summary="A three.js module for the 3D view")
def three_file(name: str) -> FileResponse:
    root = three_dir()
    if "\0" in name:
        raise NotFoundError(f"no three.js file {name!r}")
    path = (root / name).resolve()
    inside = any(path.is_relative_to(root / folder) for folder in THREE_FOLDERS)
    if not inside or not path.is_file() or path.suffix != ".js":
        hint = (
            ""
            if (root / "build" / "three.module.js").is_file()
            else f" (three.js is not installed at {root}: run scripts/install-js or set FARFIELD_THREE_DIR)"
        )
        raise NotFoundError(f"no three.js file {name!r}{hint}")
    # the package is pinned: its files change only with the lock file, so the browser may keep them
    return FileResponse(path, media_type=MEDIA_TYPES[".js"], headers={"Cache-Control": "max-age=3600"})


@router.get("/dashboard/{name:path}", summary="A dashboard file")
def dashboard_file(name: str) -> FileResponse:
    return _file(name)
