"""Cost admission (issue 24): a job is planned when it is created, and refused beyond the limits on
texels per cell and per job (413) and on open cells per tenant (429), with nothing stored.

The API app runs in-process on a real SQLite database and blob folder, with a scene uploaded through
the route; no broker is needed, since every job sent through the API here is refused.  Jobs that
pass are created with :func:`farfield.service.jobs.admission.create_job` on the same database (their cells stay
queued: nothing sends them).
"""

from __future__ import annotations

import contextlib
import os
import re
import time

import numpy as np
import pytest
from fastapi.testclient import TestClient
from scenes import city, write_scene
from service_harness import start_service, upload, wait_for_job

from farfield.api.app import create_app
from farfield.core import procedural
from farfield.service.cell_limits import MemoryGuard, resident_bytes
from farfield.service.db import CellRow, Database, JobRow
from farfield.service.jobs.admission import create_job, open_tenant_cells
from farfield.service.jobs.schema import JobSpec
from farfield.service.keys import authenticate
from farfield.service.scenes import get_scene_row
from farfield.service.settings import AdmissionLimits, Settings

KEY = "ff-test-admission-key-0123456789"
# A 4-unit box cell about 80 units in front of a 3-building city (lots at x, z in 0..40).
CELL = {"kind": "box", "lo": [28.0, 3.0, -80.0], "hi": [32.0, 7.0, -76.0]}


@contextlib.contextmanager
def api_client(home, **limits: str):
    """The API on ``home`` whose environment (and so its settings) holds ``limits``: the limits
    are read from the environment, as every farfield process gets its settings."""
    env = {"FARFIELD_HOME": str(home), "REDIS_URL": "redis://127.0.0.1:1/0", "FARFIELD_ADMIN_KEY": KEY, **limits}
    with pytest.MonkeyPatch.context() as patch:
        for name in [n for n in os.environ if n.startswith("FARFIELD_MAX_")]:
            patch.delenv(name)
        for name, value in env.items():
            patch.setenv(name, value)
        with TestClient(create_app(Settings.from_env()), headers={"Authorization": f"Bearer {KEY}"}) as client:
            yield client


@pytest.fixture(scope="module")
def home(tmp_path_factory):
    """A service home with the city uploaded; yields (home, scene id)."""
    home = tmp_path_factory.mktemp("admission")
    with api_client(home) as client:
        path = write_scene(city(buildings=3), home, "glb")
        response = client.post("/v1/scenes", files={"file": (path.name, path.read_bytes())})
        assert response.status_code == 201, response.text
        return home, response.json()["id"]


def stored(home) -> tuple[int, int]:
    """(jobs, cells) in the database."""
    db = Database(Settings.from_env({"FARFIELD_HOME": str(home)}).database_url)
    with db.session() as s:
        return s.query(JobRow).count(), s.query(CellRow).count()


def create_directly(home, scene_id: str, limits: AdmissionLimits | None = None, **spec) -> JobRow:
    """A job created by the service function, as the API would (no broker: its cells stay queued)."""
    db = Database(Settings.from_env({"FARFIELD_HOME": str(home)}).database_url)
    tenant_id = authenticate(db, KEY)
    scene = get_scene_row(db, tenant_id, scene_id, with_objects=True)
    return create_job(db, tenant_id, scene, JobSpec(scene_id=scene_id, **spec), limits or AdmissionLimits())


@pytest.mark.slow
def test_a_16384_job_is_refused_with_its_estimate(home):
    """The issue's case: one layered cell at 16384 px was accepted and held a worker for about an
    hour.  With the default limits it is refused at once, with the estimate, the limit and the
    variable to raise it; nothing is stored."""
    home, scene_id = home
    before = stored(home)
    with api_client(home) as client:
        response = client.post("/v1/jobs", json={"scene_id": scene_id, "resolution": 16384, "viewcells": [CELL]})
    assert response.status_code == 413, response.text
    answer = response.json()
    assert answer["error"] == "JobTooCostlyError"
    detail = answer["detail"]
    assert (
        detail.startswith("view cell 0 needs more than ") and "texels (at least " in detail and " layers of " in detail
    ), detail
    assert "over the limit of 4e9 per cell (FARFIELD_MAX_CELL_TEXELS)" in detail
    assert stored(home) == before


@pytest.mark.parametrize(
    "technique, resolution, options",
    [("layered", 2048, {}), ("tdm", 2048, {}), ("layered", 512, {}), ("envmap", 2048, {})],
)
def test_documented_sizes_pass_the_default_limits(home, technique, resolution, options):
    """Resolution up to 2048 with default options passes on the default limits: a layered cell here
    plans 130 layers of 2577x3646 (1.2e9 texels), an envmap cell 6 faces x 64 layers of 2048x2048."""
    home, scene_id = home
    cell = CELL if technique != "envmap" else {"kind": "box", "lo": [15.0, 5.0, -45.0], "hi": [25.0, 15.0, -35.0]}
    job = create_directly(home, scene_id, technique=technique, resolution=resolution, viewcells=[cell], options=options)
    assert job.state == "queued"


