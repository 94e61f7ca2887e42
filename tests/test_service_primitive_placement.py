"""Primitive-budget placement jobs (seed 004 as a job: ``"placement": {"algorithm": "primitive-budget"}``).

In one process on real parts (SQLite, the blob folder, the planner, EGL bakes at 32 px), the worker
tasks' functions called in turn as a worker calls them: the grid is planned on the "worker", every
image becomes a cell baked as an ``ldi`` bundle, and the check writes a database that
``farfield walkthrough`` opens and whose every sampled view stays within P.  Then with the whole
service (``farfield up``'s parts: redis-server, uvicorn, a real Celery worker): the CLI submits,
waits and downloads; the placement and lookup routes answer; a resubmission bakes nothing; bad
requests are refused with their reason and nothing stored."""

from __future__ import annotations

import io
import json
import math
import re
import zipfile
from pathlib import Path

import numpy as np
import pytest
from scenes import write_scene
from service_harness import service_on_sqlite, upload, wait_for_job  # noqa: F401 - the service fixtures

from farfield.core.procedural import city

# The 25-building city (1,082 triangles) seen from a 10 x 1 x 10 box between its buildings: at
# P = 487 (45 % of the model) its solution grid has 16 images (0.2 s of planning).
VIEW_SPACE = {"lo": [35.0, 3.0, 35.0], "hi": [45.0, 4.0, 45.0]}
P = 487
REQUEST = {
    "view_space": VIEW_SPACE,
    "budget": {"primitives": P},
    "algorithm": "primitive-budget",
    "grid_points": 2,
    "max_level": 1,
}


def _scene():
    return city(25, seed=1, detail=8)


class Flow:
    """A primitive-budget job stored and queued for planning, its worker's functions run here."""

    def __init__(self, root: Path, request: dict = REQUEST):
        from farfield.service.blobs import LocalBlobStore
        from farfield.service.db import Database
        from farfield.service.jobs.admission import create_placement_job
        from farfield.service.jobs.schema import JobSpec
        from farfield.service.keys import tenant_named
        from farfield.service.scenes import ingest_scene
        from farfield.service.settings import Settings

        settings = Settings.from_env({"FARFIELD_HOME": str(root)})
        self.db = Database(settings.database_url)
        self.db.migrate()
        self.blobs = LocalBlobStore(settings.blob_dir)
        self.tenant = tenant_named(self.db, "images").id
        self.path = write_scene(_scene(), root, "glb", "city")
        with open(self.path, "rb") as f:
            self.scene = ingest_scene(self.db, self.blobs, self.tenant, "city.glb", f, limit=2**26)
        self.job_id = create_placement_job(
            self.db, self.tenant, self.scene, JobSpec(scene_id=self.scene.id, resolution=32, placement=request)
        ).id

    def job(self):
        from farfield.service.db import JobRow

        with self.db.session() as s:
            return s.get(JobRow, self.job_id)

    def run(self) -> list[str]:
        """Plan, bake every cell, check: the states the job went through."""
        from farfield.service.jobs.runner import run_cell
        from farfield.service.placement.rounds import after_cell, check_job, plan_job

        state, cells = plan_job(self.db, self.blobs, self.job_id, "W", 3)
        seen = [state]
        for cell_id in cells:
            assert run_cell(self.db, self.blobs, cell_id, 3, worker="W") == "done"
            waits = after_cell(self.db, self.blobs, self.job_id)
        if cells:
            assert waits, "the last cell of the round leaves the job waiting for its check"
            state, added = check_job(self.db, self.blobs, self.job_id, "W", 3)
            assert added == []
            seen.append(state)
        return seen


@pytest.fixture(scope="module")
def flow(tmp_path_factory):
    made = Flow(tmp_path_factory.mktemp("primitive-flow"))
    made.states = made.run()
    yield made
    made.db.dispose()


