"""Parse an uploaded scene file in a child process and report its summary as JSON.

The API validates uploads by parsing them, but a 200 MB mesh parsed inside the API process would
raise its memory by gigabytes (and a loader crash would take it down).  :func:`check_scene_file`
runs ``python -m service.scene_check [--sides one|both] FILE EXTENSION NAME [LIMITS_JSON [ASSETS_ZIP]]`` instead: the child checks
the file against the scene limits (:mod:`farfield.core.exchange.limits`), prints the scene's summary (or the
error's type and message) as one JSON line and exits.

:class:`SceneCheckGate` bounds those children per API process: at most ``running`` parse at once
(``FARFIELD_SCENE_CHECKS``) and at most ``waiting`` more uploads wait for a slot
(``FARFIELD_SCENE_CHECK_QUEUE``); an upload past both is refused at once with a 429 and a short
``Retry-After`` (:class:`~farfield.core.errors.BusyError`) by the API's body middleware
(:class:`farfield.api.limits.BodyLimit`) before a byte of its body is read, so that a burst of
uploads neither runs dozens of parsers (each may take gigabytes) nor is spooled to disk, and holds
at most ``running + waiting`` of the request threads every other route, ``/v1/health``
included, needs (the settings keep that sum within
:data:`farfield.service.settings.MAX_SCENE_CHECK_PLACES`).
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict
from pathlib import Path

from farfield.core import errors
from farfield.core.errors import BusyError, FarfieldError, SceneLoadError
from farfield.core.exchange.limits import DEFAULT_LIMITS, SceneLimits
from farfield.core.sidedness import DEFAULT_SIDES

TIMEOUT_S = 600


def summarize(
    path: Path,
    extension: str,
    name: str,
    limits: SceneLimits = DEFAULT_LIMITS,
    assets: Path | None = None,
    sides: str = DEFAULT_SIDES,
) -> dict:
    """The summary the service stores for a scene file (run in the child); ``assets``: a zip of the
    files it refers to (:func:`farfield.core.exchange.archive.unpack_scene_archive`); ``sides``: the
    loader's option (:mod:`farfield.core.sidedness`)."""
    from farfield.core.exchange import load_scene_bytes
    from farfield.core.exchange.archive import read_assets_zip

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        files = read_assets_zip(assets.read_bytes()) if assets is not None else None
        scene = load_scene_bytes(path.read_bytes(), extension, name, files, limits=limits, sides=sides)
    return {
        "content_hash": scene.content_hash,
        "triangles": scene.triangle_count,
        "bounds": scene.bounds.tolist(),
        "objects": [obj.summary() for obj in scene.objects],
        "warnings": list(scene.warnings),
    }


def check_scene_file(
    path: Path,
    extension: str,
    name: str,
    limits: SceneLimits = DEFAULT_LIMITS,
    assets: Path | None = None,
    sides: str = DEFAULT_SIDES,
) -> dict:
    """Parse ``path`` (with the files of the ``assets`` zip, with the loader's ``sides`` option) in a
    child process; its summary, or the loader's error raised here."""
    try:
        done = subprocess.run(
            [sys.executable, "-m", "farfield.service.scene_check", "--sides", sides, str(path), extension, name, json.dumps(asdict(limits)), *([str(assets)] if assets else [])],
            capture_output=True, text=True, timeout=TIMEOUT_S,
        )  # fmt: skip
    except subprocess.TimeoutExpired:
        raise SceneLoadError(f"{name}: parsing took longer than {TIMEOUT_S} s") from None
    lines = done.stdout.strip().splitlines()
    try:
        result = json.loads(lines[-1]) if lines else None
    except ValueError:
        result = None
    if not isinstance(result, dict):
        tail = (done.stderr.strip().splitlines() or ["no output"])[-1]
        raise SceneLoadError(f"{name}: the scene could not be parsed ({tail})")
    if "error" in result:
        kind = getattr(errors, result["error"], None)
        cls = kind if isinstance(kind, type) and issubclass(kind, FarfieldError) else SceneLoadError
        raise cls(result["message"])
    return result


class SceneCheckGate:
    """At most ``running`` scene checks at once and ``waiting`` more admitted uploads (the module
    docstring); thread-safe, one per API process.

    >>> gate = SceneCheckGate(running=1, waiting=0)
    >>> with gate.admitted():
    ...     try:
    ...         with gate.admitted():
    ...             pass
    ...     except BusyError as error:
    ...         print(error)
    the service is checking 1 scene upload(s), its limit (FARFIELD_SCENE_CHECKS=1, FARFIELD_SCENE_CHECK_QUEUE=0); try again in a few seconds
    """

    def __init__(self, running: int, waiting: int) -> None:
        if running < 1 or waiting < 0:
            raise ValueError(f"a scene-check gate needs running >= 1 and waiting >= 0, got {running}, {waiting}")
        self.running, self.waiting = running, waiting
        self._slots = threading.BoundedSemaphore(running)
        self._lock = threading.Lock()
        self._admitted = 0

    @property
    def admitted_count(self) -> int:
        """Uploads admitted now (checking or waiting to)."""
        return self._admitted

    @contextmanager
    def admitted(self) -> Iterator[SceneCheckGate]:
        """Hold one of the ``running + waiting`` places for an upload, or raise :class:`BusyError`
        (the API takes it in :class:`farfield.api.limits.BodyLimit`, before the body is read)."""
        with self._lock:
            if self._admitted >= self.running + self.waiting:
                raise BusyError(
                    f"the service is checking {self._admitted} scene upload(s), its limit "
                    f"(FARFIELD_SCENE_CHECKS={self.running}, FARFIELD_SCENE_CHECK_QUEUE={self.waiting}); "
                    "try again in a few seconds"
                )
            self._admitted += 1
        try:
            yield self
        finally:
            with self._lock:
                self._admitted -= 1

    def check(self, *args, **kwargs) -> dict:
        """:func:`check_scene_file` once a running slot is free (call it inside :meth:`admitted`)."""
        with self._slots:
            return check_scene_file(*args, **kwargs)


def main(argv: list[str]) -> int:
    sides = DEFAULT_SIDES
    if argv[:1] == ["--sides"]:
        sides, argv = argv[1], argv[2:]
    path, extension, name = Path(argv[0]), argv[1], argv[2]
    limits = SceneLimits(**json.loads(argv[3])) if len(argv) > 3 else DEFAULT_LIMITS
    assets = Path(argv[4]) if len(argv) > 4 else None
    try:
        print(json.dumps(summarize(path, extension, name, limits, assets, sides)))
        return 0
    except FarfieldError as error:
        print(json.dumps({"error": type(error).__name__, "message": str(error)}))
        return 2
    except Exception as error:  # noqa: BLE001 - a loader bug on a hostile file is still bad input
        print(json.dumps({"error": "SceneLoadError", "message": f"{name}: {type(error).__name__}: {error}"}))
        return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