def test_the_estimate_matches_the_bakes_plan(home):
    """The estimate is the plan the bake uses: 1024 px, 65 layers of 1289x1823 (measured in a bake)."""
    home, scene_id = home
    with api_client(home, FARFIELD_MAX_CELL_TEXELS="1e8") as client:
        response = client.post("/v1/jobs", json={"scene_id": scene_id, "resolution": 1024, "viewcells": [CELL]})
    assert response.status_code == 413
    assert response.json()["detail"].startswith(
        "view cell 0 needs about 1.5e8 texels (65 layers of 1289x1823) over the limit of 1e8 per cell"
    )


def test_a_job_over_the_job_limit_is_refused_and_nothing_stored(home):
    """Cells that pass one by one, but not together."""
    home, scene_id = home
    before = stored(home)
    cells = [
        CELL,
        {**CELL, "lo": [34.0, 3.0, -80.0], "hi": [38.0, 7.0, -76.0]},
        {**CELL, "lo": [22.0, 3.0, -80.0], "hi": [26.0, 7.0, -76.0]},
    ]
    with api_client(home, FARFIELD_MAX_JOB_TEXELS="3e7") as client:  # each cell plans about 1.9e7 texels at 512
        response = client.post("/v1/jobs", json={"scene_id": scene_id, "resolution": 512, "viewcells": cells})
    assert response.status_code == 413, response.text
    assert response.json()["detail"] == (
        "the job is too large: its first 2 of 3 view cells already need about 4e7 texels over the limit of 3e7 per job "
        "(FARFIELD_MAX_JOB_TEXELS): split it into smaller jobs, lower the resolution, or raise the limit"
    )
    assert stored(home) == before


def test_a_tenant_over_its_open_cells_is_refused_with_429(home):
    """Open (queued or running) cells per tenant are capped; the refusal names the count and the limit."""
    home, scene_id = home
    create_directly(
        home, scene_id, resolution=64, grid={"lo": [20.0, 3.0, -80.0], "hi": [36.0, 7.0, -76.0], "counts": [4, 1, 1]}
    )
    db = Database(Settings.from_env({"FARFIELD_HOME": str(home)}).database_url)
    open_cells = open_tenant_cells(db, authenticate(db, KEY))  # queued: nothing sends them
    assert open_cells >= 4
    before = stored(home)
    with api_client(home, FARFIELD_MAX_TENANT_CELLS=str(open_cells + 1)) as client:
        response = client.post("/v1/jobs", json={"scene_id": scene_id, "resolution": 64, "viewcells": [CELL, CELL]})
    assert response.status_code == 429 and response.headers["retry-after"] == "30", response.text
    assert response.json() == {
        "detail": f"tenant has {open_cells:,} cells queued or running; this job's 2 would pass the limit of {open_cells + 1:,} "
        "(FARFIELD_MAX_TENANT_CELLS): wait for some to end, or cancel a job",
        "error": "QuotaError",
    }
    assert stored(home) == before


def test_a_job_over_the_tenant_cap_on_its_own_is_413_not_429(home):
    """A job with more cells than a tenant may ever have open could never pass: a 429 would have a
    client retry it forever."""
    home, scene_id = home
    before = stored(home)
    with api_client(home, FARFIELD_MAX_TENANT_CELLS="2") as client:
        response = client.post(
            "/v1/jobs", json={"scene_id": scene_id, "resolution": 64, "viewcells": [CELL, CELL, CELL]}
        )
    assert response.status_code == 413 and "FARFIELD_MAX_TENANT_CELLS" in response.json()["detail"], response.text
    assert stored(home) == before


def test_a_refused_plan_costs_no_more_than_the_limit(home):
    """Admission stops planning at 8 times the limit: with a limit of 1e7 texels the 4096-px cell
    (260 layers of 5153x7291 when planned in full, 9.8e9 texels) is refused after 3 layers."""
    home, scene_id = home
    with api_client(home, FARFIELD_MAX_CELL_TEXELS="1e7") as client:
        response = client.post("/v1/jobs", json={"scene_id": scene_id, "resolution": 4096, "viewcells": [CELL]})
    assert response.status_code == 413
    assert response.json()["detail"].startswith(
        "view cell 0 needs more than 1.1e8 texels (at least 3 layers of 5141x7259) over the limit of 1e7"
    )


# --- limits per cell on a real worker ------------------------------------------------------------


