"""The service as a cluster (issue 58): an API node and worker nodes that share only Redis over TCP,
the database and an S3 endpoint (tests/cluster_harness.py), and leases on running cells.

The lease is lowered to 4 s (heartbeat every 1 s, a sweep every 1 s) so that the tests wait seconds,
not the default 30 s lease; benchmarks/bench_cluster_recovery.py measures the defaults.  A node is
killed whole (its process group, SIGKILL), paused (SIGSTOP) or partitioned away (its network
namespace's link cut) mid-cell, as a host that loses power, stalls or loses its network: the cell
runs again on another node, the job completes, and no cell's result is
applied twice.  A job across the three nodes equals the same job run on a single host, byte for
byte; and a job completes through each shared service failing for a few seconds (Redis, S3 and,
where the cluster could start its own server, PostgreSQL; the 30 s campaign is
benchmarks/bench_cluster_faults.py).

One cluster of three worker nodes serves the module, on a PostgreSQL server of its own where
``scripts/postgres-server`` can start one (CI: .ci/run installs it), the nodes reaching S3 through a
gate that can close, each worker node in a network namespace of its own where one can be made
(root, ``ip netns``; with a server database), reaching the shared services through gates on its
veth pair, so that it can be partitioned away; its tests run in the order written: the workers'
records, the job across the nodes against a single host, the three faults, PostgreSQL failing
under an admission, a node paused and resumed, a node partitioned and healed, a node killed, a job
cancelled while its node dies.  Each test starts the nodes it needs if one before left too few
(run alone, it pays their start).  The jobs that only need to cross the nodes have the smallest
cells (16 to 32 px); those that stop a node mid-cell are larger (960 to 1280 px: a bake of a few
seconds here), so that the cell is seen running (claimed, not ended) before it ends, which is when
a node is stopped.
"""

from __future__ import annotations

import json
import re
import time
from concurrent.futures import ThreadPoolExecutor

import pytest
from cluster_harness import BAKE_OUTCOME, Cluster, wait_through_faults
from service_harness import BUNNY, BUNNY_GRID, upload, wait_for_job
from sqlalchemy.orm import undefer

from farfield.service.blobs import LocalBlobStore, blob_store
from farfield.service.db import CellRow, Database, SceneRow, Tenant
from farfield.service.jobs.admission import create_job
from farfield.service.jobs.admitting import admit_job
from farfield.service.jobs.runner import run_cell
from farfield.service.jobs.schema import JobSpec
from farfield.service.settings import Settings

pytestmark = [pytest.mark.service, pytest.mark.skipif(not BUNNY.exists(), reason="needs ../shared/scenes")]

LEASE = {"FARFIELD_LEASE_S": "4", "FARFIELD_HEARTBEAT_S": "1", "FARFIELD_SWEEP_S": "1", "FARFIELD_REQUEUE_AFTER": "10"}
RECOVERY_S = 60  # the bound: the cell runs again elsewhere within this
LATE = "the cell went on without it (its lease was lost"  # what a worker logs when its late attempt stops or is refused


FAULT_S = 3  # how long a shared service stays down in CI (benchmarks/bench_cluster_faults.py: 30 s)
# The cells of the jobs that only need to run across the nodes: the smallest, some 0.1 s of baking.
SMALL = {"grid": {**BUNNY_GRID, "counts": [3, 1, 1]}, "evaluate": False}
# Cell columns that say when, where and under which lease an attempt ran, not what it made.
RUN_COLUMNS = ("id", "job_id", "worker", "queued_at", "started_at", "finished_at", "seconds", "lease_token",
               "lease_until")  # fmt: skip


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    root = tmp_path_factory.mktemp("cluster")
    with Cluster(root, workers=3, env=LEASE, s3_gate=True, own_postgres=True, netns=True) as running:
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
    """A cell of the job that a worker has claimed and not ended.  Not "some progress recorded": a
    worker writes progress every 0.5 s (service.jobs.runner.PROGRESS_EVERY_S), and an idle machine's
    640 px cell ended between two looks with none (CI: 'no cell ... running within 120 s')."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = client.get(f"/v1/jobs/{job_id}").json()
        busy = [c for c in job["cells"] if c["state"] == "running" and c["worker"]]
        if busy:
            return busy[0]
        ended = [c["state"] for c in job["cells"] if c["state"] in ("done", "failed", "cancelled")]
        assert len(ended) < len(job["cells"]), f"job {job_id}'s cells ended ({ended}) before one was seen running"
        time.sleep(0.05)
    raise AssertionError(f"no cell of job {job_id} was running within {timeout} s")


def done_by(node_log: str) -> int:
    """Bake tasks a node's log says ended with the cell done."""
    return BAKE_OUTCOME.findall(node_log).count("done")


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


