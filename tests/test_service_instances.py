"""A job of an instance bakes its prototype once, and its bundle stores the prototype's pages once
(issue 56, item 1): the jobs of several instances of one mesh (``EXT_mesh_gpu_instancing``
instances, turned and scaled) bake one octahedral impostor between them; each instance's bundle is
the prototype's moved to it, served byte for byte as it was when every instance stored it whole.
A real SQLite database and blob folder; cells run as a worker runs them (``run_cell``), baking for
real; the results are read through the REST routes."""

from __future__ import annotations

import io
import json
import re
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from gltf_files import instanced_scene

from farfield.core.impostor.bundle import GLB_NAME, MANIFEST_NAME, bundle_zip, read_bundle, write_bundle
from farfield.core.impostor.glb import impostor_glb
from farfield.core.techniques import get_technique
from farfield.core.techniques.instances import instance_part
from farfield.service.blobs import LocalBlobStore
from farfield.service.db import CellRow, Database
from farfield.service.jobs.admission import create_job
from farfield.service.jobs.admitting import admit_job
from farfield.service.jobs.instances import prototype_prefix, read_cell_impostor
from farfield.service.jobs.runner import run_cell
from farfield.service.jobs.schema import JobSpec
from farfield.service.keys import ADMIN_TENANT, tenant_named
from farfield.service.scenes import ingest_scene, load_stored_scene
from farfield.service.settings import AdmissionLimits

KEY = "ff-test-instances-key-0123456789"
PAGE = re.compile(r"[a-z]+-\d{3}\.png")


def _instance_job(db, blobs, tenant: str, stored, scene, i: int) -> CellRow:
    """Run the one-cell job of instance ``box@i`` of ``stored`` (a cell outside twice its radius)."""
    m = next(obj for obj in scene.objects if obj.name == f"box@{i}").instance_matrix
    cell = {"kind": "outside-sphere", "centre": m[:3, 3].tolist(), "radius": 2.0 * float(np.linalg.norm(m[:3, 0]))}
    spec = JobSpec(scene_id=stored.id, technique="octahedral", viewcells=[cell], objects=[f"box@{i}"],
                   options={"grid": 5, "frame_resolution": 16, "padding": 1}, resolution=64, evaluate=False)  # fmt: skip
    job = create_job(db, tenant, stored, spec)
    _, (cell_id,) = admit_job(db, blobs, job.id, "test-worker@here", 3, AdmissionLimits())
    assert run_cell(db, blobs, cell_id, 3) == "done"
    with db.session() as s:
        return s.get(CellRow, cell_id)


def test_the_instances_of_one_mesh_bake_one_impostor(tmp_path):
    db = Database(f"sqlite:///{tmp_path / 'farfield.db'}")
    db.migrate()
    blobs = LocalBlobStore(tmp_path / "blobs")
    path = instanced_scene(tmp_path / "boxes.glb", count=3, texture=False)
    tenant = tenant_named(db, "alice").id
    stored = ingest_scene(db, blobs, tenant, "boxes.glb", io.BytesIO(path.read_bytes()), limit=2**22)
    scene = load_stored_scene(blobs, stored)
    cells = [_instance_job(db, blobs, tenant, stored, scene, i) for i in range(3)]
    assert [c.stats["baked"] for c in cells] == [True, False, False]  # one bake for three instances
    assert len({c.stats["prototype"] for c in cells}) == 1
    assert len({c.result_key for c in cells}) == 3  # each instance's bundle is its own, in world space
    manifests = [json.loads(p.read_text()) for p in (tmp_path / "blobs" / "impostors").glob(f"*/{MANIFEST_NAME}")]
    prototypes = [m for m in manifests if "instance_matrix" not in m["parameters"]]
    assert len(manifests) == 4 and len(prototypes) == 1  # one prototype bake, three moved bundles


def _whole_bundle(blobs, prototype: str, scene, i: int, folder: Path) -> Path:
    """The bundle the service stored for instance ``box@i`` before instances shared their pages:
    the prototype's impostor moved by the instance's matrix, written whole."""
    technique = get_technique("octahedral")
    impostor = read_bundle(blobs.copy_to_directory(prototype, folder / "prototype"))
    _, matrix, objects = instance_part(scene, [f"box@{i}"])
    moved = technique.instancing.moved(impostor, matrix, list(objects), scene.content_hash)
    write_bundle(moved, folder / f"whole-{i}")
    return folder / f"whole-{i}"


def _stored(root: Path) -> dict[str, int]:
    """Bytes stored per kind of file under ``root`` (pages, GLBs, the rest)."""
    sizes = {"pages": 0, "glb": 0, "other": 0}
    for file in root.rglob("*"):
        if file.is_file():
            kind = "pages" if PAGE.fullmatch(file.name) else "glb" if file.name == GLB_NAME else "other"
            sizes[kind] += file.stat().st_size
    return sizes


