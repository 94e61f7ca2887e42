"""The service as a cluster (issue 58): an API node and worker nodes that share only Redis over TCP,
the database and an S3 endpoint (tests/cluster_harness.py), and leases on running cells.

The lease is lowered to 4 s (heartbeat every 1 s, a sweep every 1 s) so that the tests wait seconds,
not the default 30 s lease; benchmarks/bench_cluster_recovery.py measures the defaults.  A node is
killed whole (its process group, SIGKILL) or paused (SIGSTOP) mid-cell, as a host that loses power
or stalls: the cell runs again on the other node, the job completes, and no cell's result is
applied twice.

One cluster of two worker nodes serves the module, its tests in the order written: the workers'
records, a node paused and resumed, a node killed (one node left), a job cancelled while its node
dies (none left).  Each test starts the nodes it needs if one before left too few (run alone, it
pays their start).  The cells are small (520 and 640 px: a bake of a few seconds here) but longer than
the half second before a cell first records progress, which is when a node is stopped.
"""

from __future__ import annotations

import re
import time

import pytest
from cluster_harness import Cluster
from service_harness import BUNNY, BUNNY_GRID, upload, wait_for_job

pytestmark = [pytest.mark.service, pytest.mark.skipif(not BUNNY.exists(), reason="needs ../shared/scenes")]

LEASE = {"FARFIELD_LEASE_S": "4", "FARFIELD_HEARTBEAT_S": "1", "FARFIELD_SWEEP_S": "1", "FARFIELD_REQUEUE_AFTER": "10"}
RECOVERY_S = 60  # the bound: the cell runs again elsewhere within this
LATE = "the cell went on without it (its lease was lost"  # what a worker logs when its late attempt stops or is refused


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    with Cluster(tmp_path_factory.mktemp("cluster"), workers=2, env=LEASE) as running:
        running.wait_for_workers()
        yield running


@pytest.fixture(scope="module")
def bunny(cluster):
    with cluster.client() as client:
        response = upload(client, BUNNY)
        assert response.status_code == 201, response.text
        return response.json()["id"]


def live_workers(cluster: Cluster, count: int = 2) -> None:
    """At least ``count`` live worker nodes (a test before may have killed some)."""
    live = [n for n in cluster.workers if n.alive()]
    for _ in range(count - len(live)):
        cluster.add_worker(f"node{len(cluster.workers)}")
    cluster.wait_for_workers(count)


def wait_for_cell(client, job_id: str, index: int, check, timeout: float, what: str) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        cell = client.get(f"/v1/jobs/{job_id}/cells/{index}").json()
        if check(cell):
            return cell
        time.sleep(0.1)
    raise AssertionError(f"cell {index} of job {job_id}: not {what} within {timeout} s: {cell}")


def running_mid_cell(client, job_id: str, timeout: float = 120) -> dict:
    """A cell of the job that a worker is baking (some progress recorded)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = client.get(f"/v1/jobs/{job_id}").json()
        busy = [c for c in job["cells"] if c["state"] == "running" and c["worker"] and c["progress"] > 0]
        if busy:
            return busy[0]
        time.sleep(0.05)
    raise AssertionError(f"no cell of job {job_id} was running within {timeout} s")


def done_by(node_log: str) -> int:
    """Bake tasks a node's log says ended with the cell done."""
    return len(re.findall(r"Task farfield\.bake_cell\[[^]]+\] succeeded in [0-9.e-]+s: 'done'", node_log))


def test_workers_report_host_kind_renderer_and_heartbeat(cluster):
    live_workers(cluster)
    deadline = time.monotonic() + 60
    with cluster.client() as client:
        while True:  # a node's renderer is probed (a second or so) after its first heartbeat
            listed = client.get("/v1/workers").json()
            alive = [w for w in listed["workers"] if w["alive"]]
            if all(w["renderer"] for w in alive) or time.monotonic() > deadline:
                break
            time.sleep(0.2)
    assert listed["lease_s"] == 4 and listed["heartbeat_s"] == 1
    assert len(alive) >= 2
    for worker in alive:
        assert worker["kind"] == "cpu" and "llvmpipe" in worker["renderer"], worker  # this machine's Mesa EGL
        assert worker["host"] and worker["heartbeat_age_s"] < 4 and re.fullmatch(r"node\d+@.+", worker["name"])


