"""The service end to end with real parts: ``farfield up`` (embedded redis-server, uvicorn, a real
``celery worker``, SQLite, blob directory) driven over HTTP."""

from __future__ import annotations

import io
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import PIL.Image
import pytest
import trimesh
from service_harness import BUNNY, BUNNY_GRID, ROOT, service_client, service_on_each_database, upload, wait_for_job  # noqa: F401 - the service and client fixtures

from farfield.core.exchange import load_scene
from farfield.core.impostor.bundle import page_file_name, write_bundle
from farfield.core.techniques.layered import BakeOptions, bake_layered
from farfield.core.viewcells import viewcell_from_dict

pytestmark = pytest.mark.skipif(not BUNNY.exists(), reason="needs ../shared/scenes")


@pytest.fixture(scope="module")
def bunny_id(client):
    response = upload(client, BUNNY)
    assert response.status_code == 201, response.text
    return response.json()["id"]


def blob_files(service) -> set[str]:
    root = service.home / "blobs"
    return {str(p.relative_to(root)) for p in root.rglob("*") if p.is_file()}


def test_upload_reports_the_scene(client, bunny_id):
    scene = client.get(f"/v1/scenes/{bunny_id}").json()
    assert scene["triangles"] == 69451
    assert scene["name"] == "bun_zipper.ply"
    assert scene["original_name"] == "bun_zipper.ply" and scene["object_count"] == 1 and "objects" not in scene
    objects = client.get(scene["objects_url"])
    assert [o["name"] for o in objects.json()] and objects.headers["X-Total-Count"] == "1" and len(scene["bounds"]) == 2
    assert objects.json()[0]["triangles"] == 69451
    assert bunny_id in [s["id"] for s in client.get("/v1/scenes").json()]


def test_grid_job_pages_equal_what_core_bakes(client, bunny_id, tmp_path):
    created = client.post("/v1/jobs", json={"scene_id": bunny_id, "grid": BUNNY_GRID, "resolution": 256})
    assert created.status_code == 201, created.text
    job = wait_for_job(client, created.json()["id"])
    assert job["state"] == "done", job["errors"]
    assert job["counts"]["done"] == 4 and job["progress"] == 1.0
    scene = load_scene(BUNNY)
    for cell in job["cells"]:
        manifest = client.get(f"/v1/jobs/{job['id']}/cells/{cell['index']}/manifest.json").json()
        write_bundle(
            bake_layered(scene, viewcell_from_dict(cell["viewcell"]), BakeOptions(resolution=256)),
            tmp_path / str(cell["index"]),
        )
        assert len(manifest["pages"]) >= 1
        for page in range(len(manifest["pages"])):
            served = client.get(f"/v1/jobs/{job['id']}/cells/{cell['index']}/atlas/{page}.png")
            assert served.status_code == 200 and served.headers["content-type"] == "image/png"
            decoded = np.asarray(PIL.Image.open(io.BytesIO(served.content)))
            expected = np.asarray(PIL.Image.open(tmp_path / str(cell["index"]) / page_file_name(page)))
            np.testing.assert_array_equal(decoded, expected)
        zipped = client.get(f"/v1/jobs/{job['id']}/cells/{cell['index']}/bundle.zip")
        assert zipped.status_code == 200 and zipped.content[:2] == b"PK"
    database = client.get(f"/v1/jobs/{job['id']}/database.zip")
    assert database.status_code == 200
    import zipfile

    names = zipfile.ZipFile(io.BytesIO(database.content)).namelist()
    assert "index.json" in names and sum(n.endswith("manifest.json") for n in names) == 4
    centre = np.mean([viewcell_from_dict(job["cells"][0]["viewcell"]).center], axis=0)
    served = client.get(f"/v1/jobs/{job['id']}/lookup", params=dict(zip("xyz", centre.tolist()))).json()
    assert [c["index"] for c in served] == [0]
    for x in ("nan", "inf", "1e309"):  # no cell holds such a point: a 422, not an empty answer
        refused = client.get(f"/v1/jobs/{job['id']}/lookup", params={"x": x, "y": centre[1], "z": centre[2]})
        assert refused.status_code == 422 and "must be finite numbers, got x=" in refused.json()["detail"], refused.text


