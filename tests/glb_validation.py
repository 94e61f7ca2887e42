"""The Khronos glTF validator (npm ``gltf-validator``, pinned in ``tests/js/package.json``) on
every GLB a test writes: per-file reports, and the watch conftest keeps over pytest's temporary
directories.

:class:`GltfValidator` is one long-lived node process (``tests/js/validate.js``) that validates
batches of files sent as JSON lines, so the node start and the validator's load (~0.4 s) are paid
once per session.  :class:`GlbWatch` finds the ``.glb`` files that are new or changed under
pytest's base temporary directory after each test: the test's own ``tmp_path`` (scanned once,
then closed) and every directory a broader fixture made with ``tmp_path_factory`` (a service's
home, where its workers write bundles), rescanned after each test at the cost of one ``stat`` per
directory (a directory whose modification time is unchanged keeps its cached listing).  Hidden
names are skipped: farfield writes a bundle or a blob under a hidden name and renames it into
place, so a half-written file is never read.
"""

from __future__ import annotations

import json
import os
import subprocess
import time
from pathlib import Path

from threejs import JS_DIR, VALIDATOR_MODULE, VALIDATOR_SKIP_REASON, node

_SETTLE_NS = 100_000_000  # 0.1 s, well above the coarse clock's tick


class GltfValidator:
    """The pinned Khronos glTF validator in one long-lived node process.

    :meth:`validate` sends a batch of paths and returns one report per path: ``path``,
    ``errors``, ``warnings``, ``infos``, ``hints`` (counts) and ``messages`` (each ``code``,
    ``severity`` 0 error .. 3 hint, ``message``, ``pointer``), or ``path`` and ``failed`` (the
    validator refused the bytes, or the file could not be read).
    """

    def __init__(self):
        executable = node()
        if executable is None or not VALIDATOR_MODULE.is_file():
            raise RuntimeError(VALIDATOR_SKIP_REASON)
        self.process = subprocess.Popen(
            [executable, str(JS_DIR / "validate.js")], cwd=JS_DIR, text=True,
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        )  # fmt: skip
        self.version = json.loads(self._line())["version"]

    def _line(self) -> str:
        line = self.process.stdout.readline()
        if not line:
            self.process.wait()
            raise RuntimeError(
                f"the glTF validator stopped (exit {self.process.returncode}): {self.process.stderr.read()[-2000:]}"
            )
        return line

    def validate(self, paths) -> list[dict]:
        """One report per path of ``paths``, in order."""
        paths = [str(Path(p).resolve()) for p in paths]
        if not paths:
            return []
        self.process.stdin.write(json.dumps({"paths": paths}) + "\n")
        self.process.stdin.flush()
        return json.loads(self._line())["results"]

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.stdin.close()
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()


def ktx2_gaps(report: dict) -> list[dict]:
    """The warnings that are the validator not knowing ``KHR_texture_basisu`` (2.0.0-dev.3.10): an
    image of mimeType ``image/ktx2`` is "not in the list" and its bytes "not recognized" (each such
    image also draws an UNUSED_OBJECT info and the extension an UNSUPPORTED_EXTENSION info)."""
    ktx2 = {
        m["pointer"].rsplit("/", 1)[0]
        for m in report.get("messages", [])
        if m["code"] == "VALUE_NOT_IN_LIST" and "'image/ktx2'" in m["message"]
    }
    return [
        m
        for m in report.get("messages", [])
        if m["code"] in ("VALUE_NOT_IN_LIST", "IMAGE_UNRECOGNIZED_FORMAT")
        and m.get("pointer", "").removesuffix("/mimeType") in ktx2
    ]


def problems(report: dict) -> list[str]:
    """The errors and warnings of one validator report, one readable line each (empty: clean);
    :func:`ktx2_gaps` are not problems."""
    if "failed" in report:
        return [f"validator refused the file: {report['failed']}"]
    gaps = ktx2_gaps(report)
    lines = [
        f"{'error' if m['severity'] == 0 else 'warning'} {m['code']} at {m.get('pointer') or '/'}: {m['message']}"
        for m in report["messages"]
        if m["severity"] <= 1 and m not in gaps
    ]
    unlisted = report["errors"] + report["warnings"] - len(gaps) - len(lines)
    return lines + ([f"... and {unlisted} more errors and warnings"] if unlisted > 0 else [])


