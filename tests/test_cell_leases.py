"""Cell leases (issue 58, item 2) on a real SQLite database and blob store, without a broker: a claim
holds a lease that a heartbeat renews; the sweep's release of expired leases counts the attempt and
ends what must end; a late outcome under a lost lease is discarded.  The whole path (worker nodes
killed and paused, the API's sweeper) is tests/test_cluster.py."""

from __future__ import annotations

import time

import pytest
from test_failure_classes import MAX_ATTEMPTS, Stack

import farfield.service.jobs.runner as cell_runner
from farfield.service.db import JobRow, WorkerRow
from farfield.service.jobs.cells import (
    cancel_job,
    claim_cell,
    end_cell,
    finish_job_if_complete,
    release_expired_leases,
)
from farfield.service.jobs.leases import Heartbeat, renew_leases, worker_records
from farfield.service.jobs.runner import run_cell

LEASE = 30.0


@pytest.fixture
def stack(tmp_path):
    made = Stack(tmp_path)
    yield made
    made.db.dispose()


def expire(stack: Stack, lease_s: float = 0.05) -> dict:
    """Wait out a ``lease_s`` lease, then run the sweep's release."""
    time.sleep(lease_s * 2)
    return release_expired_leases(stack.db, stack.blobs, MAX_ATTEMPTS, lease_s)


def test_a_claim_holds_a_lease_that_renewal_keeps_and_expiry_takes(stack):
    claim = claim_cell(stack.db, stack.cell_id, MAX_ATTEMPTS, "node-a@host", lease_s=LEASE)
    token = claim.cell.lease_token
    assert len(token) == 32 and claim.cell.lease_until > time.time()
    assert release_expired_leases(stack.db, stack.blobs, MAX_ATTEMPTS, LEASE) == {}  # not expired
    assert renew_leases(stack.db, "node-a@host", [stack.cell_id], LEASE) == 1  # the heartbeat's renewal
    assert release_expired_leases(stack.db, stack.blobs, MAX_ATTEMPTS, LEASE) == {}
    assert renew_leases(stack.db, "node-b@host", [stack.cell_id], LEASE) == 0  # not another worker's to renew
    claim = claim_cell(stack.db, stack.cell_id, MAX_ATTEMPTS, "node-a@host", lease_s=0.05)  # its own redelivery
    assert claim.cell.attempts == 2 and claim.cell.lease_token != token
    assert expire(stack) == {stack.cell_id: "queued"}
    cell = stack.cell()
    assert cell.state == "queued" and cell.attempts == 2 and cell.lease_token is None
    assert cell.error == (
        "attempt 2 of 3 was lost (its lease expired: its worker stopped renewing it for 0.05 s); queued again"
    )
    assert cell.queued_at == 0.0  # sent again at the sweep's next look for lost messages


def test_a_live_lease_of_another_worker_is_not_taken_by_a_duplicate_delivery(stack):
    first = claim_cell(stack.db, stack.cell_id, MAX_ATTEMPTS, "node-a@host", lease_s=LEASE)
    duplicate = claim_cell(stack.db, stack.cell_id, MAX_ATTEMPTS, "node-b@host", lease_s=LEASE)
    assert duplicate.cell is None and stack.cell().attempts == 1 and stack.cell().lease_token == first.cell.lease_token


def test_a_late_outcome_under_a_lost_lease_is_discarded(stack):
    """A paused node's attempt comes back after the sweep gave its cell to another: its result
    changes nothing, and the other attempt's result is the cell's."""
    late = claim_cell(stack.db, stack.cell_id, MAX_ATTEMPTS, "node-a@host", lease_s=0.05).cell
    expire(stack)
    other = claim_cell(stack.db, stack.cell_id, MAX_ATTEMPTS, "node-b@host", lease_s=LEASE).cell
    assert other.attempts == 2
    # The same attempt number would not be enough on its own: the token is what the late write names.
    assert not end_cell(stack.db, stack.cell_id, 1, "done", result="impostors/late", token=late.lease_token)
    assert end_cell(stack.db, stack.cell_id, 2, "done", result="impostors/other", token=other.lease_token)
    assert not end_cell(stack.db, stack.cell_id, 2, "done", result="impostors/late", token=late.lease_token)
    cell = stack.cell()
    assert cell.state == "done" and cell.result_key == "impostors/other" and cell.worker == "node-b@host"


def test_an_attempt_whose_lease_expires_while_it_bakes_stops_and_records_nothing(stack, monkeypatch):
    """The sweep takes the lease while the bake runs (its node was paused): the attempt finishes its
    bake, and its outcome is discarded; the cell stays queued for its next attempt."""
    real_bake = cell_runner.bake_cell

    def bake_then_lose_the_lease(*args, **kwargs):
        impostor = real_bake(*args, **kwargs)
        expire(stack)
        return impostor

    monkeypatch.setattr(cell_runner, "bake_cell", bake_then_lose_the_lease)
    assert run_cell(stack.db, stack.blobs, stack.cell_id, MAX_ATTEMPTS, "node-a@host", lease_s=0.05) == "lost"
    cell = stack.cell()
    assert cell.state == "queued" and cell.attempts == 1 and cell.result_key is None and cell.progress == 0.0
    monkeypatch.setattr(cell_runner, "bake_cell", real_bake)
    assert run_cell(stack.db, stack.blobs, stack.cell_id, MAX_ATTEMPTS, "node-b@host", lease_s=LEASE) == "done"
    cell = stack.cell()
    assert cell.state == "done" and cell.attempts == 2 and cell.worker == "node-b@host"
    assert cell.stats["baked"] is False  # the late attempt's bundle, published under the same key, was found