def limited_job(tmp_path, resolution: int = 512, **env: str) -> dict:
    """One layered cell of the city at ``resolution`` (512 px: 1.9e7 texels, far under the admission
    limits) on a real ``farfield up`` with ``env``; returns the ended job's record."""
    service = start_service(tmp_path / "home", **env)
    try:
        with service.client() as client:
            path = write_scene(city(buildings=3), tmp_path, "glb")
            scene_id = upload(client, path).json()["id"]
            created = client.post(
                "/v1/jobs", json={"scene_id": scene_id, "resolution": resolution, "viewcells": [CELL]}
            )
            assert created.status_code == 201, created.text
            job = wait_for_job(client, created.json()["id"], timeout=180)
            time.sleep(1.0)  # a redelivery after the pool process died must change nothing
            return client.get(f"/v1/jobs/{job['id']}").json()
    finally:
        assert service.stop() == 0


@pytest.mark.service
def test_a_cell_past_its_time_limit_fails_once_with_the_limit_named(tmp_path):
    """Celery's soft time limit ends the attempt as a failed cell naming FARFIELD_CELL_TIME_LIMIT;
    it is bad input, so there is no retry and the job ends failed."""
    # 2048 px: 130 layers of 2577 x 3646 (1.2e9 texels, under the 4e9 cell limit), a bake of 14 s on
    # llvmpipe here; at 512 px it took 0.4 s on a faster machine and sometimes ended within the 1 s.
    job = limited_job(tmp_path, 2048, FARFIELD_CELL_TIME_LIMIT="1")
    cell = job["cells"][0]
    assert job["state"] == "failed" and cell["state"] == "failed", job
    # One attempt, or none where the limit strikes before the pool process claims the cell: never two.
    # (It failed once with two on the loaded 2-core machine: the pool process alone recorded the limit,
    # wherever the signal landed; now the worker's main process fails the cell before it signals,
    # test_the_soft_time_limit_fails_the_cell_from_the_main_process_whatever_the_pool_process_does.)
    assert cell["attempts"] <= 1 and not cell["has_result"], cell
    assert cell["error"].startswith(
        "CellLimitError: the cell ran longer than FARFIELD_CELL_TIME_LIMIT (1 s) and was stopped; not retried"
    )


@pytest.mark.service
def test_a_cell_past_its_memory_limit_fails_once_with_the_limit_named(tmp_path):
    """The pool process's memory guard fails the cell naming FARFIELD_CELL_MEMORY_MB and ends the
    process; the redelivered message finds the cell failed, so there is one attempt and the job
    ends failed.  (64 MiB is below any pool process's resident set: the guard fires at once.)"""
    job = limited_job(tmp_path, FARFIELD_CELL_MEMORY_MB="64")
    cell = job["cells"][0]
    assert job["state"] == "failed" and cell["state"] == "failed", job
    assert cell["attempts"] == 1 and not cell["has_result"]
    assert re.fullmatch(
        r"CellLimitError: the cell's worker process grew to \d+ MiB of memory, over FARFIELD_CELL_MEMORY_MB \(64 MiB\), and was stopped; not retried.*",
        cell["error"],
    ), cell["error"]


@pytest.mark.service
def test_a_placement_s_planning_past_the_memory_limit_fails_the_job_once(tmp_path):
    """Planning runs under the same guard as a cell: past FARFIELD_CELL_MEMORY_MB the job fails
    naming the limit and what to change, and the planning process's redelivery changes nothing.
    (Before the guard covered planning, a request whose planning grew without bound held its worker
    until someone killed it.)"""
    service = start_service(tmp_path / "home", FARFIELD_CELL_MEMORY_MB="64")
    try:
        with service.client() as client:
            # test_service_placement's slow plan (many seconds): the guard, reading every 0.1 s, sees it
            scene_id = upload(
                client, write_scene(procedural.city(25, seed=1, detail=8), tmp_path, "glb", "city")
            ).json()["id"]
            placement = {
                "view_space": {"lo": [10.0, 2.0, 10.0], "hi": [70.0, 6.0, 70.0]},
                "budget": {"primitives": 600},
                "cpv_size": 3,
            }
            created = client.post("/v1/jobs", json={"scene_id": scene_id, "resolution": 64, "placement": placement})
            assert created.status_code == 201, created.text
            job = wait_for_job(client, created.json()["id"], timeout=180)
            time.sleep(1.0)
            job = client.get(f"/v1/jobs/{job['id']}").json()
    finally:
        assert service.stop() == 0
    assert job["state"] == "failed" and job["cells_total"] == 0, job
    assert re.fullmatch(
        r"CellLimitError: the planning's worker process grew to \d+ MiB of memory, over FARFIELD_CELL_MEMORY_MB \(64 MiB\), "
        r"and was stopped; not retried, since planning would need as much again: use a larger cpv_size.*",
        job["error"],
    ), job["error"]


