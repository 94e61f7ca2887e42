"""A killed ``farfield up`` leaves nothing the next one trips on (issue 59, item 10): its children
(they run in their own sessions, so a SIGKILL of the supervisor left the API, the workers and
redis-server running) and its temporary folders are reaped by the next ``farfield up`` on the same
home, and two ``farfield up`` never share a home.  Real processes: ``farfield up`` itself."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import psutil
import pytest
from service_harness import ROOT, start_service


def alive(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


@pytest.mark.service
def test_the_next_farfield_up_reaps_what_a_killed_one_left(tmp_path):
    home = tmp_path / "home"
    first = start_service(home)
    children = [first.api_pid(), first.redis_pid(), *first.worker_mains()]
    pool = first.worker_pool_children()
    stale = home / "tmp" / "farfield-cell-stale"  # what a killed pool process leaves
    stale.mkdir(parents=True)
    os.kill(first.process.pid, signal.SIGKILL)
    first.process.wait()
    time.sleep(1.0)
    assert all(alive(pid) for pid in children)  # orphans: without reaping they would run on

    second = start_service(home)
    try:
        deadline = time.monotonic() + 10
        while any(alive(pid) for pid in children + pool) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not any(alive(pid) for pid in children + pool)
        assert not stale.exists()
        with second.client() as client:
            assert client.get("/v1/health").json()["status"] == "ok"
        # A third on the same home is refused with one line, and leaves the second alone.
        third = subprocess.run(
            [sys.executable, "-m", "farfield.cli.main", "up"],
            cwd=ROOT, env=second.env, capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert third.returncode != 0 and "another farfield up" in third.stderr, third.stderr
        assert second.process.poll() is None and alive(second.api_pid())
    finally:
        assert second.stop() == 0
    assert not (home / "run").exists() or not any((home / "run").iterdir())  # a clean stop forgets its children
