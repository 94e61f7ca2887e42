"""A placement job planned with visibility over REST (issue 57 item 2): ``GET /v1/jobs/{id}/lookup``
answers the region's potentially visible set.  Everything is real: the service (``farfield up``:
uvicorn, a Celery worker, SQLite, the blob folder), the job planned on the worker with EGL id cube
maps.  Its own module (its own service): a placement job another module leaves planning would hold
the worker."""

from __future__ import annotations

import json

from scenes import write_scene
from service_harness import service_client, service_on_sqlite, upload  # noqa: F401 - the service fixtures
from test_placement_api import city_request, submit_placement, view_params

from farfield.core import procedural


def test_a_placement_planned_with_visibility_answers_its_pvs(client, tmp_path):
    """Issue 57 item 2: a wall between the view space and a dense block; planned with visibility,
    nothing needs an impostor, and the lookup answers the region's PVS, which lacks the block."""
    from farfield.core.scene import Scene, SceneObject

    def box(name, low, high, n=1):
        return SceneObject(name, *procedural.subdivided_box(low, high, n))

    scene = Scene.from_objects([box("wall", (10, -50, -50), (11, 50, 50)), box("hidden", (20, -2, -2), (24, 2, 2), 24),
                                box("beside", (-5, 0, 30), (-4, 1, 31))], "walled")  # fmt: skip
    made = upload(client, write_scene(scene, tmp_path, "glb", "walled"))
    assert made.status_code == 201, made.text
    request = {
        **city_request(0.5 * scene.triangle_count, [-10.0, -2.0, -10.0], [0.0, 2.0, 10.0]),
        "cpv_size": 10.0,
        "visibility": True,
    }
    job_id, placement, _, root = submit_placement(client, made.json()["id"], request, tmp_path / "db")
    assert placement.cpvs == [] and "visibility" in json.loads((root / "index.json").read_text())["placement"]
    answer = client.get(f"/v1/jobs/{job_id}/lookup", params=view_params([-5.0, 0.0, 0.0], [1.0, 0.0, 0.0]))
    assert answer.status_code == 200, answer.text
    pvs = answer.json()["pvs"]
    assert (
        sorted(pvs["elements"]) == ["beside", "wall"] and pvs["count"] == 2 and pvs["of"] > 100 and pvs["region"] == 1
    )
    assert pvs["box"] == [[-10.0, -2.0, 0.0], [0.0, 2.0, 10.0]]
