"""Cell leases and worker heartbeats: a running cell is held by its worker only while that worker lives.

A claimed cell (:func:`farfield.service.jobs.cells.claim_cell`) holds a lease: a token naming the
attempt (``cells.lease_token``) and an expiry (``cells.lease_until``, ``FARFIELD_LEASE_S`` on).  The
worker that runs it renews the lease every ``FARFIELD_HEARTBEAT_S`` from a heartbeat thread in its
main process (:class:`Heartbeat`), which renews only the cells its pool processes are running right
now, and records the worker itself (``workers``: host, kind, renderer, last heartbeat) for
``GET /v1/workers``.  The heartbeat lives in the main process, not beside the bake, so a bake that
holds the GIL in a long numba or GL call does not lose its lease, while a node that is killed whole
(or stopped, or cut off from the database) stops renewing it.

The API's sweeper (:func:`farfield.service.jobs.cells.release_expired_leases`) queues again each running cell whose lease ran
out, whichever host held it, counting the attempt (failed at the last one; cancelled when its job
was), and sends it again at once.  Every write of an attempt names its token, compared in the SQL
``UPDATE``'s ``WHERE`` (:func:`~farfield.service.jobs.cells.end_cell`,
:func:`~farfield.service.jobs.cells.set_progress`): a result that comes back under a lost lease (a
node paused past its lease and resumed, a partition healed) changes nothing, and so is never
applied twice.  Clocks: expiries are written and compared by each host's own clock (epoch seconds),
so hosts must keep time (NTP) to well within the lease.
"""

from __future__ import annotations

import logging
import os
import socket
import subprocess
import sys
import threading
import uuid

from sqlalchemy import select, update

from farfield.service.db import CellRow, Database, JobRow, WorkerRow, now
from farfield.service.pools import QueueSwitch

log = logging.getLogger("farfield.leases")

RENDERER_PROBE_S = 60  # the renderer probe (a child process that opens an EGL context) gives up after this
FORK_WAIT_S = 10.0  # the longest a fork of the worker's main process waits for a heartbeat in flight


def new_token() -> str:
    """A fresh lease token (32 hex digits).

    >>> len(new_token())
    32
    """
    return uuid.uuid4().hex


def renew_leases(db: Database, worker: str, cell_ids: list[str], lease_s: float) -> int:
    """Push on the leases of ``cell_ids`` still running on ``worker``; how many were renewed.  A cell
    whose lease the sweeper took (queued again, or running elsewhere) is left alone."""
    if not cell_ids:
        return 0
    with db.session() as s:
        return s.execute(
            update(CellRow)
            .where(CellRow.id.in_(cell_ids), CellRow.state == "running", CellRow.worker == worker)
            .values(lease_until=now() + lease_s)
        ).rowcount


def lease_lost(db: Database, cell_id: str, token: str) -> bool:
    """Whether the attempt holding ``token`` no longer holds the cell (its lease expired and the cell
    was queued again, or it ended)."""
    with db.reading() as s:
        held = s.scalar(select(CellRow.lease_token).where(CellRow.id == cell_id, CellRow.state == "running"))
    return held != token


# --- the worker registry ------------------------------------------------------------------------


def probe_renderer(device: str | None) -> str | None:
    """GL_RENDERER of this machine's EGL (device ``device``), read in a child process (a context is
    never made in a worker's main process, whose pool processes fork from it); None if none opens."""
    code = "from farfield.core.render.context import renderer_info; print(renderer_info().renderer)"
    env = {**os.environ, **({"FARFIELD_EGL_DEVICE": device} if device else {})}
    try:
        out = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, timeout=RENDERER_PROBE_S, env=env
        )
    except (OSError, subprocess.SubprocessError):
        return None
    lines = out.stdout.strip().splitlines()
    return lines[-1][:500] if out.returncode == 0 and lines else None


def renderer_kind(renderer: str | None) -> str:
    """ "cpu" for a software renderer (Mesa llvmpipe or softpipe, SwiftShader), "gpu" for any other,
    "unknown" when no EGL context opened.

    >>> renderer_kind("llvmpipe (LLVM 15.0.6, 256 bits)"), renderer_kind("NVIDIA H100 80GB HBM3/PCIe/SSE2")
    ('cpu', 'gpu')
    """
    if not renderer:
        return "unknown"
    return "cpu" if any(s in renderer.lower() for s in ("llvmpipe", "softpipe", "swiftshader")) else "gpu"


def record_worker(
    db: Database,
    name: str,
    concurrency: int,
    renderer: str | None,
    started_at: float,
    kind: str | None = None,
    queues: tuple[str, ...] | None = None,
) -> None:
    """Insert or refresh the worker's row (its heartbeat); ``kind`` (``FARFIELD_WORKER_KIND``) instead of
    the renderer's, and the ``queues`` it consumes (:mod:`farfield.service.pools`)."""
    values = {
        "host": socket.gethostname(), "pid": os.getpid(), "kind": kind or renderer_kind(renderer), "renderer": renderer,
        "concurrency": concurrency, "started_at": started_at, "heartbeat_at": now(),
        "queues": ",".join(queues) if queues is not None else None,
    }  # fmt: skip
    with db.session() as s:
        if not s.execute(update(WorkerRow).where(WorkerRow.name == name).values(**values)).rowcount:
            s.add(WorkerRow(name=name, **values))


