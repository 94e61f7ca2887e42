"""A placement's candidate step fanned out to a real render worker (``farfield up``: embedded Redis,
a real ``celery worker``, SQLite, the blob directory; service.placement.candidate_fanout): the
parts a worker computed and the parts the planner computed, merged, are the one-process placement
byte for byte; and a placement job planned with ``FARFIELD_PLANNING_PARTS`` on one worker (whose part
tasks can only run after its planning task) ends done, as planned in one process."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
import redis
from celery import Celery
from scenes import write_scene
from service_harness import service_client, service_on_sqlite, upload, wait_for_job  # noqa: F401 - the service fixtures
from sqlalchemy import select

from farfield.core.exchange import load_scene
from farfield.core.placement.cost_model import primitive_model
from farfield.core.placement.planner import PlacementSettings, place
from farfield.core.procedural import city
from farfield.service.blobs import blob_store
from farfield.service.db import CellRow, Database, JobRow
from farfield.service.placement import candidate_fanout
from farfield.service.placement.candidate_fanout import _fan_out
from farfield.service.placement.frame_time import placement_cells, planner_settings
from farfield.service.settings import Settings
from farfield.workers.tasks import PLAN_CANDIDATE_PART

PARTS = 3


@pytest.fixture(scope="module")
def service_env():
    return {"FARFIELD_PLANNING_PARTS": str(PARTS)}


def _dump(placement) -> str:
    return json.dumps(placement.to_dict(), sort_keys=True)


def test_parts_a_worker_computed_merge_into_the_one_process_placement(service):
    scene = city(25, seed=1, detail=8)
    settings = PlacementSettings(t_max=600.0, model=primitive_model(), vdi_deg=45.0, options={"resolution": 64},
                                 cpv_size=10.0)  # fmt: skip
    view = (np.array([10.0, 2.0, 10.0]), np.array([70.0, 6.0, 70.0]))
    one = place(scene, *view, settings)
    blobs = blob_store(Settings.from_env(service.env))
    claims = redis.Redis.from_url(service.broker)
    app = Celery("farfield-test", broker=service.broker)
    prefix = "jobs/test/candidate-parts/fanout"

    def send(prefix: str, part: int, start: int, stop: int) -> None:
        app.send_task(PLAN_CANDIDATE_PART, args=[prefix, part, start, stop], queue="render")
        if part == PARTS - 1:  # let the worker claim the first part before this process takes any
            deadline = time.monotonic() + 60
            while claims.get(f"farfield:{prefix}:claim-0") is None:
                assert time.monotonic() < deadline, "the worker never claimed a part"
                time.sleep(0.02)

    read, reports = [], []
    original = blobs.read_bytes

    def counted(key: str) -> bytes:
        read.append(key)
        return original(key)

    blobs.read_bytes = counted

    def candidates(inputs, progress):
        from farfield.core.placement.candidate_parts import node_ranges

        ranges = node_ranges(inputs, PARTS)
        return _fan_out(blobs, claims, send, prefix, inputs, ranges, lambda d, t: reports.append((d, t)))

    split = place(scene, *view, settings, candidates=candidates)
    assert one.impostors and one.summary["candidates"] > 10
    assert f"{prefix}/part-0.pickle" in read  # the worker's part, stored and read back
    assert _dump(split) == _dump(one)
    assert reports[-1][0] == reports[-1][1]  # every node's part done
    assert not blobs.list_files(prefix) and not claims.keys(f"farfield:{prefix}:*")  # nothing left behind


def test_a_job_planned_in_parts_on_one_worker_bakes_what_one_process_plans(service, client, tmp_path):
    path = write_scene(city(25, seed=1, detail=8), tmp_path, "glb", "city")
    scene_id = upload(client, path).json()["id"]
    placement = {
        "view_space": {"lo": [10.0, 2.0, 10.0], "hi": [70.0, 6.0, 70.0]},
        "budget": {"primitives": 800},
        "cpv_size": 20,
    }
    response = client.post(
        "/v1/jobs", json={"scene_id": scene_id, "technique": "layered", "resolution": 64, "placement": placement}
    )
    assert response.status_code == 201, response.text
    job = wait_for_job(client, response.json()["id"], timeout=240)
    assert job["state"] == "done", (job["error"], job["errors"])
    settings = Settings.from_env(service.env)
    db = Database(settings.database_url)
    try:
        with db.session() as s:
            row = s.get(JobRow, job["id"])
            params = row.params
            cells = {
                c.index: (c.viewcell, c.params) for c in s.scalars(select(CellRow).where(CellRow.job_id == row.id))
            }
    finally:
        db.dispose()
    planner, lo, hi = planner_settings(params)
    alone = place(load_scene(str(path)), lo, hi, planner).to_dict()
    planned = placement_cells(alone, {imp["id"] for imp in alone["impostors"]})
    assert planned and candidate_fanout.planning_parts(service.env) == PARTS
    for entry in planned:  # round 0 (the plan) baked what one process plans, cell for cell
        assert cells[entry["index"]] == (entry["viewcell"], entry["params"])
    log = (service.home / "logs" / "worker0.log").read_text()
    assert PLAN_CANDIDATE_PART in log  # the part tasks were sent (and found their parts planned)
