"""Tenant quotas hold under concurrency, for every job kind (issue 59, item 6): jobs created at the
same moment by many threads never leave a tenant past ``FARFIELD_MAX_TENANT_CELLS``, and placement
jobs count against ``FARFIELD_MAX_TENANT_PLACEMENTS`` (they skipped every quota).  Real databases:
SQLite, and PostgreSQL where ``FARFIELD_TEST_DATABASE_URL`` names a server."""

from __future__ import annotations

import io
import os
import threading

import pytest
import trimesh

from farfield.core.errors import QuotaError
from farfield.service.blobs import LocalBlobStore
from farfield.service.db import CellRow, Database, JobRow
from farfield.service.jobs.admission import create_job
from farfield.service.jobs.schema import JobSpec
from farfield.service.keys import tenant_named
from farfield.service.scenes import ingest_scene
from farfield.service.settings import AdmissionLimits

CELL = {"kind": "box", "lo": [-4.0, -0.5, -0.5], "hi": [-3.0, 0.5, 0.5]}
PLACEMENT = {"view_space": {"lo": [-6.0, 0.0, -6.0], "hi": [6.0, 1.0, 6.0]}, "budget": {"primitives": 100.0}}


@pytest.fixture(params=["sqlite", "postgresql"])
def stack(request, tmp_path):
    drop = None
    url = f"sqlite:///{tmp_path / 'farfield.db'}"
    if request.param == "postgresql":
        from service_harness import fresh_postgres_database

        admin_url = os.environ.get("FARFIELD_TEST_DATABASE_URL")
        if not admin_url:
            pytest.skip(
                "no PostgreSQL server: set FARFIELD_TEST_DATABASE_URL (CI starts one with scripts/postgres-server)"
            )
        url, drop = fresh_postgres_database(admin_url)
    db = Database(url)
    db.migrate()
    blobs = LocalBlobStore(tmp_path / "blobs")
    tenant = tenant_named(db, "quota")
    data = io.BytesIO(trimesh.creation.box(extents=(1.0, 1.0, 1.0)).export(file_type="stl"))
    scene = ingest_scene(db, blobs, tenant.id, "crate.stl", data, limit=2**20)
    try:
        yield db, tenant.id, scene
    finally:
        db.engine.dispose()
        if drop is not None:
            drop()


def at_once(count: int, submit) -> list:
    """``submit()`` from ``count`` threads released together; each one's job or QuotaError."""
    barrier = threading.Barrier(count)
    results = [None] * count

    def run(k: int) -> None:
        barrier.wait()
        try:
            results[k] = submit()
        except QuotaError as error:
            results[k] = error

    threads = [threading.Thread(target=run, args=(k,)) for k in range(count)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    return results


def test_simultaneous_jobs_never_pass_the_tenant_cell_quota(stack):
    """Eight jobs of three cells each at once, a quota of seven cells: two pass, six are 429s.  The
    count was read without a lock, so parallel requests all passed it."""
    db, tenant_id, scene = stack
    limits = AdmissionLimits(max_tenant_cells=7)
    spec = JobSpec(scene_id=scene.id, viewcells=[CELL] * 3, resolution=16)
    results = at_once(8, lambda: create_job(db, tenant_id, scene, spec, limits))
    passed = [r for r in results if isinstance(r, JobRow)]
    refused = [r for r in results if isinstance(r, QuotaError)]
    assert len(passed) == 2 and len(refused) == 6, results
    assert "FARFIELD_MAX_TENANT_CELLS" in str(refused[0])
    with db.session() as s:
        assert s.query(CellRow).count() == 6 and s.query(JobRow).count() == 2  # nothing of the refused


def test_placement_jobs_count_against_their_own_quota(stack):
    """Placement jobs were stored whatever the tenant had open (30 in 2 s in the campaign)."""
    db, tenant_id, scene = stack
    limits = AdmissionLimits(max_tenant_placements=2)
    spec = JobSpec(scene_id=scene.id, placement=PLACEMENT, resolution=16)
    results = at_once(6, lambda: create_job(db, tenant_id, scene, spec, limits))
    passed = [r for r in results if isinstance(r, JobRow)]
    refused = [r for r in results if isinstance(r, QuotaError)]
    assert len(passed) == 2 and len(refused) == 4, results
    assert "FARFIELD_MAX_TENANT_PLACEMENTS=2" in str(refused[0])
    with db.session() as s:
        s.query(JobRow).filter(JobRow.id == passed[0].id).update({"state": "done"})
    assert isinstance(create_job(db, tenant_id, scene, spec, limits), JobRow)  # one ended: room for one more


def test_retrying_a_failed_job_counts_against_the_cell_quota(stack):
    """A retry queued the failed cells again whatever the tenant had open."""
    from farfield.service.jobs.cells import retry_job

    db, tenant_id, scene = stack
    limits = AdmissionLimits(max_tenant_cells=4)
    spec = JobSpec(scene_id=scene.id, viewcells=[CELL] * 3, resolution=16)
    failed = create_job(db, tenant_id, scene, spec, limits)
    with db.session() as s:
        s.query(CellRow).filter(CellRow.job_id == failed.id).update({"state": "failed"})
        s.query(JobRow).filter(JobRow.id == failed.id).update({"state": "failed"})
    create_job(db, tenant_id, scene, spec, limits)  # 3 open cells: a retry of 3 more would make 6
    with pytest.raises(QuotaError, match="FARFIELD_MAX_TENANT_CELLS"):
        retry_job(db, tenant_id, failed.id, limits)
    with db.session() as s:  # nothing changed
        assert s.get(JobRow, failed.id).state == "failed"
        assert {c.state for c in s.query(CellRow).filter(CellRow.job_id == failed.id)} == {"failed"}