@pytest.mark.slow
def test_the_job_plans_the_grid_bakes_one_ldi_cell_per_image_and_writes_its_database(flow):
    from farfield.service.db import job_cells
    from farfield.service.placement.states import planner_state_keys

    assert flow.states == ["running", "done"]
    job = flow.job()
    assert job.params["technique"] == "ldi" and job.params["placement"]["algorithm"] == "primitive-budget"
    record = job.planning
    summary = record["summary"]
    cells = job_cells(flow.db, flow.job_id)
    assert summary["images"] == record["impostors"] == len(cells) >= 3
    assert summary["check"]["views"] == 2000 and summary["check"]["within_p"] == 1.0 and summary["check"]["max"] <= P
    assert all(c.state == "done" and c.params["technique"] == "ldi" and c.stats["samples"] > 0 for c in cells)
    assert planner_state_keys(flow.blobs, flow.job_id) == []  # the grid lives on in the index
    index = json.loads(flow.blobs.read_bytes(job.index_key))
    assert index["format"] == "farfield.primitive_placement" and index["kind"] == "primitive-placement"
    assert (
        index["scene_hash"] == flow.scene.content_hash
        and index["resolution"] == 32
        and index["construction_images"] == 9
    )
    names = {f"{pi}-{ii}" for pi, p in enumerate(index["points"]) for ii in range(len(p["images"]))}
    assert set(index["bundles"]) == names == {c.params["image"] for c in cells}
    for c in cells:  # each image's bundle is its cell's
        assert index["bundles"][c.params["image"]] == f"cells/{c.index:05d}/"


def test_the_unpacked_database_walks_within_the_budget(flow, tmp_path):
    """What an engine gets (the job's database laid out as database.zip unpacks it) opens as an image
    database, its LDIs are the baked bundles, and every sampled view draws at most P."""
    from farfield.core.exchange import load_scene
    from farfield.core.placement.image_database import ImageDatabase, image_walkthrough
    from farfield.service.db import job_cells

    root = tmp_path / "db"
    root.mkdir()
    job = flow.job()
    (root / "index.json").write_bytes(flow.blobs.read_bytes(job.index_key))
    for c in job_cells(flow.db, flow.job_id):
        flow.blobs.copy_to_directory(c.result_key, root / "cells" / f"{c.index:05d}")
    db = ImageDatabase(root, load_scene(flow.path))
    point = next(i for i, p in enumerate(db.placement.points) if p.images)
    assert db.impostor(point, 0).technique == "ldi"
    rng = np.random.default_rng(3)
    p = db.placement
    eyes = p.view_lo + rng.random((6, 3)) * (p.view_hi - p.view_lo)
    # and the views at the grid points that hold an image, looking along it (each warps that LDI)
    with_image = [
        (q.position, im["yaw"]) for q in p.points for im in q.images if p.view(q.position, im["yaw"])["image"] >= 0
    ][:4]
    eyes = np.vstack([eyes, [e for e, _ in with_image]])
    yaws = np.concatenate([rng.random(6) * 2 * math.pi, [y for _, y in with_image]])
    result = image_walkthrough(db, eyes, yaws, repeats=1)
    s = result["summary"]
    assert s["share_within_p"] == 1.0 and s["primitives_max"] <= P
    assert s["views_with_image"] >= 1
    with pytest.raises(Exception, match="another scene"):
        ImageDatabase(root, city(9, seed=2, detail=8))


@pytest.mark.slow
def test_a_second_job_of_the_same_request_bakes_nothing(flow):
    from farfield.service.db import job_cells
    from farfield.service.jobs.admission import create_placement_job
    from farfield.service.jobs.schema import JobSpec

    first = {c.params["image"]: c.result_key for c in job_cells(flow.db, flow.job_id)}
    again = Flow.__new__(Flow)
    again.db, again.blobs, again.tenant, again.scene, again.path = (
        flow.db,
        flow.blobs,
        flow.tenant,
        flow.scene,
        flow.path,
    )
    again.job_id = create_placement_job(
        flow.db, flow.tenant, flow.scene, JobSpec(scene_id=flow.scene.id, resolution=32, placement=REQUEST)
    ).id
    assert again.run() == ["running", "done"]
    cells = job_cells(flow.db, again.job_id)
    assert {c.params["image"]: c.result_key for c in cells} == first
    assert not any(c.stats["baked"] for c in cells)


