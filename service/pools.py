"""GPU and CPU pools: the queue a cell is sent to, and the queues a worker consumes (issue 58, item 4).

**Two queues by cost.**  The admission's full check plans each cell of a job of view cells
(:mod:`farfield.service.jobs.admitting`) and stores its texels (``cells.texels``: layers x texture
texels).  A cell that plans more than ``FARFIELD_HEAVY_TEXELS`` is *heavy* and goes to
:data:`HEAVY_QUEUE`, every other task (light cells, a placement job's cells, whose cost is not planned
before they are sent, admissions and placement plans) to :data:`LIGHT_QUEUE`, the one ``render``
queue of before.  The queue is chosen from the stored texels each time a cell is sent
(:func:`cell_queues`), so the sweeper's re-sends and a retry keep it.

**Workers subscribe by kind.**  A worker's kind is its GL renderer's (``gpu`` for anything but a
software renderer: :func:`farfield.service.jobs.leases.renderer_kind`), or ``FARFIELD_WORKER_KIND``.
Each kind serves its own queue, and the other kind's while no worker of that kind is live (a
heartbeat within the lease, :func:`live_kinds`): :func:`worker_queues`.  So heavy cells go to GPU
workers when any is live and to CPU workers otherwise; light ones go to CPU workers when any is live,
and a farm of GPU workers alone serves both; a job of heavy and light cells uses both kinds at once.
A GPU worker does not take light cells while a CPU worker is live, even when it is idle: set
``FARFIELD_HEAVY_TEXELS`` lower (0: every planned cell is heavy) to give the GPUs more.

Every worker starts consuming both queues (``farfield up`` and ``farfield worker`` pass ``-Q
render,render.heavy``); its heartbeat (:class:`farfield.service.jobs.leases.Heartbeat`) asks
:meth:`QueueSwitch.update` after each beat and, when the registry changed, the worker's consumer adds or
cancels a queue (Celery's ``add_task_queue`` / ``cancel_task_queue``, run in the consumer's own thread),
so a switch follows a worker's arrival within a heartbeat, its stop (a warm shutdown records that it
consumes nothing) within a heartbeat, and its death within the lease.  A message a worker had
already taken runs there.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from sqlalchemy import or_, select

from farfield.service.db import CellRow, Database, WorkerRow, now

LIGHT_QUEUE = "render"
HEAVY_QUEUE = "render.heavy"
QUEUES = (LIGHT_QUEUE, HEAVY_QUEUE)
OWN_QUEUE = {"cpu": LIGHT_QUEUE, "gpu": HEAVY_QUEUE}
OTHER_KIND = {"cpu": "gpu", "gpu": "cpu"}
CHUNK = 500  # cell ids per query (SQLite allows 32,766 parameters; PostgreSQL 65,535)


def cell_queue(texels: float | None, heavy_texels: int) -> str:
    """The queue of a cell that plans ``texels`` (None: not planned).

    >>> cell_queue(2e8, 100_000_000), cell_queue(1e8, 100_000_000), cell_queue(None, 0)
    ('render.heavy', 'render', 'render')
    """
    return HEAVY_QUEUE if texels is not None and texels > heavy_texels else LIGHT_QUEUE


def cell_queues(db: Database, cell_ids: list[str], heavy_texels: int) -> dict[str, str]:
    """Each cell's queue, from its stored texels (a cell not found: the light queue)."""
    found: dict[str, float | None] = {}
    with db.reading() as s:
        for start in range(0, len(cell_ids), CHUNK):
            chunk = cell_ids[start : start + CHUNK]
            for cell_id, texels in s.execute(select(CellRow.id, CellRow.texels).where(CellRow.id.in_(chunk))):
                found[cell_id] = texels
    return {cell_id: cell_queue(found.get(cell_id), heavy_texels) for cell_id in cell_ids}


