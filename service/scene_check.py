"""Parse an uploaded scene file in a child process and report its summary as JSON.

The API validates uploads by parsing them, but a 200 MB mesh parsed inside the API process would
raise its memory by gigabytes (and a loader crash would take it down).  :func:`check_scene_file`
runs ``python -m service.scene_check [--sides one|both] FILE EXTENSION NAME [LIMITS_JSON [ASSETS_ZIP]]`` instead: the child checks
the file against the scene limits (:mod:`farfield.core.exchange.limits`), prints the scene's summary (or the
error's type and message) as one JSON line and exits.
"""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from dataclasses import asdict
from pathlib import Path

from farfield.core import errors
from farfield.core.errors import FarfieldError, SceneLoadError
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
