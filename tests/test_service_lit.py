"""Lit impostors through the service: a layered job with ``channels: albedo+normal`` (``farfield up``
with a real worker, SQLite) bakes bundles with normal pages and a lit GLB, and its evaluation
reports the lit figures beside the unlit ones."""

from __future__ import annotations

import io
import json
import struct
import zipfile

from scenes import box_object, write_scene
from service_harness import service_client, service_on_sqlite, upload, wait_for_job  # noqa: F401 - fixtures

from farfield.core.scene import Scene
from farfield.core.techniques.part import LIT_REPORT_FIGURES


def test_a_lit_layered_job_bakes_normal_pages_a_lit_glb_and_reports_the_lit_figures(client, tmp_path):
    scene = Scene.from_objects(
        [
            box_object("block", (-5.0, 0.0, -5.0), (5.0, 8.0, 5.0), (0.8, 0.35, 0.2, 1.0)),
            box_object("tower", (-1.5, 8.0, -1.5), (1.5, 14.0, 1.5), (0.3, 0.4, 0.85, 1.0)),
        ],
        source="lit-block",
    )
    response = upload(client, write_scene(scene, tmp_path, "glb", stem="block"))
    assert response.status_code == 201, response.text
    spec = {"scene_id": response.json()["id"], "technique": "layered", "resolution": 64,
            "viewcells": [{"kind": "box", "lo": [-2, 3, -27], "hi": [2, 7, -23]}],
            "options": {"channels": "albedo+normal"}}  # fmt: skip
    created = client.post("/v1/jobs", json=spec)
    assert created.status_code == 201, created.text
    job = wait_for_job(client, created.json()["id"])
    assert job["state"] == "done", job["errors"]
    figures = job["cells"][0]["stats"]["evaluation"]
    assert set(figures["lit"]) == {*LIT_REPORT_FIGURES, "lit_error_mean_worst"}
    assert figures["lit"]["normal_error_median"] < 5.0 and figures["hole_pixels"] == 0
    assert job["evaluation"]["lit"]["cells"] == 1
    assert job["evaluation"]["lit"]["normal_error_median"] == figures["lit"]["normal_error_median"]
    archive = zipfile.ZipFile(io.BytesIO(client.get(f"/v1/jobs/{job['id']}/cells/0/bundle.zip").content))
    names = set(archive.namelist())
    assert {"normal-000.png", "atlas-000.png", "manifest.json", "impostor.glb"} <= names
    manifest = json.loads(archive.read("manifest.json"))
    assert manifest["parameters"]["channels"] == "albedo+normal" and "normal" in manifest["channels"]
    glb = client.get(f"/v1/jobs/{job['id']}/cells/0/impostor.glb").content
    document = json.loads(glb[20 : 20 + struct.unpack_from("<I", glb, 12)[0]])
    assert all("normalTexture" in m for m in document["materials"])
    refused = client.post("/v1/jobs", json={**spec, "options": {"channels": "albedo+depth"}})
    assert refused.status_code == 422 and "channels" in refused.text, refused.text


def test_the_3d_view_lights_a_lit_impostor_as_it_lights_the_scene(client, service, browser, tmp_path):
    """The dashboard's 3D view, lit (one sun and an ambient light, as the lit evaluation): the lit
    impostor's frame against the lit source scene's from the cell's centre, and unlit the same;
    moving the sun changes the lit impostor (its normals are lit), not the unlit one."""
    import base64
    import math

    import numpy as np
    from browser import new_page, tid
    from service_harness import ADMIN_KEY

    from farfield.core.render.raster import Camera

    scene = Scene.from_objects(
        [
            box_object("block", (-5.0, 0.0, -5.0), (5.0, 8.0, 5.0), (0.8, 0.35, 0.2, 1.0)),
            box_object("tower", (-1.5, 8.0, -1.5), (1.5, 14.0, 1.5), (0.3, 0.4, 0.85, 1.0)),
        ],
        source="lit-block",
    )
    scene_id = upload(client, write_scene(scene, tmp_path, "glb", stem="block")).json()["id"]
    spec = {"scene_id": scene_id, "technique": "layered", "resolution": 128, "evaluate": False,
            "viewcells": [{"kind": "box", "lo": [-6, 3, -29], "hi": [2, 9, -21]}], "options": {"channels": "albedo+normal"}}  # fmt: skip
    job = wait_for_job(client, client.post("/v1/jobs", json=spec).json()["id"])
    assert job["state"] == "done", job["errors"]
    page = new_page(browser, service.url)
    page.evaluate(f"localStorage.setItem('farfield.apiKey', '{ADMIN_KEY}')")
    page.goto(f"{service.url}/dashboard/viewer.html?job={job['id']}&size=128&paused=1")
    assert page.evaluate("window.farfieldViewer.ready") is True, page.locator(tid("viewer-error")).text_content()
    camera = Camera.look_at(np.array([-2.0, 6.0, -25.0]), np.array([0.0, 6.0, 0.0]), math.radians(45.0), 128, 1.0, 60.0)
    spec = {"eye": camera.eye.tolist(), "right": camera.right.tolist(), "up": camera.up.tolist(), "forward": camera.forward.tolist(),
            "fov": camera.fov, "near": camera.near, "far": camera.far}  # fmt: skip

    def frame(mode: str, lit: bool, azimuth: float = 240.0) -> np.ndarray:
        light = {"lit": lit, "azimuth": azimuth, "elevation": 35.0}
        answer = page.evaluate("([c, m, l]) => window.farfieldViewer.show(c, m, true, l)", [spec, mode, light])
        assert answer["error"] is None and answer["key"] != "outside", answer
        return np.frombuffer(base64.b64decode(answer["pixels"]), np.uint8).reshape(128, 128, 4)

    def difference(a: np.ndarray, b: np.ndarray) -> float:
        both = (a[..., 3] > 0) & (b[..., 3] > 0)
        assert both.sum() > 2000
        return float(np.abs(a[..., :3].astype(int) - b[..., :3].astype(int)).max(axis=-1)[both].mean())

    lit_impostor, lit_scene = frame("impostors", True), frame("scene", True)
    unlit_impostor, unlit_scene = frame("impostors", False), frame("scene", False)
    assert difference(lit_impostor, lit_scene) <= 4.0 and difference(unlit_impostor, unlit_scene) <= 4.0
    assert difference(lit_impostor, unlit_impostor) > 10.0  # lit is not unlit
    assert difference(frame("impostors", True, azimuth=60.0), lit_impostor) > 10.0  # the sun moved
    assert difference(frame("impostors", False, azimuth=60.0), unlit_impostor) == 0.0
    assert page.js_errors == []
    page.context.close()
