"""A placement job's database over REST (``GET /v1/jobs/{id}/lookup`` with a view direction,
``GET /v1/jobs/{id}/placement``) and offline (``farfield lookup``).

Everything is real: the service (``farfield up``: uvicorn, a Celery worker, SQLite or PostgreSQL,
the blob folder), and a placement job submitted over REST (a small procedural city under a primitive
budget, planned on the worker, its impostors baked with EGL at 64 px, checked and repaired); the
tests read the job's own database back (:func:`submit_placement`).
"""

from __future__ import annotations

import io
import json
import subprocess
import sys
import uuid
import zipfile
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scenes import write_scene
from service_harness import ADMIN_KEY, ROOT, service_client, service_on_each_database, upload, wait_for_job  # noqa: F401 - fixtures

from farfield.core import procedural
from farfield.core.impostor.bundle import MANIFEST_NAME
from farfield.core.placement.database import UNDER_BUDGET
from farfield.core.placement.result import Placement
from farfield.core.placement.view_space import FACE_NAMES, VDI

VIEW = ([20.0, 110.0, 20.0], [100.0, 115.0, 100.0])  # above the roofs of the small city


def small_city():
    return procedural.city(36, seed=5, detail=6)


def city_request(t_max: float, lo=VIEW[0], hi=VIEW[1]) -> dict:
    """A placement job's request: the view space, a primitive budget, coarse CPVs (quick to plan)."""
    return {
        "view_space": {"lo": list(lo), "hi": list(hi)},
        "budget": {"primitives": t_max},
        "vdi_deg": 45.0,
        "cpv_size": 20.0,
    }


def placement_of(index: dict) -> Placement:
    """The placement a database index describes (its placement section and its cells as impostors)."""
    section = index["placement"]
    impostors = [
        {"id": c["index"], "objects": c["objects"], "cell": c["viewcell"], "cpvs": c["cpvs"],
         "memory_bytes_estimated": c["figures"]["estimated"]["memory_bytes_estimated"]}
        for c in index["cells"]
    ]  # fmt: skip
    return Placement(
        section["parameters"],
        section["elements"],
        impostors,
        section["cpvs"],
        section["unsolvable"],
        section["summary"],
    )


def submit_placement(client, scene_id: str, request: dict, directory: Path) -> tuple[str, Placement, dict, Path]:
    """Submit a placement job over REST and wait for it: (job id, its placement, {impostor id: an
    object whose ``stats`` are the cell's}, its database.zip unpacked into ``directory``)."""
    made = client.post(
        "/v1/jobs", json={"scene_id": scene_id, "technique": "layered", "resolution": 64, "placement": request}
    )
    assert made.status_code == 201, made.text
    job = wait_for_job(client, made.json()["id"], timeout=600)
    assert job["state"] == "done", (job["error"], job["errors"])
    data = client.get(f"/v1/jobs/{job['id']}/database.zip")
    assert data.status_code == 200, data.text
    zipfile.ZipFile(io.BytesIO(data.content)).extractall(directory)
    index = json.loads((directory / "index.json").read_text())
    impostors = {c["index"]: SimpleNamespace(stats=c["stats"]) for c in job["cells"]}
    return job["id"], placement_of(index), impostors, directory


def placing_job(client, scene_id: str) -> str:
    """A placement job caught while it plans: fine CPVs at street level take the worker seconds."""
    made = client.post("/v1/jobs", json={"scene_id": scene_id, "technique": "layered", "resolution": 64,
                                         "placement": {**city_request(300.0, [0.0, 2.0, 0.0], [100.0, 6.0, 100.0]), "cpv_size": 2.0, "vdi_deg": 11.25}})  # fmt: skip
    assert made.status_code == 201, made.text
    return made.json()["id"]


def cpv_centre_view(cpv: dict) -> tuple[list[float], list[float]]:
    """The centre of a CPV's region and the axis of its view-direction interval."""
    lo, hi = (np.asarray(v) for v in cpv["region"])
    v = cpv["vdi"]
    axis, _ = VDI(FACE_NAMES.index(v["face"]), v["level"], v["i"], v["j"]).cone()
    return (0.5 * (lo + hi)).tolist(), np.asarray(axis, dtype=np.float64).reshape(3).tolist()


def view_params(position, direction) -> dict:
    return {**dict(zip("xyz", position)), **dict(zip(("dx", "dy", "dz"), direction))}


@pytest.fixture(scope="module")
def scene_id(client, tmp_path_factory):
    made = upload(client, write_scene(small_city(), tmp_path_factory.mktemp("city"), "glb"))
    assert made.status_code == 201, made.text
    return made.json()["id"]


