"""A placement job's database over REST (``GET /v1/jobs/{id}/lookup`` with a view direction,
``GET /v1/jobs/{id}/placement``) and offline (``farfield lookup``).

The service is real (``farfield up``: uvicorn, SQLite or PostgreSQL, the blob folder); the placement
is real (a small procedural city under a primitive budget, impostors baked with EGL at 64 px).  The
placement *job* is written through ``service.db`` and the blob store as a finished one would be
(:func:`publish_placement_job`): until the service plans placement jobs itself, the routes are what
is tested here.  TODO(merge): make it a job submitted over REST once the placement job type exists.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import uuid
from pathlib import Path

import numpy as np
import pytest
from scenes import write_scene
from service_harness import ADMIN_KEY, ROOT, service_client, service_on_each_database, upload  # noqa: F401 - fixtures

from farfield.core import procedural
from farfield.core.bundle import MANIFEST_NAME, write_bundle
from farfield.core.placement.cost_model import primitive_model
from farfield.core.placement.database import UNDER_BUDGET, bake_placement, placement_cells, placement_index, write_placement_database
from farfield.core.placement.planner import PlacementSettings, place
from farfield.core.placement.view_space import FACE_NAMES, VDI

VIEW = ([20.0, 110.0, 20.0], [100.0, 115.0, 100.0])  # above the roofs of the small city


def city_placement():
    """(scene, placement, {impostor id: baked impostor}): a small city, half its triangles as t_max."""
    city = procedural.city(36, seed=5, detail=6)
    settings = PlacementSettings(t_max=0.5 * city.triangle_count, model=primitive_model(), vdi_deg=45.0, options={"resolution": 64}, cpv_size=20.0)
    placement = place(city, *VIEW, settings)
    return city, placement, bake_placement(city, placement)


def publish_placement_job(service, scene_id: str, placement, impostors: dict, state: str = "done") -> str:
    """Write a placement job as the service leaves it: a JobRow of type ``placement``, one CellRow
    per impostor with its bundle published in the blob store, and (``done``) the index blob of
    :func:`placement_index`; ``placing``: the job row alone.  Returns the job id."""
    from farfield.service.blobs import blob_store
    from farfield.service.db import CellRow, Database, JobRow, SceneRow, now
    from farfield.service.jobs import result_key
    from farfield.service.keys import authenticate
    from farfield.service.settings import Settings

    settings = Settings.from_env(service.env)
    db, blobs = Database(settings.database_url), blob_store(settings)
    try:
        tenant_id = authenticate(db, ADMIN_KEY)
        with db.session() as s:
            scene = s.get(SceneRow, scene_id)
        parameters = placement.parameters
        options = dict(parameters["options"])
        job_id = uuid.uuid4().hex
        request = {"view_space": parameters["view_space"], "budget": {"primitives": parameters["t_max"]}, "cpv_size": parameters["cpv_size"], "vdi_deg": parameters["vdi_deg"]}
        params = {"technique": parameters["technique"], "resolution": options["resolution"], "fov_deg": options["fov_deg"], "options": options, "placement": request}
        job = JobRow(id=job_id, tenant_id=tenant_id, scene_id=scene_id, job_type="placement", params=params, evaluate=False, state=state, created_at=now(), started_at=now())
        rows, entries = [], []
        if state == "done":
            for cell in placement_cells(placement):
                key = result_key(scene.content_hash, cell["technique"], cell["params"], cell["viewcell"])
                with tempfile.TemporaryDirectory() as tmp:
                    write_bundle(impostors[cell["index"]], Path(tmp) / "bundle")
                    blobs.publish_directory(key, Path(tmp) / "bundle", last=MANIFEST_NAME)
                stats = json.loads(blobs.read_bytes(f"{key}/{MANIFEST_NAME}"))["stats"]
                rows.append(CellRow(id=uuid.uuid4().hex, job_id=job_id, index=cell["index"], grid=None, viewcell=cell["viewcell"], state="done", attempts=1, result_key=key, stats=stats, progress=1.0, finished_at=now(), seconds=0.1))
                entries.append({"index": cell["index"], "state": "done", "bundle": f"cells/{cell['index']:05d}/", "stats": stats})
            job.index_key = f"jobs/{job_id}/index.json"
            blobs.put_bytes(job.index_key, json.dumps(placement_index(placement, entries, job=job_id, scene=scene_id), sort_keys=True, indent=1).encode())
            job.finished_at = now()
        with db.session() as s:
            s.add(job)
            s.flush()
            for row in rows:
                s.add(row)
        return job_id
    finally:
        db.dispose()


def cpv_centre_view(cpv: dict) -> tuple[list[float], list[float]]:
    """The centre of a CPV's region and the axis of its view-direction interval."""
    lo, hi = (np.asarray(v) for v in cpv["region"])
    v = cpv["vdi"]
    axis, _ = VDI(FACE_NAMES.index(v["face"]), v["level"], v["i"], v["j"]).cone()
    return (0.5 * (lo + hi)).tolist(), np.asarray(axis, dtype=np.float64).reshape(3).tolist()