def test_a_job_across_three_nodes_without_a_shared_disk_equals_the_single_host_one(cluster, bunny, tmp_path):
    """A grid job of 3 cells at 16 px baked by a cluster of three worker nodes that share no disk
    (each its own FARFIELD_HOME and TMPDIR, the bundles in S3, the database on PostgreSQL where the
    cluster has one; at least two nodes take its cells) against the same job run on a single host: SQLite and a blob directory on this test's disk, its
    cells run one after another in this process by the code a worker runs (``admit_job``, then
    ``run_cell``), on the same stored scene (its row and blobs copied from the cluster, under the same
    tenant id: a bundle's key digests its tenant).  Equal byte for byte:

    - each cell's row in the database, every column but those that say when, where and under which
      lease an attempt ran (``RUN_COLUMNS``: ids, worker, times, lease token) and the bake's own timings
      in its stats (``stats.seconds``): index, grid, view cell, state, attempts, error, bundle key,
      stats, progress;
    - each cell's bundle: the names and bytes of every blob under its key;
    - the job's impostor database index (``jobs/<id>/index.json``), but for the job's id.
    """
    live_workers(cluster, 3)
    request = {**SMALL, "scene_id": bunny, "resolution": 16}
    with cluster.client() as client:
        created = client.post("/v1/jobs", json=request)
        assert created.status_code == 201, created.text
        job = wait_for_job(client, created.json()["id"], timeout=120)
    assert job["state"] == "done" and job["counts"]["done"] == 3, job
    # Across the nodes (prefetch 1: each takes one message at a time), none holding a blob of its own.
    assert len({c["worker"].split("@")[0] for c in job["cells"]}) >= 2, [c["worker"] for c in job["cells"]]
    assert not [path for node in cluster.workers for path in node.home.rglob("*") if path.name == "blobs"]

    shared = cluster.shared_env()
    database, s3 = Database(shared["DATABASE_URL"]), blob_store(Settings.from_env(shared))
    single = Settings.from_env({"FARFIELD_HOME": str(tmp_path)})
    local_db, local = Database(single.database_url), LocalBlobStore(single.blob_dir)
    local_db.migrate()
    scene = _copy_scene(database, s3, local_db, local, bunny)
    local_id = create_job(local_db, scene.tenant_id, scene, JobSpec(**request)).id
    state, cell_ids = admit_job(local_db, local, local_id, "single-host", max_attempts=3)
    assert state == "queued" and len(cell_ids) == 3
    assert [run_cell(local_db, local, cell_id, 3, worker="single-host") for cell_id in cell_ids] == ["done"] * 3

    records = [_made(database, job["id"]), _made(local_db, local_id)]
    database.dispose()
    local_db.dispose()
    assert records[0] == records[1]
    for cell in records[0]:
        key = cell["result_key"]
        files = sorted(s3.list_files(key))
        assert files and files == sorted(local.list_files(key)), key
        assert all(s3.read_bytes(f"{key}/{name}") == local.read_bytes(f"{key}/{name}") for name in files), key
    indexes = [
        {**json.loads(store.read_bytes(f"jobs/{i}/index.json")), "job": None}
        for store, i in ((s3, job["id"]), (local, local_id))
    ]
    assert indexes[0] == indexes[1]


def _copy_scene(database: Database, blobs, to_db: Database, to_blobs, scene_id: str) -> SceneRow:
    """The stored scene (its tenant's row, its own row and its blobs) copied from one service's
    database and blob store to another's, as it was uploaded there."""
    with database.session() as s:
        row = s.get(SceneRow, scene_id, options=[undefer(SceneRow.objects)])
        tenant = s.get(Tenant, row.tenant_id)
        rows = [{c.key: getattr(r, c.key) for c in type(r).__table__.columns} for r in (tenant, row)]
    with to_db.session() as s:
        s.add(Tenant(**rows[0]))
        s.flush()  # the tenant first (no relationship orders the rows)
        s.add(SceneRow(**rows[1]))
    folder = row.blob_key.rsplit("/", 1)[0]
    for name in blobs.list_files(folder):
        to_blobs.put_bytes(f"{folder}/{name}", blobs.read_bytes(f"{folder}/{name}"))
    with to_db.session() as s:
        return s.get(SceneRow, scene_id, options=[undefer(SceneRow.objects)])