@pytest.mark.parametrize(
    "name, content, status, message",
    [
        ("broken.glb", b"glTF\x02\x00\x00\x00garbage" * 10, 422, "broken.glb"),
        ("empty.ply", b"", 422, "empty"),
        ("notes.txt", b"hello", 422, "unsupported scene format"),
        ("big.stl", b"\0" * (6 * 2**20), 413, "limit"),
    ],
)
def test_bad_uploads_leave_nothing_behind(service, client, name, content, status, message, tmp_path):
    before_rows, before_blobs = client.get("/v1/scenes").json(), blob_files(service)
    response = client.post("/v1/scenes", files={"file": (name, content)})
    assert response.status_code == status, response.text
    assert message in response.json()["detail"]
    assert client.get("/v1/scenes").json() == before_rows
    assert blob_files(service) == before_blobs
    assert client.get("/v1/health").json()["status"] == "ok"


@pytest.mark.parametrize(
    "change, status, message",
    [
        ({"resolution": 0}, 422, "resolution"),
        ({"fov_deg": 200}, 422, "fov_deg must be a number in (0, 180), got 200"),
        (
            {"grid": None, "viewcells": [{"kind": "box", "lo": [-0.01, 0.1, -0.01], "hi": [0.01, 0.12, 0.01]}]},
            422,
            "view cell 0",
        ),
        ({"scene_id": "0" * 32}, 404, "not found"),
        ({"objects": ["nope"]}, 404, "no objects named"),
        ({"options": {"grid_cell": 0}}, 422, "grid_cell must be an integer in [1, 1024], got 0"),
        ({"grid": {"lo": [0, 0, 0], "hi": [1, 1, 1], "counts": [0, 1, 1]}}, 422, "counts"),
        ({"grid": {"lo": [0, 0, 0], "hi": [1, 1, 1], "counts": [2**32, 2**32, 1]}}, 422, "over the limit"),
        ({"options": {"grid_cell": "abc"}}, 422, "grid_cell must be an integer"),
        ({"options": {"grid_cell": 8.0, "padding": 1e18}}, 422, "padding must be an integer in [0, 64]"),
        (
            {"options": {"padding": 64, "max_page": 64}},
            422,
            "padding 64 on both sides of a tile leaves no texel of a page of 64",
        ),
        (
            {"objects": []},
            422,
            "List should have at least 1 item",
        ),  # stored as [], a runtime would read "replace nothing"
    ],
)
def test_bad_job_parameters_are_refused(client, bunny_id, change, status, message):
    before = client.get("/v1/jobs").json()
    spec = {"scene_id": bunny_id, "grid": BUNNY_GRID, "resolution": 256, **change}
    spec = {k: v for k, v in spec.items() if v is not None}
    response = client.post("/v1/jobs", json=spec)
    assert response.status_code == status, response.text
    assert message in response.text
    assert client.get("/v1/jobs").json() == before


def test_unknown_ids_are_404(client):
    for path in ("/v1/scenes/nope", "/v1/jobs/nope", "/v1/jobs/nope/cells/0/bundle.zip", "/v1/jobs/nope/database.zip"):
        assert client.get(path).status_code == 404, path
    bogus = client.get("/v1/jobs", params={"state": "bogus"})
    assert (
        bogus.status_code == 422
        and bogus.json()["error"] == "QueryError"
        and "unknown job state 'bogus'" in bogus.json()["detail"]
    )
    assert client.get("/v1/jobs", params={"limit": 0}).status_code == 422