def view_params(position, direction) -> dict:
    return {**dict(zip("xyz", position)), **dict(zip(("dx", "dy", "dz"), direction))}


@pytest.fixture(scope="module")
def planned():
    return city_placement()


@pytest.fixture(scope="module")
def jobs(service, client, planned, tmp_path_factory):
    """(done placement job id, placing job id, grid job id) on the module's service."""
    city, placement, impostors = planned
    path = write_scene(city, tmp_path_factory.mktemp("city"), "glb")
    made = upload(client, path)
    assert made.status_code == 201, made.text
    scene_id = made.json()["id"]
    done = publish_placement_job(service, scene_id, placement, impostors)
    placing = publish_placement_job(service, scene_id, placement, impostors, state="placing")
    grid = client.post("/v1/jobs", json={"scene_id": scene_id, "resolution": 64, "evaluate": False, "viewcells": [{"kind": "box", "lo": VIEW[0], "hi": VIEW[1]}]})
    assert grid.status_code == 201, grid.text
    return done, placing, grid.json()["id"]


def test_every_cpv_centre_is_looked_up_with_its_impostors_cells(client, jobs, planned):
    _, placement, impostors = planned
    job_id = jobs[0]
    objects = {imp["id"]: imp["objects"] for imp in placement.impostors}
    for cpv in placement.cpvs:
        position, direction = cpv_centre_view(cpv)
        answer = client.get(f"/v1/jobs/{job_id}/lookup", params=view_params(position, direction))
        assert answer.status_code == 200, answer.text
        found = answer.json()
        assert found["cpv"] == cpv["id"] and found["status"] == cpv["status"] and found["impostors"] == cpv["impostors"]
        assert found["time_estimated"] == pytest.approx(cpv["time_after"])
        assert set(found["replaced"]) == {name for i in cpv["impostors"] for name in objects[i]}
        # Each impostor to draw comes with its cell record: done, with a result, its own stats.
        assert [c["index"] for c in found["cells"]] == cpv["impostors"]
        for cell in found["cells"]:
            assert cell["state"] == "done" and cell["has_result"] and cell["stats"]["quads"] == impostors[cell["index"]].stats["quads"]
    # A cell the lookup names is served as any cell: its bundle's manifest.
    first = placement.cpvs[0]["impostors"][0]
    manifest = client.get(f"/v1/jobs/{job_id}/cells/{first}/manifest.json")
    assert manifest.status_code == 200 and manifest.json()["stats"]["quads"] == impostors[first].stats["quads"]
    # Looking up into the sky from above the roofs: no CPV, nothing replaced, nothing to draw.
    sky = client.get(f"/v1/jobs/{job_id}/lookup", params=view_params([60.0, 112.0, 60.0], [0.0, 1.0, 0.0])).json()
    assert sky == {"cpv": None, "status": UNDER_BUDGET, "impostors": [], "replaced": [], "time_estimated": None, "cells": []}