@pytest.fixture(scope="module")
def planned(client, scene_id, tmp_path_factory):
    """The done placement job: (job id, placement, impostors by id, its database folder)."""
    return submit_placement(
        client, scene_id, city_request(0.5 * small_city().triangle_count), tmp_path_factory.mktemp("db")
    )


@pytest.fixture(scope="module")
def jobs(client, scene_id, planned):
    """(done placement job id, a placement job still placing or later, grid job id)."""
    grid = client.post(
        "/v1/jobs",
        json={
            "scene_id": scene_id,
            "resolution": 64,
            "evaluate": False,
            "viewcells": [{"kind": "box", "lo": VIEW[0], "hi": VIEW[1]}],
        },
    )
    assert grid.status_code == 201, grid.text
    return planned[0], placing_job(client, scene_id), grid.json()["id"]


def test_every_cpv_centre_is_looked_up_with_its_impostors_cells(client, jobs, planned):
    job_id, placement, impostors, _ = planned
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
            assert (
                cell["state"] == "done"
                and cell["has_result"]
                and cell["stats"]["quads"] == impostors[cell["index"]].stats["quads"]
            )
    # A cell the lookup names is served as any cell: its bundle's manifest.
    first = placement.cpvs[0]["impostors"][0]
    manifest = client.get(f"/v1/jobs/{job_id}/cells/{first}/manifest.json")
    assert manifest.status_code == 200 and manifest.json()["stats"]["quads"] == impostors[first].stats["quads"]
    # Looking up into the sky from above the roofs: no CPV, nothing replaced, nothing to draw.
    sky = client.get(f"/v1/jobs/{job_id}/lookup", params=view_params([60.0, 112.0, 60.0], [0.0, 1.0, 0.0])).json()
    assert sky == {
        "cpv": None,
        "status": UNDER_BUDGET,
        "impostors": [],
        "replaced": [],
        "time_estimated": None,
        "cells": [],
    }


def test_bad_views_and_unfinished_or_other_jobs_are_refused_with_their_reason(client, jobs):
    done, placing, grid = jobs
    missing = client.get(f"/v1/jobs/{done}/lookup", params={"x": 60, "y": 112, "z": 60, "dy": 1})
    assert (
        missing.status_code == 422 and "dx, dz" in missing.json()["detail"] and "direction" in missing.json()["detail"]
    )
    outside = client.get(f"/v1/jobs/{done}/lookup", params=view_params([60.0, 0.0, 60.0], [1.0, 0.0, 0.0]))
    assert outside.status_code == 422 and "outside the placement's view space" in outside.json()["detail"]
    still = client.get(f"/v1/jobs/{done}/lookup", params=view_params([60.0, 112.0, 60.0], [0.0, 0.0, 0.0]))
    assert still.status_code == 422 and "non-zero" in still.json()["detail"]
    # A placement job still planning has no database yet: 409 naming its state.
    for path in ("lookup", "placement"):
        early = client.get(f"/v1/jobs/{placing}/{path}", params=view_params([60.0, 112.0, 60.0], [1.0, 0.0, 0.0]))
        state = client.get(f"/v1/jobs/{placing}").json()["state"]
        assert (
            state in ("queued", "placing", "running")
            and early.status_code == 409
            and f"is {state}" in early.json()["detail"]
        ), early.text
    assert client.post(f"/v1/jobs/{placing}/cancel").status_code == 200  # frees the worker
    # A grid job's lookup is by position as before (a direction changes nothing); it has no placement.
    cells = client.get(f"/v1/jobs/{grid}/lookup", params={"x": 60, "y": 112, "z": 60})
    assert cells.status_code == 200 and [c["index"] for c in cells.json()] == [0]
    # The same cells (their state may move on between the two requests: the grid job runs meanwhile).
    same = client.get(f"/v1/jobs/{grid}/lookup", params=view_params([60.0, 112.0, 60.0], [1.0, 0.0, 0.0])).json()
    assert [(c["index"], c["viewcell"]) for c in same] == [(c["index"], c["viewcell"]) for c in cells.json()]
    other = client.get(f"/v1/jobs/{grid}/placement")
    assert other.status_code == 404 and "not a placement job" in other.json()["detail"]
    assert client.get(f"/v1/jobs/{uuid.uuid4().hex}/placement").status_code == 404