def test_a_paused_node_s_late_result_is_discarded(cluster, bunny):
    live_workers(cluster)
    with cluster.client() as client:
        created = client.post(
            "/v1/jobs", json={"scene_id": bunny, "viewcells": [_cell_of_grid()], "resolution": 640, "evaluate": False}
        )
        assert created.status_code == 201, created.text
        job_id = created.json()["id"]
        first = running_mid_cell(client, job_id)
        paused = cluster.worker(first["worker"])
        done_before = done_by(paused.log_text())  # by cells of earlier tests
        paused.pause()
        try:
            wait_for_cell(client, job_id, 0, lambda c: c["attempts"] == 2 and c["state"] in ("running", "done"),
                          RECOVERY_S, "taken by another node")  # fmt: skip
            job = wait_for_job(client, job_id, timeout=300)
        finally:
            paused.resume()
        assert job["state"] == "done", job
        settled = client.get(f"/v1/jobs/{job_id}/cells/0").json()
        assert settled["worker"] != first["worker"] and settled["attempts"] == 2
        # The paused node wakes up mid-bake: it finds its lease gone and stops, or, past its bake,
        # its outcome is refused by the token the database compares.  Either way it says so.
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and LATE not in paused.log_text():
            time.sleep(0.2)
        assert LATE in paused.log_text(), paused.log_text()[-3000:]
        assert client.get(f"/v1/jobs/{job_id}/cells/0").json() == settled  # the other node's result stands
        assert done_by(paused.log_text()) == done_before
        assert client.get(f"/v1/jobs/{job_id}").json()["state"] == "done"


def test_a_worker_node_killed_mid_cell_has_its_cell_run_again_on_the_other(cluster, bunny):
    live_workers(cluster)
    done_before = {n.name: done_by(n.log_text()) for n in cluster.workers}  # by cells of earlier tests
    with cluster.client() as client:
        grid = {**BUNNY_GRID, "counts": [2, 1, 1]}
        created = client.post("/v1/jobs", json={"scene_id": bunny, "grid": grid, "resolution": 640, "evaluate": False})
        assert created.status_code == 201, created.text
        job_id = created.json()["id"]
        victim_cell = running_mid_cell(client, job_id)
        victim = cluster.worker(victim_cell["worker"])
        victim.kill()
        # Its lease runs out (4 s), the API's sweep queues the cell again and sends it: the other node takes it.
        again = wait_for_cell(
            client, job_id, victim_cell["index"],
            lambda c: c["state"] in ("running", "done") and c["attempts"] == 2, RECOVERY_S, "running again",
        )  # fmt: skip
        assert again["worker"] != victim_cell["worker"]
        job = wait_for_job(client, job_id, timeout=300)
        assert job["state"] == "done" and job["counts"]["done"] == 2, job
        attempts = {c["index"]: c["attempts"] for c in job["cells"]}
        assert attempts == {victim_cell["index"]: 2, 1 - victim_cell["index"]: 1}, attempts
        survivors = [n for n in cluster.workers if n is not victim]
        assert {c["worker"].split("@")[0] for c in job["cells"]} <= {n.name for n in survivors}
        # No cell done twice: the killed node ended none, the others ended each cell once.
        done = {n.name: done_by(n.log_text()) - done_before.get(n.name, 0) for n in cluster.workers}
        assert done[victim.name] == 0 and sum(done[n.name] for n in survivors) == 2, done
        assert client.get(f"/v1/jobs/{job_id}/index.json").status_code == 200


def test_cancelling_a_job_whose_node_died_leaves_no_cell_running(cluster, bunny):
    """The node baking a cell is killed and the job cancelled: once the cell's lease runs out the sweep
    cancels it, the job ends (finished, nothing running) and its index answers for good (a cancelled
    job has none: 409 "ended without", never "written when it ends")."""
    live_workers(cluster, 1)
    with cluster.client() as client:
        created = client.post(
            "/v1/jobs", json={"scene_id": bunny, "viewcells": [_cell_of_grid()], "resolution": 520, "evaluate": False}
        )
        assert created.status_code == 201, created.text
        job_id = created.json()["id"]
        cluster.worker(running_mid_cell(client, job_id)["worker"]).kill()
        assert client.post(f"/v1/jobs/{job_id}/cancel").status_code == 200
        cell = wait_for_cell(client, job_id, 0, lambda c: c["state"] != "running", RECOVERY_S, "ended")
        job = client.get(f"/v1/jobs/{job_id}").json()
        assert cell["state"] == "cancelled" and job["state"] == "cancelled" and job["finished_at"] is not None
        assert job["counts"]["running"] == 0 and job["counts"]["queued"] == 0
        index = client.get(f"/v1/jobs/{job_id}/index.json")
        assert index.status_code == 409 and index.json()["detail"] == (
            f"job {job_id!r} is cancelled; it ended without an impostor database index"
        )


def _cell_of_grid() -> dict:
    """The first cell of the bunny grid as a box view cell."""
    lo, hi, counts = BUNNY_GRID["lo"], BUNNY_GRID["hi"], BUNNY_GRID["counts"]
    size = [(h - low) / n for low, h, n in zip(lo, hi, counts, strict=True)]
    return {"kind": "box", "lo": lo, "hi": [low + s for low, s in zip(lo, size, strict=True)]}