def worker_queues(kind: str, live: set[str]) -> tuple[str, ...]:
    """The queues a worker of ``kind`` consumes while workers of the kinds ``live`` (the others) live:
    its own kind's, and the other kind's while none of that kind is live.  A worker whose kind is
    not known (no EGL context opened) serves as a CPU worker.

    >>> worker_queues("cpu", {"cpu"}), worker_queues("cpu", {"gpu"}), worker_queues("gpu", {"cpu", "gpu"})
    (('render', 'render.heavy'), ('render',), ('render.heavy',))
    >>> worker_queues("gpu", set()), worker_queues("unknown", {"gpu"})
    (('render', 'render.heavy'), ('render',))
    """
    kind = kind if kind in OWN_QUEUE else "cpu"
    wanted = {OWN_QUEUE[kind]} | (set() if OTHER_KIND[kind] in live else {OWN_QUEUE[OTHER_KIND[kind]]})
    return tuple(q for q in QUEUES if q in wanted)


def live_kinds(db: Database, lease_s: float, other_than: str) -> set[str]:
    """The kinds of the workers but ``other_than`` with a heartbeat within ``lease_s`` that consume a
    queue (one that stopped recorded none: :meth:`farfield.service.jobs.leases.Heartbeat.stop`)."""
    with db.reading() as s:
        return set(
            s.scalars(
                select(WorkerRow.kind)
                .where(
                    WorkerRow.name != other_than,
                    WorkerRow.heartbeat_at >= now() - lease_s,
                    or_(WorkerRow.queues.is_(None), WorkerRow.queues != ""),
                )
                .distinct()
            )
        )


def pool_egl_device(env, index: int) -> int | None:
    """The EGL device of a worker's pool process number ``index``: one cell per device at a time.
    ``FARFIELD_EGL_DEVICES`` (``0,1,2,3``: ``farfield worker`` sets it to every GPU, its concurrency
    one process per GPU) gives pool process *i* device *i* (round robin past them);
    ``FARFIELD_EGL_DEVICE`` (``farfield up`` pins each worker of one process to its GPU) one device
    to all; neither, EGL's default (None).

    >>> pool_egl_device({"FARFIELD_EGL_DEVICES": "0,1,2"}, 4), pool_egl_device({"FARFIELD_EGL_DEVICE": "3"}, 1)
    (1, 3)
    >>> pool_egl_device({}, 0) is None
    True
    """
    devices = [int(d) for d in (env.get("FARFIELD_EGL_DEVICES") or "").split(",") if d.strip()]
    if devices:
        return devices[index % len(devices)]
    return int(env["FARFIELD_EGL_DEVICE"]) if env.get("FARFIELD_EGL_DEVICE") else None


class QueueSwitch:
    """A worker's queues, switched by its heartbeat (module docstring).  ``schedule`` runs a function
    in the worker's consumer thread (Celery's ``Consumer.call_soon``); ``add`` and ``cancel`` start and
    stop consuming a queue there (``Consumer.add_task_queue``, ``cancel_task_queue``).  :attr:`queues`
    is what the consumer consumes now (what ``GET /v1/workers`` shows)."""

    def __init__(
        self,
        schedule: Callable[[Callable[[], None]], object],
        add: Callable[[str], object],
        cancel: Callable[[str], object],
        queues: tuple[str, ...] = QUEUES,
    ) -> None:
        self.schedule, self.add, self.cancel = schedule, add, cancel
        self.queues = self.wanted = tuple(queues)
        self._lock = threading.Lock()

    def update(self, db: Database, name: str, kind: str, lease_s: float) -> tuple[str, ...]:
        """Ask for the queues a worker ``name`` of ``kind`` should consume now; returns them."""
        if kind == "unknown":  # its renderer is not known (not probed yet, or no EGL context opens): as it is
            return self.wanted
        wanted = worker_queues(kind, live_kinds(db, lease_s, name))
        if wanted != self.wanted:
            self.wanted = wanted
            self.schedule(self._switch)
        return wanted

    def _switch(self) -> None:
        """In the consumer's thread: consume :attr:`wanted` (the latest asked for, whichever of several
        scheduled switches runs first), the new queues added before the old ones are cancelled."""
        with self._lock:
            wanted, consumed = self.wanted, self.queues
            for queue in wanted:
                if queue not in consumed:
                    self.add(queue)
            for queue in consumed:
                if queue not in wanted:
                    self.cancel(queue)
            self.queues = wanted