def test_the_placement_route_holds_the_cpvs_impostors_and_totals(client, jobs, planned):
    _, placement, impostors, _ = planned
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
    assert totals["impostors"] == len(drawn) == placement.summary["impostors"] and totals["impostors_baked"] == len(
        placement.impostors
    )
    assert totals["memory_bytes_baked"] == sum(impostors[imp["id"]].stats["texture_bytes"] for imp in drawn)
    assert totals["memory_bytes_estimated"] == pytest.approx(sum(imp["memory_bytes_estimated"] for imp in drawn))
    assert (
        totals["cpvs"] == len(placement.cpvs) and totals["cpvs_by_status"]["solved"] == placement.summary["cpvs_solved"]
    )
    assert totals["unsolvable_regions"] == len(placement.unsolvable) and totals["rounds"] == len(doc["rounds"]) >= 1


def test_the_parsed_database_is_kept_between_lookups(service, client, jobs, planned):
    """The API reads a job's index blob once: with the blob gone, lookups still answer; once the job
    ends again (a new finish time: its index was written anew), the blob is read again."""
    from farfield.service.blobs import blob_store
    from farfield.service.db import Database, JobRow
    from farfield.service.settings import Settings

    done, placement, _, _ = planned
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
    return subprocess.run(
        [sys.executable, "-m", "farfield.cli.main", "lookup", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


def test_farfield_lookup_on_a_database_folder_and_zip(planned, tmp_path, client, jobs):
    _, placement, _, root = planned
    cpv = max(placement.cpvs, key=lambda c: len(c["impostors"]))
    position, direction = cpv_centre_view(cpv)
    at = ["--at", *map(str, position), "--look", *map(str, direction)]
    done = _lookup(str(root), *at, "--json")
    assert done.returncode == 0, done.stderr
    answer = json.loads(done.stdout)
    assert answer["cpv"] == cpv["id"] and answer["impostors"] == cpv["impostors"] and answer["status"] == cpv["status"]
    assert [c["bundle"] for c in answer["cells"]] == [str(root / "cells" / f"{i:05d}") for i in cpv["impostors"]]
    assert all((Path(c["bundle"]) / MANIFEST_NAME).is_file() for c in answer["cells"])
    assert set(answer["replaced"]) == {name for c in answer["cells"] for name in c["objects"]}
    # The same from the job's database.zip (bundles named inside the archive), and for a person.
    zipped = tmp_path / "job.zip"
    zipped.write_bytes(client.get(f"/v1/jobs/{jobs[0]}/database.zip").content)
    text = _lookup(str(zipped), *at)
    assert text.returncode == 0, text.stderr
    assert (
        f"CPV {cpv['id']}: {cpv['status']}" in text.stdout
        and f"impostors to draw: {len(cpv['impostors'])}" in text.stdout
    )
    for i in cpv["impostors"]:
        assert f"cells/{i:05d}/" in text.stdout
    sky = _lookup(str(root), "--at", "60", "112", "60", "--look", "0", "1", "0")
    assert sky.returncode == 0 and "under budget" in sky.stdout


def test_farfield_lookup_bad_input_is_one_line(planned, tmp_path):
    root = planned[3]
    grid = tmp_path / "grid"
    grid.mkdir()
    (grid / "index.json").write_text(
        json.dumps({"format": "farfield-impostor-database", "technique": "layered", "cells": []})
    )
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
    placement = planned[1]
    index = json.loads((root / "index.json").read_text())
    for cell in index["cells"]:
        cell["bundle"], cell["state"] = None, "queued"
    bare_root = tmp_path / "bare"
    bare_root.mkdir()
    (bare_root / "index.json").write_text(json.dumps(index))
    cpv = next(c for c in placement.cpvs if c["impostors"])
    position, direction = cpv_centre_view(cpv)
    bare = _lookup(str(bare_root), "--at", *map(str, position), "--look", *map(str, direction), "--json")
    assert bare.returncode == 0 and [c["bundle"] for c in json.loads(bare.stdout)["cells"]] == [None] * len(
        cpv["impostors"]
    )


def test_database_zip_ships_only_the_bundles_a_placement_index_names():
    from farfield.service.jobs.index import bundled_cells as _bundled_cells

    index = {
        "kind": "placement",
        "cells": [{"index": 0, "bundle": "cells/00000/"}, {"index": 1, "bundle": None, "state": "unused"}],
    }
    assert _bundled_cells(json.dumps(index).encode()) == {0}
    assert (
        _bundled_cells(json.dumps({"cells": [{"index": 0, "bundle": None}]}).encode()) is None
    )  # a grid job's: every baked cell
