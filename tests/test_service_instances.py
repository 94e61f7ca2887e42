"""A job of an instance bakes its prototype once (issue 56, item 1): the jobs of three instances of
one mesh (three ``EXT_mesh_gpu_instancing`` instances, turned and scaled) bake one octahedral
impostor between them; each instance's bundle is the prototype's moved to it.  A real SQLite database and blob folder; cells run as a
worker runs them (``run_cell``), baking for real."""

from __future__ import annotations

import io
import json

import numpy as np
from gltf_files import instanced_scene

from farfield.core.exchange import load_scene
from farfield.core.impostor.bundle import MANIFEST_NAME
from farfield.service.blobs import LocalBlobStore
from farfield.service.db import CellRow, Database
from farfield.service.jobs.admission import create_job
from farfield.service.jobs.runner import run_cell
from farfield.service.jobs.schema import JobSpec
from farfield.service.keys import tenant_named
from farfield.service.scenes import ingest_scene


def test_the_instances_of_one_mesh_bake_one_impostor(tmp_path):
    db = Database(f"sqlite:///{tmp_path / 'farfield.db'}")
    db.migrate()
    blobs = LocalBlobStore(tmp_path / "blobs")
    path = instanced_scene(tmp_path / "boxes.glb", count=3, texture=False)
    local = load_scene(path)
    by_name = {obj.name: obj for obj in local.objects}
    tenant = tenant_named(db, "alice").id
    stored = ingest_scene(db, blobs, tenant, "boxes.glb", io.BytesIO(path.read_bytes()), limit=2**22)
    cells = []
    for i in range(3):
        m = by_name[f"box@{i}"].instance_matrix
        cell = {"kind": "outside-sphere", "centre": m[:3, 3].tolist(), "radius": 2.0 * float(np.linalg.norm(m[:3, 0]))}
        spec = JobSpec(scene_id=stored.id, technique="octahedral", viewcells=[cell], objects=[f"box@{i}"],
                       options={"grid": 5, "frame_resolution": 16, "padding": 1}, resolution=64, evaluate=False)  # fmt: skip
        job = create_job(db, tenant, stored, spec)
        with db.session() as s:
            cell_id = s.query(CellRow.id).filter(CellRow.job_id == job.id).scalar()
        assert run_cell(db, blobs, cell_id, 3) == "done"
        with db.session() as s:
            cells.append(s.get(CellRow, cell_id))
    assert [c.stats["baked"] for c in cells] == [True, False, False]  # one bake for three instances
    assert len({c.stats["prototype"] for c in cells}) == 1
    assert len({c.result_key for c in cells}) == 3  # each instance's bundle is its own, in world space
    manifests = [json.loads(p.read_text()) for p in (tmp_path / "blobs" / "impostors").glob(f"*/{MANIFEST_NAME}")]
    prototypes = [m for m in manifests if "instance_matrix" not in m["parameters"]]
    assert len(manifests) == 4 and len(prototypes) == 1  # one prototype bake, three moved bundles
