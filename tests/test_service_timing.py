"""A job's time, broken down (``timing`` of its record, :mod:`farfield.service.jobs.timing`), through a
real service: ``farfield submit --wait`` prints it, ``farfield jobs ID`` shows it, ``--json`` carries it,
and its figures are the cells' own, summed.

Sharing the module's service (one ``farfield up`` start less in the suite): GPU and CPU pools (issue 58,
item 4: service/pools.py).  Heavy cells go to a GPU worker while one is live, light ones to the CPU
worker, both in one job; with no GPU worker, every cell to the CPU worker.  The service's one Celery
worker is declared a CPU worker and a second real Celery worker joined to it (sharing only the broker,
the database and the blob folder) a GPU worker, with ``FARFIELD_WORKER_KIND`` (this machine has no GPU:
both render on llvmpipe).  The cells are tiny (32 px, no evaluation): a near view cell of the bunny plans
1,368 or 4,140 texels, a far one 130, and the service's heavy threshold is 1,000."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time

import pytest
from service_harness import BUNNY, assert_timing_adds_up, service_client, service_on_sqlite, upload, wait_for_job  # noqa: F401 - the service fixtures

from farfield.service.pools import HEAVY_QUEUE, LIGHT_QUEUE
from farfield.service.supervisor import worker_command

pytestmark = pytest.mark.skipif(not BUNNY.exists(), reason="needs ../shared/scenes")

GRID = "-0.6,0.05,-0.05,-0.4,0.15,0.05,2,1,1"  # two cells of the bunny, at 128 px: a few seconds


def test_submit_wait_prints_the_breakdown_and_the_record_adds_up(service, client):
    auth = ("--url", service.url, "--key", service.env["FARFIELD_ADMIN_KEY"])
    done = service.cli("submit", str(BUNNY), "--grid", GRID, "--resolution", "128", "--wait", *auth)
    assert done.returncode == 0, done.stderr
    job_id = done.stdout.split()[1].rstrip(":")
    job = client.get(f"/v1/jobs/{job_id}").json()
    assert job["state"] == "done" and all(c["stats"]["baked"] for c in job["cells"])
    timing = assert_timing_adds_up(job)
    # A layered bake's stages (core.techniques.layered), each summed over the two cells.
    assert set(timing["stages"]) == {"plan", "record", "cull", "quads", "atlas"} and timing["stages"]["record"] > 0
    assert timing["cells"] == 2 and timing["admission_s"] > 0 and timing["evaluation_s"] > 0
    assert timing["planning_s"] == 0 and timing["checking_s"] == 0  # a grid job is neither planned nor checked
    lines = done.stdout.splitlines()
    table = lines[lines.index(next(line for line in lines if line.startswith("time "))) :]
    labels = [line[2:24].strip() for line in table[1:]]
    stages = [f"bake: {name}" for name in timing["stages"]]
    assert labels == ["wall", "admission", "cells (2, summed)", *stages, "evaluation", "overhead"], table
    shown = {label: float(line[24:34]) for label, line in zip(labels, table[1:], strict=True)}
    assert shown["bake: record"] == pytest.approx(timing["stages"]["record"], abs=5e-4)
    assert shown["cells (2, summed)"] == pytest.approx(timing["cells_s"], abs=5e-4)
    shown_by_jobs = service.cli("jobs", job_id, *auth)
    assert (
        shown_by_jobs.returncode == 0 and "bake: record" in shown_by_jobs.stdout and "overhead" in shown_by_jobs.stdout
    )

    # The same job again finds every bundle: its cells take time but bake nothing, so no stage.
    again = service.cli("submit", job["scene_id"], "--grid", GRID, "--resolution", "128", "--wait", "--json", *auth)
    assert again.returncode == 0, again.stderr
    record = json.loads(again.stdout)
    assert record["timing"]["stages"] == {} and record["timing"]["bake_s"] == 0 and record["timing"]["cells"] == 2
    found = client.get(f"/v1/jobs/{record['id']}").json()
    assert not any(c["stats"]["baked"] for c in found["cells"])
    assert_timing_adds_up(found)


NEAR = [{"kind": "box", "lo": [-0.6, 0.05, -0.05], "hi": [-0.5, 0.1, 0.0]},
        {"kind": "box", "lo": [-0.6, 0.05, -0.05], "hi": [-0.4, 0.15, 0.05]}]  # fmt: skip
FAR = [{"kind": "box", "lo": [-0.9, 0.05, -0.05], "hi": [-0.85, 0.1, 0.0]},
       {"kind": "box", "lo": [-0.9, 0.1, 0.0], "hi": [-0.85, 0.15, 0.05]}]  # fmt: skip


@pytest.fixture(scope="module")
def service_env():
    return {"FARFIELD_HEAVY_TEXELS": "1000", "FARFIELD_HEARTBEAT_S": "1", "FARFIELD_WORKER_KIND": "cpu"}


def queues_become(client, wanted: dict[str, list[str]], timeout: float = 60.0) -> dict:
    """Wait until each worker named in ``wanted`` (by its name's start) is alive and consumes those queues."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        workers = {w["name"].split("@")[0]: w for w in client.get("/v1/workers").json()["workers"] if w["alive"]}
        if all(name in workers and workers[name]["queues"] == q for name, q in wanted.items()):
            return workers
        time.sleep(0.2)
    raise AssertionError(f"the workers' queues did not become {wanted}: {workers}")  # noqa: F821 - set in the loop


def run_job(client, scene_id: str) -> list[dict]:
    spec = {"scene_id": scene_id, "resolution": 32, "evaluate": False, "viewcells": NEAR + FAR}
    job = wait_for_job(client, client.post("/v1/jobs", json=spec).json()["id"], timeout=120)
    assert job["state"] == "done", job["errors"]
    assert [c["texels"] > 1000 for c in job["cells"]] == [True, True, False, False]
    return job["cells"]


def test_heavy_cells_go_to_the_gpu_worker_while_one_is_live(service, client, tmp_path):
    scene_id = upload(client, BUNNY).json()["id"]
    # No GPU worker: the CPU worker consumes both queues and runs every cell, the heavy ones too.
    cpu = queues_become(client, {"worker0": [LIGHT_QUEUE, HEAVY_QUEUE]})["worker0"]
    assert cpu["kind"] == "cpu"
    assert {c["worker"] for c in run_job(client, scene_id)} == {cpu["name"]}
    # A GPU worker joins (sharing only the broker, the database and the blob store).
    env = {
        **service.env, "REDIS_URL": service.broker, "DATABASE_URL": f"sqlite:///{service.home / 'farfield.db'}",
        "FARFIELD_BLOB_DIR": str(service.home / "blobs"), "FARFIELD_HOME": str(tmp_path), "TMPDIR": str(tmp_path),
        "FARFIELD_WORKER_KIND": "gpu",
    }  # fmt: skip
    with open(tmp_path / "gpu0.log", "wb") as log:
        gpu_worker = subprocess.Popen(worker_command("gpu0"), env=env, stdout=log, stderr=subprocess.STDOUT,
                                      start_new_session=True)  # fmt: skip
    try:
        workers = queues_become(client, {"worker0": [LIGHT_QUEUE], "gpu0": [HEAVY_QUEUE]})
        assert workers["gpu0"]["kind"] == "gpu" and workers["gpu0"]["renderer"]  # its GL renderer, probed still
        cells = run_job(client, scene_id)
        assert [c["worker"] for c in cells] == [workers["gpu0"]["name"]] * 2 + [cpu["name"]] * 2
        os.killpg(gpu_worker.pid, signal.SIGTERM)  # a warm shutdown: it records that it consumes nothing
        assert gpu_worker.wait(60) == 0
        queues_become(client, {"worker0": [LIGHT_QUEUE, HEAVY_QUEUE]})  # within a heartbeat, not the 30 s lease
    finally:
        if gpu_worker.poll() is None:
            os.killpg(gpu_worker.pid, signal.SIGKILL)
            gpu_worker.wait()