def test_auth(service, client, bunny_id):
    with service.client(key=None) as anonymous:
        assert anonymous.get("/v1/scenes").status_code == 401
        assert anonymous.post("/v1/scenes", files={"file": ("x.ply", b"x")}).status_code == 401
        assert anonymous.get("/v1/health").status_code == 200
    with service.client(key="ff_bogus_key") as bogus:
        assert bogus.get("/v1/scenes").status_code == 401
    made = service.cli("keys", "create", "--tenant", "other", "--json")
    assert made.returncode == 0, made.stderr
    other_key = json.loads(made.stdout)
    with service.client(key=other_key["key"]) as other:
        assert other.get("/v1/scenes").json() == []
        assert other.get(f"/v1/scenes/{bunny_id}").status_code == 404
        assert other.get(f"/v1/scenes/{bunny_id}/objects").status_code == 404
        jobs = client.get("/v1/jobs").json()
        if jobs:
            assert other.get(f"/v1/jobs/{jobs[0]['id']}").status_code == 404
        assert other.post("/v1/jobs", json={"scene_id": bunny_id, "grid": BUNNY_GRID}).status_code == 404
        revoked = service.cli("keys", "revoke", other_key["prefix"])
        assert revoked.returncode == 0, revoked.stderr
        assert other.get("/v1/scenes").status_code == 401
    unknown = service.cli("keys", "revoke", "nosuchprefix")
    assert (
        unknown.returncode == 3 and unknown.stderr.strip() == "farfield: error: no API key with prefix 'nosuchprefix'"
    )


def test_cancel_stops_the_job(client, bunny_id):
    grid = {"lo": [-0.6, 0.05, -0.05], "hi": [-0.4, 0.15, 0.05], "counts": [4, 4, 1]}
    job_id = client.post("/v1/jobs", json={"scene_id": bunny_id, "grid": grid, "resolution": 512}).json()["id"]
    wait_for_job(client, job_id, states=("running",), timeout=120)
    cancelled = client.post(f"/v1/jobs/{job_id}/cancel")
    assert cancelled.status_code == 200 and cancelled.json()["state"] == "cancelled"
    time.sleep(3)  # a running cell stops at its next layer
    job = client.get(f"/v1/jobs/{job_id}").json()
    assert job["state"] == "cancelled"
    assert job["counts"]["queued"] == 0 and job["counts"]["running"] == 0
    assert job["counts"]["cancelled"] >= 10
    assert job["progress"] == job["counts"]["done"] / job["cells_total"] < 1  # what was carried out, not 100 %
    done = job["counts"]["done"]
    time.sleep(2)
    assert client.get(f"/v1/jobs/{job_id}").json()["counts"]["done"] == done  # no cell started after the cancel
    assert client.post(f"/v1/jobs/{job_id}/cancel").status_code == 409
    for path, what in (
        ("index.json", "impostor database index"),
        ("database.zip", "impostor database"),
    ):  # never written: not "when it ends"
        missing = client.get(f"/v1/jobs/{job_id}/{path}")
        assert (
            missing.status_code == 409
            and missing.json()["detail"] == f"job {job_id!r} is cancelled; it ended without an {what}"
        ), missing.text


def test_worker_killed_mid_cell_loses_nothing(service, client, bunny_id):
    """SIGKILL the pool process while it renders: the cell is delivered again, the job completes, and
    every cell has exactly one impostor."""
    grid = {"lo": [-0.6, 0.05, -0.05], "hi": [-0.4, 0.15, 0.05], "counts": [3, 1, 1]}
    job_id = client.post("/v1/jobs", json={"scene_id": bunny_id, "grid": grid, "resolution": 1024}).json()["id"]
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        job = client.get(f"/v1/jobs/{job_id}").json()
        if any(c["state"] == "running" and c["progress"] > 0 for c in job["cells"]):
            break
        time.sleep(0.05)
    victim = next(c["index"] for c in job["cells"] if c["state"] == "running")
    victims = service.worker_pool_children()
    assert victims, "no celery pool process found"
    for pid in victims:
        os.kill(pid, signal.SIGKILL)
    # Shown at once: the worker's main process queues the cell again (it showed running, attempt 1,
    # until its message came back behind the other cells).
    seen = poll_cell(
        client, job_id, victim, lambda c: c["state"] == "queued" and "worker process died" in (c["error"] or ""), 30
    )
    assert seen["attempts"] == 1, seen
    job = wait_for_job(client, job_id, timeout=300)
    assert job["state"] == "done", job["errors"]
    assert job["counts"]["done"] == 3
    assert max(c["attempts"] for c in job["cells"]) >= 2  # the killed cell ran again
    served = [client.get(f"/v1/jobs/{job_id}/cells/{c['index']}/manifest.json").json() for c in job["cells"]]
    assert [m["viewcell"] for m in served] == [c["viewcell"] for c in job["cells"]]
    # One stored impostor per cell of this job, however often its cell was delivered.
    stored = [json.loads(m.read_text()) for m in (service.home / "blobs" / "impostors").glob("*/manifest.json")]
    ours = [m for m in stored if m["resolution"] == 1024]
    assert sorted(json.dumps(m["viewcell"], sort_keys=True) for m in ours) == sorted(
        json.dumps(c["viewcell"], sort_keys=True) for c in job["cells"]
    )