def test_the_memory_guard_fires_on_growth_and_not_below_its_limit():
    """The guard reads this process's real resident set: quiet while it stays under the limit,
    firing once (its action, then the kill) when 256 MiB more are touched."""
    base = resident_bytes()
    fired, killed = [], []
    guard = MemoryGuard(base // 2**20 + 128, interval=0.02, kill=lambda: killed.append(True))
    with guard.armed(fired.append):
        time.sleep(0.2)
        assert not fired and not killed
        block = np.ones(256 * 2**20, dtype=np.uint8)  # touched: resident
        deadline = time.monotonic() + 5
        while not killed and time.monotonic() < deadline:
            time.sleep(0.02)
    assert killed == [True] and len(fired) == 1 and fired[0] > guard.limit_bytes, (fired, guard.limit_bytes)
    del block


def test_the_memory_guard_blames_only_a_process_s_first_cell():
    """Past the limit in a process that ran other cells (whose scenes and freed memory it may still
    hold), the guard ends the process without failing the cell, which then runs on a fresh one."""
    fired, killed = [], []
    guard = MemoryGuard(1, interval=60, kill=lambda: killed.append(True))  # 1 MiB: any process is over it
    with guard.armed(fired.append):
        pass  # an earlier cell, within the limit when it ran
    guard.fired.clear()
    with guard.armed(fired.append):
        assert guard.check()
    assert killed == [True] and fired == []


def test_the_soft_time_limit_fails_the_cell_from_the_main_process_whatever_the_pool_process_does(home):
    """At the soft limit the worker's main process fails the cell before it signals the pool process
    (CellRequest.on_timeout), so where the signal lands no longer decides the outcome: a pool process
    that then records the limit, finishes its bake regardless, or dies, changes nothing (the flaky
    time-limit test above, issue 58: the cell had run a second attempt)."""
    from farfield.service.jobs.cells import claim_cell, end_cell, release_lost_cells
    from farfield.workers import tasks

    home, scene_id = home
    job = create_directly(home, scene_id, resolution=64, viewcells=[CELL])
    db = Database(Settings.from_env({"FARFIELD_HOME": str(home)}).database_url)
    with db.session() as s:
        cell_id = s.query(CellRow.id).filter(CellRow.job_id == job.id).scalar()
    attempt = claim_cell(db, cell_id, 3, "worker0@host").cell
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("FARFIELD_HOME", str(home))
        patch.setenv("FARFIELD_CELL_TIME_LIMIT", "7")
        assert tasks.fail_at_time_limit(cell_id) == "failed"
        blobs = tasks.blob_store(Settings.from_env())
    assert not end_cell(db, cell_id, 1, "done", result="impostors/late", token=attempt.lease_token)  # the bake went on
    assert not end_cell(db, cell_id, 1, "failed", error="late", token=attempt.lease_token)  # the pool recorded it too
    assert release_lost_cells(db, blobs, [cell_id], 3, "its worker process died") == {}  # the pool process died
    assert claim_cell(db, cell_id, 3, "worker0@host").cell is None  # a redelivery
    with db.session() as s:
        cell, ended = s.get(CellRow, cell_id), s.get(JobRow, job.id)
        assert cell.state == "failed" and cell.attempts == 1 and cell.result_key is None and ended.state == "failed"
        assert cell.error.startswith(
            "CellLimitError: the cell ran longer than FARFIELD_CELL_TIME_LIMIT (7 s) and was stopped; not retried"
        )


def test_a_cell_killed_at_the_hard_time_limit_is_failed_by_the_main_process(home):
    """Where the pool process does not stop at the soft limit (a long call into the driver), Celery
    kills it at the hard one and calls the task's on_failure in the worker's main process, which
    fails the cell (it could record nothing itself) and ends the job."""
    from celery.exceptions import TimeLimitExceeded

    from farfield.workers import tasks

    home, scene_id = home
    job = create_directly(home, scene_id, resolution=64, viewcells=[CELL])
    db = Database(Settings.from_env({"FARFIELD_HOME": str(home)}).database_url)
    with db.session() as s:
        cell_id = s.query(CellRow.id).filter(CellRow.job_id == job.id).scalar()
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("FARFIELD_HOME", str(home))
        patch.setattr(tasks, "_STATE", {})
        tasks.bake_cell.on_failure(TimeLimitExceeded(1860), "task-id", [cell_id], {}, None)
    with db.session() as s:
        cell, ended = s.get(CellRow, cell_id), s.get(JobRow, job.id)
        assert cell.state == "failed" and ended.state == "failed"
        assert cell.error.startswith(
            "CellLimitError: the cell ran longer than FARFIELD_CELL_TIME_LIMIT and did not stop, so its worker process was killed at the hard limit (1860 s)"
        )