def _made(database: Database, job_id: str) -> list[dict]:
    """What a job's cells made, as their rows hold it (the test above)."""
    with database.session() as s:
        rows = s.query(CellRow).filter(CellRow.job_id == job_id).order_by(CellRow.index).all()
        made = [
            {c.name: getattr(row, c.key) for c in CellRow.__table__.columns if c.name not in RUN_COLUMNS}
            for row in rows
        ]
    for cell in made:
        cell["stats"] = {k: v for k, v in (cell["stats"] or {}).items() if k != "seconds"}
    return made


@pytest.mark.parametrize("fault", ["redis", "s3", "postgres"])
def test_a_job_completes_through_a_shared_service_failing(cluster, bunny, fault):
    """A shared service fails for FAULT_S seconds while a job of small cells is in flight, and comes back:
    Redis stopped and started again on its port from its append-only file, or the S3 endpoint
    refusing (its TCP gate closed: connections cut and refused) then open, both from before the job
    is submitted (the POST's send of its admission waits for Redis, ``SEND_RETRY_POLICY``; its cells
    cannot store their bundles without S3); or the cluster's own PostgreSQL server stopped and
    started again on its port and data, once the job's 9 cells are sent (once admitted: an admission
    whose database fails under it is the admission test's), held from ending until then by S3
    refusing from before the job is submitted to just after the server has stopped (no cell can be
    ``done`` before its bundle is stored).  So the fault is certain to meet the job, however fast the
    machine: before, with the fault begun after the POST, an idle machine's job of 3 small cells could
    end before Redis's stop took effect.  The job ends after the service is back, with every cell
    done and none lost (each with its bundle) or done twice (bake tasks ended ``done``, by the nodes'
    logs, as many as the cells; no bundle uploaded more often than its cell was attempted; Redis and
    S3 cost no attempt).  The 30 s faults of the campaign are benchmarks/bench_cluster_faults.py."""
    if fault == "postgres" and cluster.postgres is None:
        pytest.skip(cluster.postgres_missing)
    live_workers(cluster, 3)
    down, up = {
        "redis": (cluster.stop_redis, cluster.start_redis),
        "s3": (cluster.s3_gate.close, cluster.s3_gate.open),
        "postgres": (lambda: cluster.postgres.stop(), lambda: cluster.postgres.start()),
    }[fault]
    resolution = {"redis": 20, "s3": 24, "postgres": 28}[fault]  # a job of its own: no bundle found from another
    grid = {**BUNNY_GRID, "counts": [3, 3 if fault == "postgres" else 1, 1]}
    request = {**SMALL, "grid": grid, "scene_id": bunny, "resolution": resolution}
    marks = cluster.log_marks()
    with cluster.client() as client, ThreadPoolExecutor(1) as pool:

        def submit() -> str:
            created = client.post("/v1/jobs", json=request)
            assert created.status_code == 201, created.text
            return created.json()["id"]

        if fault == "postgres":
            cluster.s3_gate.close()  # the hold: no cell ends before the server stops
            try:
                job_id = submit()
                _wait_admitted(client, job_id)
                down()
            finally:
                cluster.s3_gate.open()
        else:
            down()
            posting = pool.submit(submit)  # answered once Redis is back (the send waits for it)
        try:
            time.sleep(FAULT_S)
        finally:
            up()
            restored = time.time()
        if fault != "postgres":
            job_id = posting.result(timeout=120)
        job, _ = wait_through_faults(client, job_id, timeout=120)
    assert job is not None and job["state"] == "done", job
    assert job["finished_at"] > restored, "the job ended before the fault did: it met no fault"
    cells = len(job["cells"])
    assert [c["state"] for c in job["cells"]] == ["done"] * cells and all(c["has_result"] for c in job["cells"]), job
    attempts = [c["attempts"] for c in job["cells"]]
    assert attempts == [1] * cells or fault == "postgres", attempts
    assert cells <= cluster.manifest_puts(marks) <= sum(attempts), (cluster.manifest_puts(marks), attempts)
    assert cluster.bake_outcomes(marks)["done"] == cells, cluster.bake_outcomes(marks)