def poll_cell(client, job_id: str, index: int, condition, timeout: float) -> dict:
    """The cell's record once ``condition`` holds (polled every 20 ms, so a short-lived state is seen)."""
    deadline = time.monotonic() + timeout
    while True:
        cell = client.get(f"/v1/jobs/{job_id}").json()["cells"][index]
        if condition(cell):
            return cell
        assert time.monotonic() < deadline, cell
        time.sleep(0.02)


def test_a_dead_worker_s_cell_is_queued_again_at_once(service, client, bunny_id):
    """SIGKILL a worker's main process mid-cell: farfield up restarts it and queues its cell again at
    once (the message would come back only after the visibility timeout, an hour), and the job ends."""
    grid = {"lo": [-0.6, 0.05, -0.05], "hi": [-0.4, 0.15, 0.05], "counts": [2, 1, 1]}
    job_id = client.post("/v1/jobs", json={"scene_id": bunny_id, "grid": grid, "resolution": 1024}).json()["id"]
    deadline = time.monotonic() + 120
    while True:
        job = client.get(f"/v1/jobs/{job_id}").json()
        running = [c for c in job["cells"] if c["state"] == "running" and c["progress"] > 0]
        if running:
            break
        assert time.monotonic() < deadline, job["counts"]
        time.sleep(0.05)
    (main,) = service.worker_mains()
    os.kill(main, signal.SIGKILL)
    seen = poll_cell(client, job_id, running[0]["index"], lambda c: c["state"] != "running" or c["attempts"] > 1, 30)
    assert seen["state"] in ("queued", "running") and seen["attempts"] in (1, 2), seen
    if seen["state"] == "queued":
        assert "exited with code -9" in seen["error"], seen
    job = wait_for_job(client, job_id, timeout=240)
    assert job["state"] == "done", job["errors"]
    assert job["cells"][running[0]["index"]]["attempts"] == 2


def test_the_api_is_started_again_when_it_dies_and_nothing_else_stops(service, client):
    """Issue 59, item 5: the supervisor raised when the API process died and stopped Redis and the
    workers with it.  Now it starts the API again on its port, within seconds; the rest runs on."""
    import httpx

    old, redis, workers = service.api_pid(), service.redis_pid(), sorted(service.worker_mains())
    os.kill(old, signal.SIGKILL)
    killed = time.monotonic()
    back = None
    while time.monotonic() < killed + 30 and back is None:
        try:
            if service.api_pid() != old and client.get("/v1/health").status_code == 200:
                back = time.monotonic() - killed
        except (StopIteration, httpx.HTTPError):
            pass
        time.sleep(0.1)
    assert back is not None and back < 10.0, back
    assert service.process.poll() is None
    assert service.redis_pid() == redis and sorted(service.worker_mains()) == workers
    assert client.get("/v1/scenes").status_code == 200


def test_redis_restart_during_a_job(service, client, bunny_id):
    grid = {"lo": [-0.6, 0.05, -0.05], "hi": [-0.4, 0.15, 0.05], "counts": [3, 2, 1]}
    job_id = client.post("/v1/jobs", json={"scene_id": bunny_id, "grid": grid, "resolution": 384}).json()["id"]
    wait_for_job(client, job_id, states=("running",), timeout=120)
    old = service.redis_pid()
    os.kill(old, signal.SIGTERM)  # a clean restart: the append-only file keeps the queue
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        try:
            if service.redis_pid() != old:
                break
        except StopIteration:
            pass
        time.sleep(0.1)
    job = wait_for_job(client, job_id, timeout=300)
    assert job["state"] == "done", job["errors"]
    assert job["counts"]["done"] == 6


