"""Results are shared within a tenant only (issue 59, item 9): a tenant submitting the same content
with the same parameters as another tenant bakes its own bundle (``stats.baked`` true), so it cannot
learn that someone else baked that content; within a tenant the bundle is still found.  A real
SQLite database and blob folder; cells run as a worker runs them (``run_cell``), baking for real."""

from __future__ import annotations

import io

import trimesh

from farfield.service.blobs import LocalBlobStore
from farfield.service.db import CellRow, Database
from farfield.service.jobs.admission import create_job
from farfield.service.jobs.runner import run_cell
from farfield.service.jobs.schema import JobSpec
from farfield.service.keys import tenant_named
from farfield.service.scenes import ingest_scene

CELL = {"kind": "box", "lo": [-4.0, -0.5, -0.5], "hi": [-3.0, 0.5, 0.5]}


def test_a_tenant_never_finds_another_tenants_bundle(tmp_path):
    db = Database(f"sqlite:///{tmp_path / 'farfield.db'}")
    db.migrate()
    blobs = LocalBlobStore(tmp_path / "blobs")
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0)).export(file_type="stl")

    def bake(tenant_id: str) -> CellRow:
        scene = ingest_scene(db, blobs, tenant_id, "crate.stl", io.BytesIO(box), limit=2**20)
        job = create_job(db, tenant_id, scene, JobSpec(scene_id=scene.id, viewcells=[CELL], resolution=16))
        with db.session() as s:
            cell_id = s.query(CellRow.id).filter(CellRow.job_id == job.id).scalar()
        assert run_cell(db, blobs, cell_id, 3) == "done"
        with db.session() as s:
            return s.get(CellRow, cell_id)

    alice, bob = tenant_named(db, "alice").id, tenant_named(db, "bob").id
    first = bake(alice)
    theirs = bake(bob)  # the same bytes, parameters and cell as alice's
    again = bake(alice)
    assert first.stats["baked"] is True
    assert theirs.stats["baked"] is True and theirs.result_key != first.result_key
    assert again.stats["baked"] is False and again.result_key == first.result_key