def test_a_job_s_admission_completes_through_postgresql_failing(cluster, bunny):
    """PostgreSQL stops as a job's admission is delivered, for FAULT_S seconds: the worker nodes are
    paused while the job is submitted (the admission message waits) and the server stopped, then
    resumed, so the admission's first delivery meets the database down, certainly.  It can neither
    claim the job nor free a hold, so it is retried with backoff (``admit_job_task``: 2, 4, ... s), not
    left to the hold's lease (``FARFIELD_ADMISSION_LEASE_S``) or the job's first
    ``FARFIELD_REQUEUE_AFTER``: a node's log says so.  The job ends after the server is back, its 3
    cells done once each at their first attempt (bake tasks ended ``done`` as many as the cells, no
    bundle uploaded more often), nothing lost."""
    if cluster.postgres is None:
        pytest.skip(cluster.postgres_missing)
    live_workers(cluster, 3)
    nodes = [n for n in cluster.workers if n.alive()]
    grid = {**BUNNY_GRID, "counts": [3, 1, 1]}
    marks = cluster.log_marks()
    with cluster.client() as client:
        for node in nodes:
            node.pause()
        try:
            created = client.post("/v1/jobs", json={**SMALL, "grid": grid, "scene_id": bunny, "resolution": 32})
            assert created.status_code == 201 and created.json()["state"] == "admitting", created.text
            job_id = created.json()["id"]
            cluster.postgres.stop()
        finally:
            for node in nodes:
                node.resume()
        try:
            time.sleep(FAULT_S)
        finally:
            cluster.postgres.start()
            restored = time.time()
        job, _ = wait_through_faults(client, job_id, timeout=120)
    assert job is not None and job["state"] == "done", job
    assert job["finished_at"] > restored
    cells = len(job["cells"])
    assert [c["state"] for c in job["cells"]] == ["done"] * cells and all(c["has_result"] for c in job["cells"]), job
    assert [c["attempts"] for c in job["cells"]] == [1] * cells, job["cells"]
    assert cells <= cluster.manifest_puts(marks) <= cells, cluster.manifest_puts(marks)
    assert cluster.bake_outcomes(marks)["done"] == cells, cluster.bake_outcomes(marks)
    logs = cluster.logs_since(marks)
    assert any(f"job {job_id}: its hold could not be freed either; admission retried" in logs[n.name] for n in nodes)


def _wait_admitted(client, job_id: str, timeout: float = 60) -> None:
    """Until the job's admission has ended (its cells sent), asked every 20 ms: its cells, some 0.1 s
    of work each, have only begun when the caller's fault begins."""
    deadline = time.monotonic() + timeout
    while client.get(f"/v1/jobs/{job_id}").json()["state"] == "admitting":
        assert time.monotonic() < deadline, f"job {job_id} still admitting after {timeout} s"
        time.sleep(0.02)