class GlbWatch:
    """New or changed ``.glb`` files under ``base`` (pytest's base temporary directory), validated
    in one batch per call of :meth:`check`; the validator starts at the first file."""

    def __init__(self, base: Path):
        self.base = str(base)
        self.validator: GltfValidator | None = None
        self.closed: set[str] = set()  # top-level folders no test writes to any more
        self.listings: dict[
            str, tuple[int, tuple[str, ...], tuple[str, ...]]
        ] = {}  # folder -> (mtime_ns, folders, GLBs)
        self.seen: dict[str, tuple[int, int]] = {}  # GLB -> (size, mtime_ns) when validated
        self.files_checked = 0
        self.flagged: set[str] = set()  # files found with errors or warnings, exempt tests' included
        self.seconds = 0.0  # spent in check(): scanning and validating

    def _walk(self, folder: str, out: list[str]) -> None:
        try:
            mtime = os.stat(folder).st_mtime_ns
        except FileNotFoundError:
            self.listings.pop(folder, None)
            return
        listing = self.listings.get(folder)
        if listing is None or listing[0] != mtime:
            folders, glbs = [], []
            try:
                with os.scandir(folder) as entries:
                    for entry in entries:
                        if entry.name.startswith("."):
                            continue  # a file or bundle still being written under its temporary name
                        if entry.is_dir(follow_symlinks=False):
                            folders.append(entry.path)
                        elif entry.name.lower().endswith(".glb") and entry.is_file(follow_symlinks=False):
                            glbs.append(entry.path)
            except (FileNotFoundError, NotADirectoryError, PermissionError):
                return
            # File times come from the kernel's coarse clock (a few ms): a folder changed this
            # recently may change again without a new time, so its listing is not trusted yet.
            settled = time.time_ns() - mtime > _SETTLE_NS
            listing = (mtime if settled else -1, tuple(folders), tuple(glbs))
            self.listings[folder] = listing
        out.extend(listing[2])
        for sub in listing[1]:
            if sub not in self.closed:
                self._walk(sub, out)

    def check(self, finished=()) -> dict[str, list[str]]:
        """Validate every GLB that is new or changed since the last call; ``finished``: top-level
        folders (a test's ``tmp_path``) that no one writes to after this call.  Returns
        ``{path: problems}`` for the files with errors or warnings (:func:`problems`)."""
        start = time.perf_counter()
        try:
            return self._check(finished)
        finally:
            self.seconds += time.perf_counter() - start

    def _check(self, finished) -> dict[str, list[str]]:
        found: list[str] = []
        self._walk(self.base, found)
        fresh, stamps = [], {}
        for path in found:
            try:
                stat = os.stat(path)
            except FileNotFoundError:
                continue
            stamp = (stat.st_size, stat.st_mtime_ns)
            if self.seen.get(path) != stamp:
                fresh.append(path)
                stamps[path] = stamp
        for folder in finished:
            folder = str(folder)
            self.closed.add(folder)
            for key in [k for k in self.listings if k == folder or k.startswith(folder + os.sep)]:
                del self.listings[key]
        if not fresh:
            return {}
        bad = {}
        for path, report in zip(fresh, self.started().validate(fresh), strict=True):
            self.seen[path] = stamps[path]
            self.files_checked += 1
            found_problems = problems(report)
            if found_problems and os.path.exists(path):  # a file removed meanwhile is no one's concern
                bad[path] = found_problems
                self.flagged.add(path)
        return bad

    def started(self) -> GltfValidator:
        """The session's validator process, started at the first call."""
        if self.validator is None:
            self.validator = GltfValidator()
        return self.validator

    def close(self) -> None:
        if self.validator is not None:
            self.validator.close()