def test_cli_submit_waits_and_downloads(service, tmp_path):
    env_args = ("--url", service.url, "--key", service.env["FARFIELD_ADMIN_KEY"])
    grid = ",".join(str(v) for v in [*BUNNY_GRID["lo"], *BUNNY_GRID["hi"], *BUNNY_GRID["counts"]])
    done = service.cli(
        "submit",
        str(BUNNY),
        "--grid",
        grid,
        "--resolution",
        "256",
        "--wait",
        "--download",
        str(tmp_path / "db"),
        "--json",
        *env_args,
    )
    assert done.returncode == 0, done.stderr
    job = json.loads(done.stdout)
    assert job["state"] == "done" and job["counts"]["done"] == 4
    index = json.loads((tmp_path / "db" / "index.json").read_text())
    assert [c["state"] for c in index["cells"]] == ["done"] * 4
    for cell in index["cells"]:
        assert (tmp_path / "db" / cell["bundle"] / "manifest.json").is_file()
        assert (tmp_path / "db" / cell["bundle"] / "atlas-000.png").is_file()
    listed = service.cli("jobs", "--json", *env_args)
    assert job["id"] in [j["id"] for j in json.loads(listed.stdout)]
    bad = service.cli("submit", job["scene_id"], "--grid", grid, "--resolution", "0", *env_args)
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1 and "resolution" in bad.stderr
    scenes = service.cli("scenes", "--json", *env_args).stdout
    for args, named in ((("--grid", "nan," + grid.split(",", 1)[1]), "grid.lo[0] is nan"), (("--grid", grid, "--fov", "inf"), "fov_deg is inf"),
                        (("--placement", "--view-space", "0,0,0,1,1,1", "--frame-ms", "nan"), "placement.budget.frame_ms is nan")):  # fmt: skip
        refused = service.cli("submit", str(BUNNY), *args, *env_args)  # JSON carries no NaN: one line, and no upload
        assert refused.returncode == 2 and refused.stderr.strip().splitlines() == [
            f"farfield: error: {named}: the service takes finite numbers only"
        ], refused.stderr
    assert service.cli("scenes", "--json", *env_args).stdout == scenes
    nobody = service.cli("jobs", "--url", service.url, "--key", "ff_wrong_key")
    assert nobody.returncode == 6 and "invalid API key" in nobody.stderr


def test_failing_cell_is_retried_then_failed_and_a_retry_completes_it(service, client, tmp_path):
    """A cell whose scene cannot be read (its blob replaced by a directory: IsADirectoryError, not
    bad input) is attempted FARFIELD_MAX_ATTEMPTS (3) times with backoff, then failed with its
    error; POST retry after the blob is back completes the job."""
    path = tmp_path / "crate.stl"
    trimesh.creation.box(extents=(1.0, 1.0, 1.0)).export(path)
    scene = upload(client, path).json()
    blob = service.home / "blobs" / "scenes" / scene["id"] / "crate.stl"
    saved = blob.read_bytes()
    blob.unlink()
    blob.mkdir()
    cell = {"kind": "box", "lo": [-4.0, -0.5, -0.5], "hi": [-3.0, 0.5, 0.5]}
    job_id = client.post("/v1/jobs", json={"scene_id": scene["id"], "viewcells": [cell], "resolution": 64}).json()["id"]
    job = wait_for_job(client, job_id, timeout=120)
    assert job["state"] == "failed"
    assert job["cells"][0]["attempts"] == 3 and "IsADirectoryError" in job["cells"][0]["error"]
    assert client.post(f"/v1/jobs/{job_id}/cancel").status_code == 409
    blob.rmdir()
    blob.write_bytes(saved)
    retried = client.post(f"/v1/jobs/{job_id}/retry")
    assert retried.status_code == 200, retried.text
    job = wait_for_job(client, job_id, timeout=120)
    assert job["state"] == "done" and job["cells"][0]["attempts"] == 1 and job["has_index"]
    assert client.post(f"/v1/jobs/{job_id}/retry").status_code == 409


