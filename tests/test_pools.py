"""GPU and CPU pools (issue 58, item 4: service/pools.py) on a real SQLite database, without a broker:
a CPU worker's switch drops the heavy queue while a GPU worker is live and takes it again once that
worker's heartbeat is past the lease.  The routing through real Celery workers (a worker declared a GPU
worker with ``FARFIELD_WORKER_KIND=gpu`` beside the CPU worker of ``farfield up``) is
tests/test_service_timing.py's (which shares that module's service)."""

from __future__ import annotations

from farfield.service.db import Database, WorkerRow, now
from farfield.service.jobs.leases import record_worker
from farfield.service.pools import HEAVY_QUEUE, LIGHT_QUEUE, QueueSwitch, live_kinds


def test_a_cpu_worker_takes_the_heavy_queue_again_once_the_gpu_worker_s_heartbeat_is_past_the_lease(tmp_path):
    db = Database(f"sqlite:///{tmp_path / 'pools.db'}")
    db.migrate()
    ran: list = []
    switch = QueueSwitch(lambda f: ran.append(f), ran.append, lambda q: ran.append(f"-{q}"))
    record_worker(db, "gpu0@h", 1, "NVIDIA H100", now(), queues=(HEAVY_QUEUE,))
    assert live_kinds(db, 30.0, "cpu0@h") == {"gpu"}
    assert switch.update(db, "cpu0@h", "cpu", 30.0) == (LIGHT_QUEUE,)
    ran.pop()()  # the consumer's thread runs the switch
    assert ran == [f"-{HEAVY_QUEUE}"] and switch.queues == (LIGHT_QUEUE,)
    with db.session() as s:  # the GPU worker's last heartbeat, 31 s ago: past the 30 s lease
        s.get(WorkerRow, "gpu0@h").heartbeat_at = now() - 31.0
    assert live_kinds(db, 30.0, "cpu0@h") == set()
    ran.clear()
    assert switch.update(db, "cpu0@h", "cpu", 30.0) == (LIGHT_QUEUE, HEAVY_QUEUE)
    switch.update(db, "cpu0@h", "cpu", 30.0)  # unchanged: nothing more scheduled
    assert len(ran) == 1
    ran.pop()()
    assert ran == [HEAVY_QUEUE] and switch.queues == (LIGHT_QUEUE, HEAVY_QUEUE)
    # A GPU worker that stopped (a warm shutdown records no queue) is not live, its heartbeat fresh or not.
    record_worker(db, "gpu0@h", 1, "NVIDIA H100", now(), queues=())
    assert live_kinds(db, 30.0, "cpu0@h") == set()
    db.dispose()