@pytest.mark.parametrize(
    "change, message",
    [
        ({"budget": {"frame_ms": 10.0}}, "give budget.primitives"),
        ({"budget": {"primitives": P, "cost_model": "llvmpipe"}}, "give budget.primitives"),
        ({"cpv_size": 2.0}, "cpv_size: not a knob of the primitive-budget placement"),
        ({"p_opt": 2 * P}, "p_opt must lie in (0, P]"),
        ({"octree_depth": 11}, "octree_depth must be an integer in 0..10"),
        ({"grid_points": 1}, "grid_points must be an integer >= 2"),
        ({"grid_points": 1000}, "grid_points must be an integer >= 2 and <= 58"),
        ({"max_level": 5000}, "max_level must be an integer >= 0 and <= 20"),
        ({"check_views": -1}, "check_views must be an integer"),
        ({"budget": {"primitives": 0}}, "primitive budget must be a finite number >= 1"),
        ({"view_space": {"lo": [1, 1, 1], "hi": [0, 2, 2]}}, "the view space is empty"),
        (
            {"algorithm": "frame-time", "p_opt": 100},
            "p_opt, grid_points, max_level: not knobs of the frame-time placement",
        ),
        ({"algorithm": "fastest"}, "algorithm"),
    ],
)
def test_bad_primitive_budget_requests_name_their_problem(tmp_path, change, message):
    from farfield.core.errors import FarfieldError
    from farfield.service.jobs.admission import create_placement_job
    from farfield.service.jobs.schema import JobSpec

    flow = Flow(tmp_path)
    try:
        with pytest.raises((FarfieldError, ValueError), match=re.escape(message)):
            create_placement_job(
                flow.db,
                flow.tenant,
                flow.scene,
                JobSpec(scene_id=flow.scene.id, resolution=32, placement={**REQUEST, **change}),
            )
    finally:
        flow.db.dispose()


def test_a_technique_other_than_ldi_or_a_fov_below_the_star_shape_bound_is_refused(tmp_path):
    from farfield.core.errors import FarfieldError
    from farfield.service.jobs.admission import create_placement_job
    from farfield.service.jobs.schema import JobSpec

    flow = Flow(tmp_path)
    try:
        with pytest.raises(FarfieldError, match="technique 'ldi'"):
            create_placement_job(
                flow.db,
                flow.tenant,
                flow.scene,
                JobSpec(scene_id=flow.scene.id, technique="layered", placement=REQUEST),
            )
        with pytest.raises(FarfieldError, match="below the star-shape bound"):
            create_placement_job(
                flow.db, flow.tenant, flow.scene, JobSpec(scene_id=flow.scene.id, fov_deg=45.0, placement=REQUEST)
            )
    finally:
        flow.db.dispose()


# --- the whole service ------------------------------------------------------------------------