def test_farfield_worker_joins_the_service(service, client, bunny_id, tmp_path):
    """A worker started with `farfield worker` on the service's Redis, database and blobs takes cells
    (cells record the worker that ran them)."""
    env = {**service.env, "REDIS_URL": service.broker}
    log = tmp_path / "joined.log"
    with open(log, "wb") as out:
        extra = subprocess.Popen(
            [sys.executable, "-m", "farfield.cli.main", "worker", "--name", "joined"],
            cwd=ROOT,
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
        )
    try:
        deadline = time.monotonic() + 60
        while b" ready." not in log.read_bytes():
            assert extra.poll() is None and time.monotonic() < deadline, log.read_text()
            time.sleep(0.1)
        grid = {**BUNNY_GRID, "counts": [4, 2, 1]}
        job_id = client.post("/v1/jobs", json={"scene_id": bunny_id, "grid": grid, "resolution": 192}).json()["id"]
        job = wait_for_job(client, job_id, timeout=120)
        assert job["state"] == "done", job["errors"]
        workers = {cell["worker"].split("@")[0] for cell in job["cells"]}
        assert "joined" in workers and "worker0" in workers, workers
    finally:
        extra.terminate()
        extra.wait(60)


def test_a_cell_that_keeps_killing_its_worker_fails_after_the_attempt_limit(service, client, bunny_id):
    """Each delivery's pool process is SIGKILLed mid-cell: after FARFIELD_MAX_ATTEMPTS (3) attempts the
    next delivery fails the cell instead of running it forever, and the job ends."""
    grid = {**BUNNY_GRID, "counts": [1, 1, 1]}
    job_id = client.post("/v1/jobs", json={"scene_id": bunny_id, "grid": grid, "resolution": 1536}).json()["id"]
    for attempt in (1, 2, 3):
        deadline = time.monotonic() + 120
        while True:
            cell = client.get(f"/v1/jobs/{job_id}").json()["cells"][0]
            if cell["state"] == "running" and cell["attempts"] == attempt and cell["progress"] > 0:
                break
            assert cell["state"] in ("queued", "running") and time.monotonic() < deadline, cell
            time.sleep(0.05)
        for pid in service.worker_pool_children():
            os.kill(pid, signal.SIGKILL)
    job = wait_for_job(client, job_id, timeout=120)
    assert job["state"] == "failed"
    assert job["cells"][0]["attempts"] == 3 and "never reported back" in job["cells"][0]["error"]


def test_bodies_are_bounded_as_they_arrive(service, client):
    """A chunked body (no Content-Length) over the limit is cut off with 413, and an upload with a
    wrong key is refused before it is read."""

    def chunks(total: int):
        for _ in range(total // 2**20):
            yield b"\0" * 2**20

    boundary = "farfieldboundary"

    def multipart(total: int):
        yield f'--{boundary}\r\nContent-Disposition: form-data; name="file"; filename="big.stl"\r\n\r\n'.encode()
        yield from chunks(total)
        yield f"\r\n--{boundary}--\r\n".encode()

    before = blob_files(service)
    headers = {"content-type": f"multipart/form-data; boundary={boundary}"}
    response = client.post("/v1/scenes", content=multipart(8 * 2**20), headers=headers)
    assert response.status_code == 413, response.text
    with service.client(key="ff_wrong_key") as stranger:
        response = stranger.post("/v1/scenes", content=multipart(8 * 2**20), headers=headers)
        assert response.status_code == 401
    response = client.post("/v1/jobs", content=chunks(16 * 2**20), headers={"content-type": "application/json"})
    assert response.status_code == 413
    assert blob_files(service) == before
    assert client.get("/v1/health").json()["status"] == "ok"


@pytest.mark.service
def test_farfield_up_takes_host_and_port_flags_over_the_environment(tmp_path):
    import socket

    import httpx
    from service_harness import start_service

    with socket.socket() as probe:  # a port free now
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    running = start_service(
        tmp_path / "home", "--host", "127.0.0.1", "--port", str(port), "--workers", "1"
    )  # FARFIELD_PORT=0 in its environment
    try:
        assert running.url == f"http://127.0.0.1:{port}"
        assert httpx.get(f"{running.url}/v1/health", timeout=10).status_code == 200
    finally:
        assert running.stop() == 0
    bad = subprocess.run(
        [sys.executable, "-m", "farfield.cli.main", "up", "--port", "70000"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert bad.returncode == 2 and "70000 is not in the range 0<=x<=65535" in bad.stderr
