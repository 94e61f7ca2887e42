"""A worker's limits per cell: the time a cell may run and the memory its pool process may hold.

**Time** (``FARFIELD_CELL_TIME_LIMIT``): Celery's soft time limit raises
``SoftTimeLimitExceeded`` in the task, which :func:`farfield.service.jobs.runner.run_cell` records as a
failed cell (:func:`time_limit_message`); its hard limit, ``CELL_TIME_GRACE`` seconds later, kills
a pool process stuck where Python cannot raise (a long call into the GL driver or numba), and the
task's ``on_failure`` in the worker's main process fails the cell (:mod:`farfield.workers.tasks`).

**Memory** (``FARFIELD_CELL_MEMORY_MB``): :class:`MemoryGuard`, a daemon thread in each pool
process that reads the process's resident set (``/proc/self/statm``) every ``interval`` seconds
while a cell runs.  Past the limit it records the cell as failed (:func:`memory_limit_message`) and
kills its own process with SIGKILL, which frees the memory at once; Celery starts a new pool process,
and the cell's message, delivered again (``task_reject_on_worker_lost``), finds the cell failed and
does nothing.

Why not ``RLIMIT_AS``: llvmpipe, numba's LLVM and the allocator's per-thread arenas reserve far
more address space than they touch (measured on 2 cores, a 512-px layered cell and its evaluation:
1.2 GiB virtual for 0.3 GiB resident; arenas grow with the threads, so more on more cores), and a
cap that bites fails inside the driver with errors that name nothing (at 1100 MiB: "the
framebuffer is not complete (UNSUPPORTED)", an internal error that would be retried; at 900 MiB the
same cell passed).  Why not ``worker_max_memory_per_child``: Celery checks
it after a task ends, so it recycles a process that grew, but stops nothing while a cell grows.
A thread cannot preempt a C call that holds the GIL; a bake's layers are Python-level steps (record,
cull, cut), so the guard runs between them, and the check is also cheap enough to run there.

Neither failure is retried: a cell that took too long or too much memory would do so again.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import threading
from collections.abc import Callable, Iterator

log = logging.getLogger("farfield.cells")

_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def resident_bytes() -> int | None:
    """This process's resident set size in bytes, or None where ``/proc`` does not say.

    >>> resident_bytes() > 0
    True
    """
    try:
        with open("/proc/self/statm", "rb") as statm:
            return int(statm.read().split()[1]) * _PAGE
    except (OSError, IndexError, ValueError):
        return None


def time_limit_message(seconds: int) -> str:
    """What a cell that ran past its time limit records.

    >>> time_limit_message(1800)[:72]
    'the cell ran longer than FARFIELD_CELL_TIME_LIMIT (1800 s) and was stopp'
    """
    return (
        f"the cell ran longer than FARFIELD_CELL_TIME_LIMIT ({seconds} s) and was stopped; not retried, since a cell this slow "
        "would be as slow again: lower the resolution, use smaller or farther view cells, or raise the limit"
    )


def hard_time_limit_message(seconds: int) -> str:
    """What a cell records when its pool process was killed at the hard time limit."""
    return (
        f"the cell ran longer than FARFIELD_CELL_TIME_LIMIT and did not stop, so its worker process was killed at the hard limit "
        f"({seconds} s); not retried, since a cell this slow would be as slow again: lower the resolution, use smaller or farther "
        "view cells, or raise the limit"
    )


CELL, PLANNING = "cell", "planning"  # what a memory limit stopped
_REMEDY = {
    CELL: "since the cell would need as much again: lower the resolution, use smaller or farther view cells, or raise the limit",
    PLANNING: "since planning would need as much again: use a larger cpv_size or vdi_deg, a smaller view space, or raise the limit",
}


def memory_limit_message(resident: int, limit_mb: int, what: str = CELL) -> str:
    """What a cell (or a placement's planning) whose process grew past the memory limit records.

    >>> memory_limit_message(9 * 2**30, 8192)[:90]
    "the cell's worker process grew to 9216 MiB of memory, over FARFIELD_CELL_MEMORY_MB (8192 M"
    >>> memory_limit_message(9 * 2**30, 8192, PLANNING)[:40]
    "the planning's worker process grew to 92"
    """
    return (
        f"the {what}'s worker process grew to {resident // 2**20} MiB of memory, over FARFIELD_CELL_MEMORY_MB ({limit_mb} MiB), "
        f"and was stopped; not retried, {_REMEDY[what]}"
    )


class MemoryGuard:
    """A watchdog of this process's resident memory while a cell runs (see the module docstring).

    ``limit_mb`` MiB; ``interval`` seconds between reads.  :meth:`armed` arms it for one cell with
    the action that records the cell's failure (given the resident bytes); past the limit the
    action runs once and then ``kill`` (default: SIGKILL to this process) ends the process.
    The thread starts on the first :meth:`armed` in a process (never before a fork).

    The resident set includes what earlier cells left in the process (parsed scenes kept for the
    next cell, memory the allocator holds on to), so a cell is blamed only when it is the first
    one the process runs: past the limit in a process that ran others, the action is skipped and
    the process just ends; its cell is then queued again (the worker's main process releases it,
    counting the attempt) and runs on a fresh process, where it is blamed if it grows as far again.
    """

    def __init__(self, limit_mb: int, interval: float = 0.1, kill: Callable[[], None] | None = None) -> None:
        self.limit_mb, self.interval = int(limit_mb), float(interval)
        self.limit_bytes = self.limit_mb * 2**20
        self._kill = kill or (lambda: os.kill(os.getpid(), signal.SIGKILL))
        self._action: Callable[[int], None] | None = None
        self._lock = threading.Lock()
        self._pid: int | None = None
        self._cells = 0  # cells armed in this process (since its fork)
        self.fired = threading.Event()

    def _start(self) -> None:
        if self._pid != os.getpid():  # a forked copy has no thread: start its own
            self._pid, self._cells = os.getpid(), 0
            threading.Thread(target=self._watch, name="farfield-memory-guard", daemon=True).start()

    def _watch(self) -> None:
        while True:
            self.fired.wait(self.interval)
            if self.fired.is_set():
                return
            self.check()

    def check(self) -> bool:
        """Read the resident set once; past the limit while armed, run the action and kill. True if it fired."""
        with self._lock:
            action = self._action
        if action is None:
            return False
        resident = resident_bytes()
        if resident is None or resident <= self.limit_bytes:
            return False
        with self._lock:
            if self._action is not action or self.fired.is_set():
                return False
            self.fired.set()
            first = self._cells == 1
        if not first:  # earlier cells' memory counts too: try the cell again on a fresh process
            log.error("pool process %d: %d MiB resident, over FARFIELD_CELL_MEMORY_MB (%d MiB), after %d earlier cells: ending the process "
                      "so that the cell runs again on a fresh one", os.getpid(), resident // 2**20, self.limit_mb, self._cells - 1)  # fmt: skip
            self._kill()
            return True
        log.error("pool process %d: %d MiB resident, over FARFIELD_CELL_MEMORY_MB (%d MiB): failing the cell and ending the process",
                  os.getpid(), resident // 2**20, self.limit_mb)  # fmt: skip
        try:
            action(resident)
        finally:
            self._kill()
        return True

    @contextlib.contextmanager
    def armed(self, action: Callable[[int], None]) -> Iterator[None]:
        """Watch while the block runs; ``action(resident_bytes)`` records the cell's failure."""
        self._start()
        with self._lock:
            self._action = action
            self._cells += 1
        try:
            yield
        finally:
            with self._lock:
                self._action = None