@pytest.fixture(scope="module")
def api(tmp_path_factory):
    from farfield.api.app import create_app
    from farfield.service.settings import Settings

    home = tmp_path_factory.mktemp("instances")
    settings = Settings.from_env(
        {"FARFIELD_HOME": str(home), "REDIS_URL": "redis://127.0.0.1:1/0", "FARFIELD_ADMIN_KEY": KEY}
    )
    with TestClient(create_app(settings), headers={"Authorization": f"Bearer {KEY}"}) as client:
        yield client


def test_instances_store_their_prototypes_pages_once_and_serve_the_same_bytes(api, tmp_path):
    svc = api.app.state.services
    db, blobs = svc.db, svc.blobs
    tenant = tenant_named(db, ADMIN_TENANT).id
    count = 6
    path = instanced_scene(tmp_path / "boxes.glb", count=count)
    stored = ingest_scene(db, blobs, tenant, "boxes.glb", io.BytesIO(path.read_bytes()), limit=2**22)
    scene = load_stored_scene(blobs, stored)
    cells = [_instance_job(db, blobs, tenant, stored, scene, i) for i in range(count)]
    assert [c.stats["baked"] for c in cells] == [True] + [False] * (count - 1)
    prototype = prototype_prefix(blobs, cells[0].result_key)
    assert prototype is not None and {prototype_prefix(blobs, c.result_key) for c in cells} == {prototype}

    # Stored: the pages and the GLB once (the prototype's), each instance its manifest and payload.
    root = Path(blobs.root) / "impostors"
    pages = sorted(p.name for p in root.glob("*/*.png"))
    assert pages and len(pages) == len(set(pages))  # every page file once: the old code stored count + 1 copies
    assert len(list(root.glob(f"*/{GLB_NAME}"))) == 1
    now = _stored(root)
    wholes = [_whole_bundle(blobs, prototype, scene, i, tmp_path) for i in range(count)]
    before = _stored(Path(blobs.path(prototype)))
    for whole in wholes:
        for kind, size in _stored(whole).items():
            before[kind] += size
    assert now["pages"] * (count + 1) == before["pages"] and now["glb"] * 2 < before["glb"]
    print(f"\n{count} instances: stored {sum(now.values())} bytes (pages {now['pages']}, GLB {now['glb']}), "
          f"whole bundles {sum(before.values())} bytes (pages {before['pages']}, GLB {before['glb']})")  # fmt: skip

    # Every reader gets the bytes of the whole bundle.
    for i, (cell, whole) in enumerate(zip(cells, wholes, strict=True)):
        base = f"/v1/jobs/{cell.job_id}/cells/0"
        for route, name in (("impostor.glb", GLB_NAME), ("manifest.json", MANIFEST_NAME), ("payload.bin", "payload.bin"),
                            ("atlas/0.png", "atlas-000.png")):  # fmt: skip
            response = api.get(f"{base}/{route}")
            assert response.status_code == 200, response.text
            assert response.content == (whole / name).read_bytes(), (i, route)
        assert api.get(f"{base}/bundle.zip").content == bundle_zip(whole)
        missing = api.get(f"{base}/atlas/9.png")  # named by page, not by the blob store's key
        assert missing.status_code == 404 and missing.json()["detail"] == (
            f"cell 0 of job {cell.job_id!r} has no atlas page 9; it has 1 (page 0)"
        ), missing.text
        read = read_cell_impostor(blobs, cell.result_key, tmp_path / f"read-{i}")  # what the evaluation reads
        assert impostor_glb(read) == (whole / GLB_NAME).read_bytes()
        response = api.get(f"/v1/jobs/{cell.job_id}/database.zip")
        assert response.status_code == 200, response.text
        database = zipfile.ZipFile(io.BytesIO(response.content))
        names = sorted(n for n in database.namelist() if n.startswith("cells/"))
        assert names == sorted(f"cells/00000/{p.name}" for p in whole.iterdir())
        assert all(database.read(n) == (whole / n.rsplit("/", 1)[1]).read_bytes() for n in names)
        assert json.loads(database.read("index.json"))["cells"][0]["bundle"] == "cells/00000/"

    # Deleting the scene keeps the prototype another scene's instance refers to.
    other_path = instanced_scene(tmp_path / "two.glb", count=2)
    other = ingest_scene(db, blobs, tenant, "two.glb", io.BytesIO(other_path.read_bytes()), limit=2**22)
    other_scene = load_stored_scene(blobs, other)
    kept = _instance_job(db, blobs, tenant, other, other_scene, 1)
    assert kept.stats["baked"] is False and prototype_prefix(blobs, kept.result_key) == prototype
    assert api.delete(f"/v1/scenes/{stored.id}").status_code == 204
    assert blobs.exists(f"{prototype}/{MANIFEST_NAME}")
    glb = api.get(f"/v1/jobs/{kept.job_id}/cells/0/impostor.glb")
    assert glb.status_code == 200
    assert glb.content == (_whole_bundle(blobs, prototype, other_scene, 1, tmp_path / "other") / GLB_NAME).read_bytes()
