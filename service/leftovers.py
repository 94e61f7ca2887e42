"""What a killed ``farfield up`` leaves, found and reaped by the next one on the same home (issue 59,
item 10).

``farfield up`` starts its children (redis-server, the API, the workers) in their own sessions, so a
SIGKILL of the supervisor leaves them running: the next ``farfield up`` found the port of the old
API taken, two sets of workers on one queue, and the old redis-server holding the append-only file.
Killed pool processes also left ``farfield-cell-*`` and ``pymp-*`` folders in the temporary directory.

- :class:`HomeLock`: one ``farfield up`` per home (``$FARFIELD_HOME/farfield-up.lock``, an
  ``flock`` the kernel releases when its process dies, however it dies); a second is refused with
  the first's pid.
- :func:`record_child` writes each child's pid and start time under ``$FARFIELD_HOME/run``;
  :func:`reap` (run once the lock is held, so their supervisor is gone) kills the recorded
  processes still alive with that same start time (a pid the system gave to an unrelated process
  since is left alone) with their process groups (a worker's pool processes included), and empties
  ``$FARFIELD_HOME/tmp``, the temporary directory the children are given (``TMPDIR``).
"""

from __future__ import annotations

import fcntl
import os
import shutil
import signal
import time
from pathlib import Path

import psutil

from farfield.core.errors import ServiceConfigError

REAP_GRACE_S = 5.0


def run_dir(home: Path) -> Path:
    return Path(home) / "run"


def temp_dir(home: Path) -> Path:
    """The temporary directory of a home's children (their ``TMPDIR``), emptied by :func:`reap`."""
    return Path(home) / "tmp"


class HomeLock:
    """The lock of one ``farfield up`` on ``home`` (module docstring)."""

    def __init__(self, home: Path) -> None:
        self.path = Path(home) / "farfield-up.lock"
        self._file = None

    def acquire(self) -> HomeLock:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        handle = open(self.path, "a+")  # noqa: SIM115 - held open while the lock is held
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.seek(0)
            holder = handle.read().strip() or "unknown"
            handle.close()
            raise ServiceConfigError(
                f"another farfield up (pid {holder}) is running on {self.path.parent}; stop it, or give this one "
                "its own FARFIELD_HOME"
            ) from None
        handle.seek(0)
        handle.truncate()
        handle.write(f"{os.getpid()}\n")
        handle.flush()
        self._file = handle
        return self

    def release(self) -> None:
        if self._file is not None:
            fcntl.flock(self._file, fcntl.LOCK_UN)
            self._file.close()
            self._file = None


def record_child(home: Path, role: str, pid: int) -> None:
    """Remember child ``pid`` (its ``role``: ``redis``, ``api``, ``worker0``, ...) and its start time."""
    directory = run_dir(home)
    directory.mkdir(parents=True, exist_ok=True)
    try:
        started = psutil.Process(pid).create_time()
    except psutil.Error:
        return  # already gone: nothing to reap later
    (directory / f"{role}.pid").write_text(f"{pid} {started!r}\n")


def forget_children(home: Path) -> None:
    """Drop the records (a clean stop: every child was stopped)."""
    shutil.rmtree(run_dir(home), ignore_errors=True)


def _recorded(home: Path) -> list[tuple[str, psutil.Process]]:
    """The recorded children still alive as the very processes recorded (same pid and start time)."""
    found = []
    for path in sorted(run_dir(home).glob("*.pid")):
        try:
            pid_text, started_text = path.read_text().split()
            process = psutil.Process(int(pid_text))
            if abs(process.create_time() - float(started_text)) < 0.01 and process.status() != psutil.STATUS_ZOMBIE:
                found.append((path.stem, process))
        except (ValueError, psutil.Error, OSError):
            continue
    return found


def reap(home: Path) -> tuple[list[str], list[str]]:
    """Kill what an earlier ``farfield up`` on ``home`` left running and empty its temporary
    directory (call with the :class:`HomeLock` held): (one line per thing reaped, the roles of the
    children stopped, e.g. ``worker0``, whose cells the caller releases)."""
    done, roles = [], []
    alive = _recorded(home)
    for _role, process in alive:
        try:
            os.killpg(process.pid, signal.SIGTERM)  # its own session: the group is it and its children
        except (ProcessLookupError, PermissionError):
            try:
                process.terminate()
            except psutil.Error:
                pass
    deadline = time.monotonic() + REAP_GRACE_S
    for role, process in alive:
        try:
            process.wait(max(0.0, deadline - time.monotonic()))
        except (psutil.TimeoutExpired, psutil.Error):
            pass
        try:  # the whole group, also where its leader ended within the grace and its children did not
            os.killpg(process.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        done.append(f"{role} (pid {process.pid}) left running by an earlier farfield up: stopped")
        roles.append(role)
    forget_children(home)
    temporary = temp_dir(home)
    if temporary.exists():
        left = sorted(p.name for p in temporary.iterdir())
        shutil.rmtree(temporary, ignore_errors=True)
        if left:
            done.append(f"{len(left)} temporary folder(s) left in {temporary} removed")
    temporary.mkdir(parents=True, exist_ok=True)
    return done, roles