def test_bad_views_and_unfinished_or_other_jobs_are_refused_with_their_reason(client, jobs):
    done, placing, grid = jobs
    missing = client.get(f"/v1/jobs/{done}/lookup", params={"x": 60, "y": 112, "z": 60, "dy": 1})
    assert missing.status_code == 422 and "dx, dz" in missing.json()["detail"] and "direction" in missing.json()["detail"]
    outside = client.get(f"/v1/jobs/{done}/lookup", params=view_params([60.0, 0.0, 60.0], [1.0, 0.0, 0.0]))
    assert outside.status_code == 422 and "outside the placement's view space" in outside.json()["detail"]
    still = client.get(f"/v1/jobs/{done}/lookup", params=view_params([60.0, 112.0, 60.0], [0.0, 0.0, 0.0]))
    assert still.status_code == 422 and "non-zero" in still.json()["detail"]
    # A placement job still planning has no database yet: 409 naming its state.
    for path in ("lookup", "placement"):
        early = client.get(f"/v1/jobs/{placing}/{path}", params=view_params([60.0, 112.0, 60.0], [1.0, 0.0, 0.0]))
        assert early.status_code == 409 and "placing" in early.json()["detail"], early.text
    # A grid job's lookup is by position as before (a direction changes nothing); it has no placement.
    cells = client.get(f"/v1/jobs/{grid}/lookup", params={"x": 60, "y": 112, "z": 60})
    assert cells.status_code == 200 and [c["index"] for c in cells.json()] == [0]
    assert client.get(f"/v1/jobs/{grid}/lookup", params=view_params([60.0, 112.0, 60.0], [1.0, 0.0, 0.0])).json() == cells.json()
    other = client.get(f"/v1/jobs/{grid}/placement")
    assert other.status_code == 404 and "not a placement job" in other.json()["detail"]
    assert client.get(f"/v1/jobs/{uuid.uuid4().hex}/placement").status_code == 404


def test_the_placement_route_holds_the_cpvs_impostors_and_totals(client, jobs, planned):
    _, placement, impostors = planned
    doc = client.get(f"/v1/jobs/{jobs[0]}/placement")
    assert doc.status_code == 200, doc.text
    doc = doc.json()
    assert doc["job"] == jobs[0] and doc["state"] == "done" and doc["version"] == 1
    assert doc["cpvs"] == json.loads(json.dumps(placement.cpvs)) and doc["unsolvable"] == placement.unsolvable
    assert doc["parameters"]["t_max"] == placement.summary["t_max"] and doc["summary"]["cpvs"] == len(placement.cpvs)
    assert [c["index"] for c in doc["cells"]] == [imp["id"] for imp in placement.impostors]
    for cell, imp in zip(doc["cells"], placement.impostors):
        assert cell["objects"] == imp["objects"] and cell["viewcell"] == imp["cell"] and cell["cpvs"] == imp["cpvs"]
        assert cell["figures"]["baked"]["quads"] == impostors[imp["id"]].stats["quads"]
    totals = doc["totals"]
    drawn = [imp for imp in placement.impostors if imp["cpvs"]]
    assert totals["impostors"] == len(drawn) == placement.summary["impostors"] and totals["impostors_baked"] == len(placement.impostors)
    assert totals["memory_bytes_baked"] == sum(impostors[imp["id"]].stats["texture_bytes"] for imp in drawn)
    assert totals["memory_bytes_estimated"] == pytest.approx(sum(imp["memory_bytes_estimated"] for imp in drawn))
    assert totals["cpvs"] == len(placement.cpvs) and totals["cpvs_by_status"]["solved"] == placement.summary["cpvs_solved"]
    assert totals["unsolvable_regions"] == len(placement.unsolvable) and totals["rounds"] == 0


def test_the_parsed_database_is_kept_between_lookups(service, client, jobs, planned):
    """The API reads a job's index blob once: with the blob gone, lookups still answer; once the job
    ends again (a new finish time: its index was written anew), the blob is read again."""
    from farfield.service.blobs import blob_store
    from farfield.service.db import Database, JobRow
    from farfield.service.settings import Settings

    _, placement, _ = planned
    done = jobs[0]
    cpv = placement.cpvs[-1]
    params = view_params(*cpv_centre_view(cpv))
    assert client.get(f"/v1/jobs/{done}/lookup", params=params).json()["cpv"] == cpv["id"]
    settings = Settings.from_env(service.env)
    blobs, db = blob_store(settings), Database(settings.database_url)
    key = f"jobs/{done}/index.json"
    saved = blobs.read_bytes(key)
    blobs.delete_prefix(key)
    try:
        assert client.get(f"/v1/jobs/{done}/lookup", params=params).json()["cpv"] == cpv["id"]
        assert client.get(f"/v1/jobs/{done}/placement").status_code == 200
        with db.session() as s:
            s.get(JobRow, done).finished_at += 1.0
        gone = client.get(f"/v1/jobs/{done}/lookup", params=params)
        assert gone.status_code == 404, gone.text
    finally:
        blobs.put_bytes(key, saved)
        db.dispose()
    assert client.get(f"/v1/jobs/{done}/lookup", params=params).json()["cpv"] == cpv["id"]