def worker_records(db: Database, tenant_id: str | None, lease_s: float) -> list[dict]:
    """The workers as ``GET /v1/workers`` shows them, newest heartbeat first: host, kind, renderer,
    last heartbeat and its age, whether it is alive (a heartbeat within the lease), and the cells it
    runs (job id and cell index; ``tenant_id`` given, only that tenant's jobs are named, the others
    counted in ``other_cells``)."""
    with db.session() as s:
        workers = list(s.scalars(select(WorkerRow).order_by(WorkerRow.heartbeat_at.desc(), WorkerRow.name)))
        running = s.execute(
            select(CellRow.worker, CellRow.job_id, CellRow.index, CellRow.progress, JobRow.tenant_id)
            .join(JobRow, CellRow.job_id == JobRow.id)
            .where(CellRow.state == "running", CellRow.worker.is_not(None))
            .order_by(CellRow.job_id, CellRow.index)
        ).all()
    clock = now()
    out = []
    for w in workers:
        mine = [r for r in running if r.worker == w.name]
        shown = [r for r in mine if tenant_id is None or r.tenant_id == tenant_id]
        out.append({
            "name": w.name, "host": w.host, "pid": w.pid, "kind": w.kind, "renderer": w.renderer,
            "concurrency": w.concurrency, "queues": None if w.queues is None else [q for q in w.queues.split(",") if q],
            "started_at": w.started_at, "heartbeat_at": w.heartbeat_at,
            "heartbeat_age_s": round(clock - w.heartbeat_at, 3), "alive": clock - w.heartbeat_at <= lease_s,
            "cells": [{"job_id": r.job_id, "index": r.index, "progress": r.progress} for r in shown],
            "other_cells": len(mine) - len(shown),
        })  # fmt: skip
    return out


class Heartbeat:
    """The heartbeat thread of a worker's main process: every ``every_s`` it renews the leases of the
    cells ``active`` (a function: the cell ids the pool runs now) returns and refreshes the worker's
    row; the first beat probes the renderer.  A failed beat is logged and the next one tries again
    (a lease that runs out meanwhile is the sweeper's).  ``kind``: the worker's kind
    (``FARFIELD_WORKER_KIND``) instead of its renderer's; ``switch``: its
    :class:`~farfield.service.pools.QueueSwitch`, asked after each beat which queues to consume."""

    def __init__(
        self,
        db: Database,
        name: str,
        concurrency: int,
        lease_s: float,
        every_s: float,
        active,
        kind: str | None = None,
        switch: QueueSwitch | None = None,
    ) -> None:
        self.db, self.name, self.concurrency = db, name, concurrency
        self.lease_s, self.every_s, self.active = lease_s, every_s, active
        self.kind, self.switch = kind, switch
        self.started_at, self.renderer = now(), None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="farfield-heartbeat", daemon=True)
        # The worker's main process forks its pool processes while this thread may be inside the
        # database driver (with the GIL released, holding the driver's or SQLite's own mutexes, which
        # a forked child would find held for ever): a fork waits for the beat in flight (at most
        # FORK_WAIT_S).  A pool process inherits this object, never its thread: its copy of the
        # engine's connections must not be closed there (they are the main process's).
        self._beating = threading.Lock()
        self._held = False
        os.register_at_fork(before=self._before_fork, after_in_parent=self._after_fork, after_in_child=self._in_child)

    def _before_fork(self) -> None:
        self._held = self._beating.acquire(timeout=FORK_WAIT_S)

    def _after_fork(self) -> None:
        if self._held:
            self._held = False
            self._beating.release()

    def _in_child(self) -> None:
        self._beating, self._held = threading.Lock(), False
        self.db.engine.dispose(close=False)

    def start(self) -> Heartbeat:
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop beating; a worker with a switch records that it consumes no queue any more, so that
        the others take its kind's queue at their next beat, not after its lease (service.pools)."""
        self._stop.set()
        self._thread.join(timeout=10)
        if self.switch is not None:
            try:
                with self._beating:
                    record_worker(self.db, self.name, self.concurrency, self.renderer, self.started_at, self.kind, ())
            except Exception:  # noqa: BLE001 - its lease runs out instead
                log.warning("worker %s: could not record its stop", self.name, exc_info=True)

    def beat(self) -> int:
        """One heartbeat: renew the active cells' leases and the worker's row; how many leases were renewed."""
        renewed = renew_leases(self.db, self.name, self.active(), self.lease_s)
        queues = self.switch.queues if self.switch is not None else None
        record_worker(self.db, self.name, self.concurrency, self.renderer, self.started_at, self.kind, queues)
        if self.switch is not None:
            self.switch.update(self.db, self.name, self.kind or renderer_kind(self.renderer), self.lease_s)
        return renewed

    def _run(self) -> None:
        probed = False
        while True:
            try:
                with self._beating:
                    self.beat()
            except Exception:  # noqa: BLE001 - the next beat tries again
                log.warning("worker %s: heartbeat failed", self.name, exc_info=True)
            if not probed:  # after the first beat (the probe takes a second or so): beat again with it
                probed, self.renderer = True, probe_renderer(os.environ.get("FARFIELD_EGL_DEVICE"))
                continue
            if self._stop.wait(self.every_s):
                return