def test_submit_wait_download_walk_look_up_and_refuse_over_the_service(service, tmp_path):
    path = write_scene(_scene(), tmp_path, "glb", "city")
    auth = ("--url", service.url, "--key", service.env["FARFIELD_ADMIN_KEY"])
    out = tmp_path / "db"
    submitted = service.cli(
        "submit", str(path), "--placement", "--algorithm", "primitive-budget", "--view-space", "35,3,35,45,4,45", "--primitives", str(P),
        "--grid-points", "2", "--max-level", "1", "--resolution", "32", "--wait", "--download", str(out), "--json", *auth,
    )  # fmt: skip
    assert submitted.returncode == 0, submitted.stderr
    job = json.loads(submitted.stdout.strip().splitlines()[-1])
    assert (
        job["state"] == "done" and job["technique"] == "ldi" and job["placement"]["summary"]["check"]["within_p"] == 1.0
    )
    assert (out / "index.json").is_file() and any((out / "cells").iterdir())
    walked = service.cli("walkthrough", str(out), str(path), "--random", "5", "--repeats", "1", "--json")
    assert walked.returncode == 0, walked.stderr
    assert json.loads(walked.stdout)["summary"]["share_within_p"] == 1.0

    with service.client() as client:
        doc = client.get(f"/v1/jobs/{job['id']}/placement").json()
        assert doc["algorithm"] == "primitive-budget" and doc["parameters"]["primitives"] == P
        assert (
            doc["totals"]["images"] == doc["totals"]["images_baked"] == job["cells_total"]
            and doc["totals"]["memory_bytes_baked"] > 0
        )
        cell_of = {im["name"]: im["cell"] for p in doc["points"] for im in p["images"]}
        # a view from a grid point along one of its images' yaw warps that image, within P
        looked, answers, pi_with = 0, {}, None
        for pi, point in enumerate(doc["points"]):
            for im in point["images"]:
                x, y, z = point["position"]
                dx, dz = math.sin(im["yaw"]), -math.cos(im["yaw"])
                answer = client.get(
                    f"/v1/jobs/{job['id']}/lookup", params={"x": x, "y": y, "z": z, "dx": dx, "dy": 0.0, "dz": dz}
                ).json()
                assert answer["primitives"] <= P and answer["within_budget"], answer
                if answer["image"] is not None:
                    assert answer["point"] == pi and answer["cells"][0]["index"] == cell_of[answer["image"]]
                    looked += 1
                    answers[pi], pi_with = (answer, point["position"], im["yaw"]), pi
        assert looked >= 1
        flat = client.get(f"/v1/jobs/{job['id']}/lookup", params={"x": 40, "y": 3, "z": 40, "dx": 0, "dy": 1, "dz": 0})
        assert flat.status_code == 422 and "horizontally" in flat.json()["detail"]
        nowhere = client.get(
            f"/v1/jobs/{job['id']}/lookup", params={"x": "nan", "y": 3, "z": 40, "dx": 1, "dy": 0, "dz": 0}
        )
        assert nowhere.status_code == 422 and "finite" in nowhere.json()["detail"]
        zipped = client.get(f"/v1/jobs/{job['id']}/database.zip").content
        archive = zipfile.ZipFile(io.BytesIO(zipped))
        assert sum(n.endswith("manifest.json") for n in archive.namelist()) == job["cells_total"]
        # the same request again: every image found, none baked
        again = wait_for_job(
            client,
            client.post("/v1/jobs", json={"scene_id": job["scene_id"], "resolution": 32, "placement": REQUEST}).json()[
                "id"
            ],
            timeout=300,
        )
        assert again["state"] == "done" and not any(c["stats"]["baked"] for c in again["cells"])
        before = client.get("/v1/jobs").json()
        bad = client.post(
            "/v1/jobs", json={"scene_id": job["scene_id"], "placement": {**REQUEST, "budget": {"frame_ms": 5}}}
        )
        assert bad.status_code == 422 and "give budget.primitives" in bad.json()["detail"]
        assert client.get("/v1/jobs").json() == before
    # offline, on the zip as the API gives it: the same answer as the service's lookup at a grid point with an image
    (tmp_path / "db.zip").write_bytes(zipped)
    answer, (x, y, z), yaw = answers[pi_with]
    offline = service.cli(
        "lookup",
        str(tmp_path / "db.zip"),
        "--at",
        str(x),
        str(y),
        str(z),
        "--look",
        str(math.sin(yaw)),
        "0",
        str(-math.cos(yaw)),
        "--json",
    )
    assert offline.returncode == 0, offline.stderr
    assert json.loads(offline.stdout)["image"] == answer["image"] is not None
    walked_zip = service.cli(
        "walkthrough", str(tmp_path / "db.zip"), str(path), "--random", "2", "--repeats", "1", "--no-compare", "--json"
    )
    assert walked_zip.returncode == 0 and json.loads(walked_zip.stdout)["summary"]["share_within_p"] == 1.0, (
        walked_zip.stderr
    )
    refused = service.cli("submit", job["scene_id"], "--placement", "--view-space", "35,3,35,45,4,45", "--primitives", "400", "--fov", "40",
                          "--algorithm", "primitive-budget", *auth)  # fmt: skip
    assert (
        refused.returncode != 0
        and "star-shape bound" in refused.stderr
        and len(refused.stderr.strip().splitlines()) == 1
    )
