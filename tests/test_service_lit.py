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