def test_a_paused_node_s_late_result_is_discarded(cluster, bunny):
    live_workers(cluster)
    with cluster.client() as client:
        created = client.post(
            "/v1/jobs", json={"scene_id": bunny, "viewcells": [_cell_of_grid()], "resolution": 960, "evaluate": False}
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


def test_a_node_partitioned_mid_cell_has_its_cell_run_again_and_its_late_result_discarded(cluster, bunny):
    """The node baking a cell (1280 px) is cut off from the broker, the database and the blob store
    alike (its network namespace's link cut: its packets dropped, its connections hanging, as behind
    a switch that fails), running on; once its lease runs out (4 s) the API's sweep queues the cell
    again and another node takes it (attempt 2), and the link is healed.  The partitioned node's
    connections go on where they hung: its attempt finds its lease gone and stops, or its outcome is
    refused by the lease token, and says so; the other node's result stands, the job completes, and
    the cell is done once (one bake task ended ``done`` in the nodes' logs, no bundle uploaded more
    often than the cell was attempted)."""
    if cluster.netns_missing:
        pytest.skip(cluster.netns_missing)
    live_workers(cluster)
    marks = cluster.log_marks()
    with cluster.client() as client:
        # 1280 px: a bundle of its own (the paused node's test bakes this view cell at 960 px, the
        # killed node's and the cancel test's at 1024).
        created = client.post(
            "/v1/jobs", json={"scene_id": bunny, "viewcells": [_cell_of_grid()], "resolution": 1280, "evaluate": False}
        )
        assert created.status_code == 201, created.text
        job_id = created.json()["id"]
        first = running_mid_cell(client, job_id)
        cut = cluster.worker(first["worker"])
        cut.partition()
        try:
            again = wait_for_cell(client, job_id, 0, lambda c: c["attempts"] == 2 and c["state"] in ("running", "done"),
                                  RECOVERY_S, "taken by another node")  # fmt: skip
        finally:
            cut.heal()
        assert again["worker"] != first["worker"], again
        job = wait_for_job(client, job_id, timeout=300)
        assert job["state"] == "done", job
        settled = client.get(f"/v1/jobs/{job_id}/cells/0").json()
        assert settled["worker"] == again["worker"] and settled["attempts"] == 2 and settled["has_result"], settled
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and LATE not in cluster.logs_since(marks)[cut.name]:
            time.sleep(0.2)
        assert LATE in cluster.logs_since(marks)[cut.name], cut.log_text()[-3000:]
        assert client.get(f"/v1/jobs/{job_id}/cells/0").json() == settled  # the other node's result stands
        assert client.get(f"/v1/jobs/{job_id}").json()["state"] == "done"
    outcomes = cluster.bake_outcomes(marks)
    assert outcomes["done"] == 1 and done_by(cluster.logs_since(marks)[cut.name]) == 0, outcomes
    assert 1 <= cluster.manifest_puts(marks) <= 2, cluster.manifest_puts(marks)


def test_a_worker_node_killed_mid_cell_has_its_cell_run_again_on_the_other(cluster, bunny):
    live_workers(cluster)
    done_before = {n.name: done_by(n.log_text()) for n in cluster.workers}  # by cells of earlier tests
    with cluster.client() as client:
        grid = {**BUNNY_GRID, "counts": [2, 1, 1]}
        created = client.post("/v1/jobs", json={"scene_id": bunny, "grid": grid, "resolution": 1024, "evaluate": False})
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
    """The node baking a cell (1024 px: killed at its first progress, so the size costs nothing, and
    a bake that lasts; at 520 px an idle machine's bake of 0.9 s could end between two looks for its
    progress) is killed and the job cancelled: once the cell's lease runs out the sweep cancels it, the job ends (finished, nothing running) and its index answers for good (a cancelled
    job has none: 409 "ended without", never "written when it ends")."""
    live_workers(cluster, 1)
    with cluster.client() as client:
        created = client.post(
            "/v1/jobs", json={"scene_id": bunny, "viewcells": [_cell_of_grid()], "resolution": 1024, "evaluate": False}
        )
        assert created.status_code == 201, created.text
        job_id = created.json()["id"]
        cluster.worker(running_mid_cell(client, job_id)["worker"]).kill()
        assert client.post(f"/v1/jobs/{job_id}/cancel").status_code == 200
        cell = wait_for_cell(client, job_id, 0, lambda c: c["state"] != "running", RECOVERY_S, "ended")
        # The sweep ends the cell, then the job in a transaction of its own (service.jobs.cells.release_lost_cells):
        # a read between the two sees the cell cancelled and the job not yet finished.
        deadline = time.monotonic() + 10
        while (job := client.get(f"/v1/jobs/{job_id}").json())["finished_at"] is None and time.monotonic() < deadline:
            time.sleep(0.1)
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


def test_namespaces_left_by_a_killed_run_are_removed_and_live_ones_kept():
    """A test run killed before its cleanup (kill -9) leaves its nodes' namespaces; the next run's
    harness removes those whose process is gone, and keeps a live run's."""
    import os
    import subprocess

    from cluster_harness import NAMESPACE_PREFIX, netns_unavailable, remove_stale_namespaces

    why = netns_unavailable()
    if why:
        pytest.skip(why)
    gone = subprocess.Popen(["true"])
    gone.wait()
    dead, live = f"{NAMESPACE_PREFIX}{gone.pid}-stale", f"{NAMESPACE_PREFIX}{os.getppid()}-live"
    for name in (dead, live):
        subprocess.run(["ip", "netns", "add", name], check=True, capture_output=True)
    try:
        assert dead in remove_stale_namespaces()
        listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
        assert dead not in listed and live in listed
    finally:
        for name in (dead, live):
            subprocess.run(["ip", "netns", "del", name], capture_output=True)