# --- farfield lookup, offline --------------------------------------------------------------------


def _lookup(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "farfield.cli.main", "lookup", *args], cwd=ROOT, capture_output=True, text=True, timeout=120, check=False)


def test_farfield_lookup_on_a_database_folder_and_zip(planned, tmp_path, client, jobs):
    _, placement, impostors = planned
    root = write_placement_database(tmp_path / "db", placement, impostors)
    cpv = max(placement.cpvs, key=lambda c: len(c["impostors"]))
    position, direction = cpv_centre_view(cpv)
    at = ["--at", *map(str, position), "--look", *map(str, direction)]
    done = _lookup(str(root), *at, "--json")
    assert done.returncode == 0, done.stderr
    answer = json.loads(done.stdout)
    assert answer["cpv"] == cpv["id"] and answer["impostors"] == cpv["impostors"] and answer["status"] == "solved"
    assert [c["bundle"] for c in answer["cells"]] == [str(root / "cells" / f"{i:05d}") for i in cpv["impostors"]]
    assert all((Path(c["bundle"]) / MANIFEST_NAME).is_file() for c in answer["cells"])
    assert set(answer["replaced"]) == {name for c in answer["cells"] for name in c["objects"]}
    # The same from the job's database.zip (bundles named inside the archive), and for a person.
    zipped = tmp_path / "job.zip"
    zipped.write_bytes(client.get(f"/v1/jobs/{jobs[0]}/database.zip").content)
    text = _lookup(str(zipped), *at)
    assert text.returncode == 0, text.stderr
    assert f"CPV {cpv['id']}: solved" in text.stdout and f"impostors to draw: {len(cpv['impostors'])}" in text.stdout
    for i in cpv["impostors"]:
        assert f"cells/{i:05d}/" in text.stdout
    sky = _lookup(str(root), "--at", "60", "112", "60", "--look", "0", "1", "0")
    assert sky.returncode == 0 and "under budget" in sky.stdout


def test_farfield_lookup_bad_input_is_one_line(planned, tmp_path):
    placement = planned[1]
    root = write_placement_database(tmp_path / "db", placement, {})
    grid = tmp_path / "grid"
    grid.mkdir()
    (grid / "index.json").write_text(json.dumps({"format": "farfield-impostor-database", "technique": "layered", "cells": []}))
    cases = [
        ((str(root), "--at", "60", "0", "60", "--look", "1", "0", "0"), "outside the placement's view space"),
        ((str(root), "--at", "60", "112", "60", "--look", "0", "0", "0"), "non-zero"),
        ((str(tmp_path / "nothing"), "--at", "60", "112", "60", "--look", "1", "0", "0"), "not an impostor database"),
        ((str(grid), "--at", "60", "112", "60", "--look", "1", "0", "0"), "not a placement database"),
    ]
    for args, message in cases:
        run = _lookup(*args)
        assert run.returncode != 0 and run.stdout == "", (args, run)
        assert run.stderr.count("\n") == 1 and message in run.stderr, (args, run.stderr)
    # Without bundles (cells not baked), the impostors are still named, with no bundle.
    cpv = placement.cpvs[0]
    position, direction = cpv_centre_view(cpv)
    bare = _lookup(str(root), "--at", *map(str, position), "--look", *map(str, direction), "--json")
    assert bare.returncode == 0 and [c["bundle"] for c in json.loads(bare.stdout)["cells"]] == [None] * len(cpv["impostors"])