def test_the_last_attempt_s_expiry_fails_the_cell_and_ends_the_job(stack):
    for attempt in range(1, MAX_ATTEMPTS + 1):
        assert (
            claim_cell(stack.db, stack.cell_id, MAX_ATTEMPTS, f"node-{attempt}@host", lease_s=0.05).cell.attempts
            == attempt
        )
        expected = "failed" if attempt == MAX_ATTEMPTS else "queued"
        assert expire(stack) == {stack.cell_id: expected}
    cell = stack.cell()
    assert cell.error.startswith("attempt 3 of 3 never reported back (its lease expired")
    assert stack.job_state() == "failed"


def test_cancelling_a_job_whose_worker_died_leaves_no_cell_running(stack):
    """The cancel cancels a running cell whose lease has run out; one whose lease runs out later is
    cancelled by the sweep; either way the job ends (finished) with nothing running."""
    with stack.db.session() as s:
        tenant_id = s.get(JobRow, stack.job_id).tenant_id
    claim_cell(stack.db, stack.cell_id, MAX_ATTEMPTS, "node-a@host", lease_s=LEASE)
    cancel_job(stack.db, stack.blobs, tenant_id, stack.job_id)
    assert stack.cell().state == "running"  # its lease is live: the worker may still see the cancel
    renew_leases(stack.db, "node-a@host", [stack.cell_id], 0.05)  # its last heartbeat: then the node died
    assert expire(stack) == {stack.cell_id: "cancelled"}
    with stack.db.session() as s:
        job = s.get(JobRow, stack.job_id)
    assert job.state == "cancelled" and job.finished_at is not None


def test_the_cancel_itself_ends_a_cell_whose_lease_already_ran_out(tmp_path):
    stack = Stack(tmp_path)
    with stack.db.session() as s:
        tenant_id = s.get(JobRow, stack.job_id).tenant_id
    claim_cell(stack.db, stack.cell_id, MAX_ATTEMPTS, "node-a@host", lease_s=0.01)
    time.sleep(0.05)
    job = cancel_job(stack.db, stack.blobs, tenant_id, stack.job_id)
    assert stack.cell().state == "cancelled" and job.finished_at is not None
    assert not finish_job_if_complete(stack.db, stack.blobs, stack.job_id)


def test_the_heartbeat_renews_the_active_cells_and_records_its_worker(stack):
    claim_cell(stack.db, stack.cell_id, MAX_ATTEMPTS, "node-a@host", lease_s=0.01)  # only the heartbeat holds it
    beat = Heartbeat(stack.db, "node-a@host", 2, LEASE, 0.1, lambda: [stack.cell_id]).start()
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:  # the first beat, then the renderer probe, then beats
            with stack.db.session() as s:
                row = s.get(WorkerRow, "node-a@host")
            if row is not None and row.renderer is not None:
                break
            time.sleep(0.1)
        assert release_expired_leases(stack.db, stack.blobs, MAX_ATTEMPTS, LEASE) == {}
    finally:
        beat.stop()
    assert stack.cell().state == "running" and stack.cell().lease_until > time.time() + LEASE - 5
    (record,) = worker_records(stack.db, None, LEASE)
    assert record["name"] == "node-a@host" and record["alive"] and record["concurrency"] == 2
    assert record["kind"] == "cpu" and "llvmpipe" in record["renderer"]  # this machine's Mesa EGL
    assert record["cells"] == [{"job_id": stack.job_id, "index": 0, "progress": 0.0}]
    assert worker_records(stack.db, "another-tenant", LEASE)[0]["other_cells"] == 1


def test_a_fork_of_the_worker_waits_for_the_heartbeat_in_flight(stack):
    """The worker's main process forks its pool processes while the heartbeat thread may be inside
    the database driver, holding mutexes a child would find held for ever (a pool process that hangs
    on its first query): a fork waits until the beat in flight has ended."""
    import os
    import threading

    inside, ended = threading.Event(), []

    def slow_active():  # called inside the beat, before its queries
        inside.set()
        time.sleep(0.5)
        ended.append(True)
        return []

    beat = Heartbeat(stack.db, "node-a@host", 1, LEASE, 60.0, slow_active).start()
    try:
        assert inside.wait(30)
        pid = os.fork()
        if pid == 0:  # the child: the beat had ended before the fork, and its lock is free here
            os._exit(0 if ended and beat._beating.acquire(blocking=False) else 1)
        _, status = os.waitpid(pid, 0)
        assert os.waitstatus_to_exitcode(status) == 0
    finally:
        beat.stop()
