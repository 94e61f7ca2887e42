"""The ``tdm`` job type (seed 003's textured depth meshes) end to end with real parts: ``farfield up``
(embedded redis-server, uvicorn, a real ``celery worker``, SQLite or PostgreSQL, blob directory)
driven over HTTP, the CLI and the dashboard; the downloaded bundles read back with
:func:`farfield.core.impostor.bundle.read_bundle`.  Plus ``farfield bake --technique tdm`` and the option checks.

A small procedural scene (a 10-unit block with a tower on it, and a shed off to the side that the
jobs leave out) and two 4-unit box cells about 20 units in front of it, at 96 pixels: a few seconds
of baking on llvmpipe.
"""

from __future__ import annotations

import json
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from browser import dashboard_page, tid
from click.testing import CliRunner
from scenes import box_object, write_scene
from service_harness import (  # noqa: F401 - the service and client fixtures
    ADMIN_KEY,
    ROOT,
    service_client,
    service_on_each_database,
    stored_options,
    upload,
    wait_for_job,
)

from farfield.cli.main import _register, cli
from farfield.core.errors import LayerPlanError
from farfield.core.exchange import load_scene
from farfield.core.impostor.bundle import MANIFEST_NAME, read_bundle
from farfield.core.scene import Scene
from farfield.core.techniques import get_technique
from farfield.core.techniques.part import REPORT_FIGURES, report_part
from farfield.core.techniques.tdm.technique import TdmOptions, bake_tdm
from farfield.core.viewcells import viewcell_from_dict

PART = ["block", "tower"]  # the represented objects; the shed is left out
# 2 x 1 x 1 box cells of side 4, about 20 units in front (-z) of the block's face at z = -5.
GRID = {"lo": [-4.0, 3.0, -27.0], "hi": [4.0, 7.0, -23.0], "counts": [2, 1, 1]}
OPTIONS = {"enlargement": 2.0, "oversampling": 1}
SPEC = {"job_type": "tdm", "grid": GRID, "objects": PART, "resolution": 96, "fov_deg": 45.0, "options": OPTIONS}
STATS = ("layers", "layers_planned", "voxels", "initial_triangles", "triangles", "meshes", "texture_bytes", "texture_bytes_tile_area",
         "geometry_bytes", "atlas_pages", "seconds")  # fmt: skip


def block_scene() -> Scene:
    """A block (10 x 8 x 10) with a tower (3 x 6 x 3) on top, and a shed 35 units away."""
    return Scene.from_objects(
        [
            box_object("block", (-5.0, 0.0, -5.0), (5.0, 8.0, 5.0), (0.8, 0.35, 0.2, 1.0)),
            box_object("tower", (-1.5, 8.0, -1.5), (1.5, 14.0, 1.5), (0.3, 0.4, 0.85, 1.0)),
            box_object("shed", (40.0, 0.0, -5.0), (46.0, 4.0, 1.0), (0.5, 0.5, 0.5, 1.0)),
        ],
        source="tdm-block",
    )


@pytest.fixture(scope="module")
def block_glb(tmp_path_factory) -> Path:
    return write_scene(block_scene(), tmp_path_factory.mktemp("block"), "glb", stem="block")


@pytest.fixture(scope="module")
def block_id(client, block_glb):
    response = upload(client, block_glb)
    assert response.status_code == 201, response.text
    return response.json()["id"]


# --- the options, without a service -------------------------------------------------------------


def test_tdm_options_of_stored_parameters():
    tdm_options = get_technique("tdm").options_of
    params = {
        "resolution": 96,
        "fov_deg": 45.0,
        "objects": None,
        "options": {"enlargement": 3, "oversampling": 4, "culling": "umbra", "padding": 1},
    }
    options = tdm_options(params)
    assert options == TdmOptions(resolution=96, fov_deg=45.0, enlargement=3, oversampling=4, culling="umbra", padding=1)
    assert tdm_options({**params, "options": {}}) == TdmOptions(resolution=96, fov_deg=45.0)
    names = {o["name"] for o in get_technique("tdm").describe()["options"]}
    assert names == {
        "channels",
        "enlargement",
        "oversampling",
        "culling",
        "max_error_px",
        "budget",
        "pixel_model",
        "padding",
        "texel_margin",
        "max_page",
    }
    assert (
        tdm_options({**params, "options": {"texel_margin": 2}}).texel_margin == 2
    )  # it was missing from the API's list
    with pytest.raises(LayerPlanError, match=r"unknown tdm options \['grid_cell'\]; known: \['enlargement'"):
        tdm_options({**params, "options": {"grid_cell": 8}})
    with pytest.raises(LayerPlanError, match="enlargement"):
        tdm_options({**params, "options": {"enlargement": 0.5}})
    with pytest.raises(LayerPlanError, match="oversampling"):
        tdm_options({**params, "options": {"oversampling": 0}})


# --- the service --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "change, status, message",
    [
        (
            {"options": {**OPTIONS, "grid_cell": 8}},
            422,
            "unknown tdm options ['grid_cell']; known: ['enlargement', 'oversampling'",
        ),
        ({"options": {"enlargement": 0.5}}, 422, "enlargement must be a number in [1, 8], got 0.5"),
        ({"options": {"enlargement": "big"}}, 422, "enlargement must be a number"),
        ({"options": {"enlargement": True}}, 422, "enlargement must be a number"),
        ({"options": {"oversampling": 0}}, 422, "oversampling must be an integer"),
        ({"options": {"oversampling": 1.5}}, 422, "oversampling must be an integer"),
        ({"options": {"padding": 2**70}}, 422, "padding must be an integer in [0, 64]"),
        ({"options": {"culling": "maybe"}}, 422, "culling must be a string out of"),
        ({"options": {"pixel_model": "maybe"}}, 422, "pixel_model"),
        ({"options": {"padding": -1}}, 422, "padding"),
        ({"resolution": 0}, 422, "resolution"),
        (
            {"grid": None, "viewcells": [{"kind": "box", "lo": [-1, 2, -1], "hi": [1, 4, 1]}]},
            422,
            "view cell 0",
        ),  # inside the part: no layer plan
        ({"objects": ["nope"]}, 404, "no objects named"),
        ({"job_type": "voxels"}, 422, "job_type"),
    ],
)
def test_bad_tdm_jobs_are_refused(client, block_id, change, status, message):
    before = client.get("/v1/jobs").json()
    spec = {"scene_id": block_id, **SPEC, **change}
    spec = {k: v for k, v in spec.items() if v is not None}
    response = client.post("/v1/jobs", json=spec)
    assert response.status_code == status, response.text
    assert message in response.text
    assert client.get("/v1/jobs").json() == before


def test_tdm_job_makes_textured_depth_meshes(client, block_id, block_glb, tmp_path):
    created = client.post("/v1/jobs", json={"scene_id": block_id, **SPEC})
    assert created.status_code == 201, created.text
    assert created.json()["job_type"] == "tdm" and created.json()["cells_total"] == 2
    job = wait_for_job(client, created.json()["id"], timeout=300)
    assert job["state"] == "done", job["errors"]
    assert job["counts"]["done"] == 2 and job["progress"] == 1.0
    assert job["params"]["options"] == stored_options("tdm", **OPTIONS) and job["params"]["objects"] == PART
    for cell in job["cells"]:
        assert cell["has_result"] and set(STATS) <= set(cell["stats"]), cell["stats"]
        assert 0 < cell["stats"]["triangles"] < cell["stats"]["initial_triangles"]
        assert (
            cell["stats"]["evaluation"]["hole_pixels"] == 0 and cell["stats"]["evaluation"]["viewpoints"] == 4
        )  # evaluated on the worker
    assert job["evaluation"]["cells"] == 2

    # One cell's bundle on its own, then the whole database.
    manifest = client.get(f"/v1/jobs/{job['id']}/cells/0/manifest.json").json()
    assert manifest["technique"] == "tdm"
    single = client.get(f"/v1/jobs/{job['id']}/cells/1/bundle.zip")
    assert single.status_code == 200, single.text
    (tmp_path / "cell1.zip").write_bytes(single.content)
    with zipfile.ZipFile(tmp_path / "cell1.zip") as archive:
        archive.extractall(tmp_path / "cell1")
    bundle_dirs = {p.parent for p in (tmp_path / "cell1").rglob(MANIFEST_NAME)}
    assert len(bundle_dirs) == 1
    assert read_bundle(bundle_dirs.pop()).technique == "tdm"

    database = client.get(f"/v1/jobs/{job['id']}/database.zip")
    assert database.status_code == 200, database.text
    (tmp_path / "database.zip").write_bytes(database.content)
    with zipfile.ZipFile(tmp_path / "database.zip") as archive:
        archive.extractall(tmp_path / "db")
    index = json.loads((tmp_path / "db" / "index.json").read_text())
    assert index["job_type"] == "tdm" and [c["index"] for c in index["cells"]] == [0, 1]
    assert index["cells"][0]["neighbours"] == [1] and index["cells"][1]["neighbours"] == [0]
    impostors = []
    for entry in index["cells"]:
        assert entry["state"] == "done" and entry["bundle"] is not None
        impostor = read_bundle(tmp_path / "db" / entry["bundle"])
        assert impostor.technique == "tdm"
        assert (
            set(STATS) - {"seconds"} <= set(impostor.stats) and "seconds" not in impostor.stats
        )  # timings stay out of bundles
        assert 0 < impostor.stats["triangles"] < impostor.stats["initial_triangles"]
        assert impostor.stats["layers"] <= impostor.stats["layers_planned"]
        impostors.append(impostor)

    # What the service baked is what core bakes for that cell (the bake is deterministic).
    cell = viewcell_from_dict(job["cells"][0]["viewcell"])
    expected = bake_tdm(load_scene(block_glb), cell, TdmOptions(resolution=96, fov_deg=45.0, **OPTIONS), PART)
    for name in ("layers", "voxels", "initial_triangles", "triangles", "meshes", "atlas_pages"):
        assert impostors[0].stats[name] == expected.stats[name], name


def test_cells_of_a_part_are_evaluated_on_the_worker_unless_switched_off(service, client, block_id, block_glb):
    """A layered job's cell carries its evaluation against the real geometry (``stats.evaluation``):
    the figures core's report_part gives for the same bake, and the seconds it took apart from the
    bake's; the bundle holds none of it.  ``evaluate: false`` skips it and shares the bundle; a job
    that finds the bundle already baked evaluates the stored bundle, to the same figures."""
    spec = {"scene_id": block_id, "technique": "layered", "viewcells": [{"kind": "box", "lo": [-2, 3, -27], "hi": [2, 7, -23]}],
            "objects": PART, "resolution": 64}  # fmt: skip
    first = wait_for_job(client, client.post("/v1/jobs", json=spec).json()["id"])
    assert first["state"] == "done" and first["evaluate"] is True, first["errors"]
    cell = first["cells"][0]
    figures = cell["stats"]["evaluation"]
    assert set(figures) == {*REPORT_FIGURES, "samples", "seconds"}
    assert (
        figures["viewpoints"] == 4 and figures["seconds"] > 0 and cell["stats"]["seconds"]["total"] > 0
    )  # bake and evaluation apart
    layered = get_technique("layered")
    baked = layered.bake(
        load_scene(block_glb), viewcell_from_dict(cell["viewcell"]), layered.options_of(first["params"]), PART, None
    )
    expected = report_part(load_scene(block_glb), baked)
    for name in (*REPORT_FIGURES, "samples"):
        assert figures[name] == pytest.approx(expected[name], rel=1e-12, abs=1e-12), name
    assert figures["hole_pixels"] == 0
    assert first["evaluation"] == {
        "cells": 1, "cells_broken": int(bool(figures["hole_pixels"] or figures["bloat_beyond_1px"])), "hole_pixels": figures["hole_pixels"],
        "bloat_beyond_1px": figures["bloat_beyond_1px"], "colour_error_mean": figures["colour_error_mean"], "ssim_min": figures["ssim_min"],
        "seconds": figures["seconds"],
    }  # fmt: skip
    shown = service.cli("jobs", first["id"], "--url", service.url, "--key", service.env["FARFIELD_ADMIN_KEY"])
    assert (
        shown.returncode == 0
        and f"evaluation: 1 cells, {first['evaluation']['cells_broken']} breaking the guarantee" in shown.stdout
    ), shown.stdout
    manifest = client.get(f"/v1/jobs/{first['id']}/cells/0/manifest.json")
    assert "evaluation" not in manifest.json()["stats"] and "seconds" not in manifest.json()["stats"]

    off = client.post("/v1/jobs", json={**spec, "evaluate": False})
    assert off.status_code == 201 and off.json()["evaluate"] is False, off.text
    off = wait_for_job(client, off.json()["id"])
    assert off["state"] == "done" and off["evaluation"] is None
    assert "evaluation" not in off["cells"][0]["stats"]
    assert client.get(f"/v1/jobs/{off['id']}/cells/0/manifest.json").content == manifest.content  # the same bundle
    refused = client.post("/v1/jobs", json={**spec, "evaluate": "no"})
    assert refused.status_code == 422 and "evaluate" in refused.text

    again = wait_for_job(
        client, client.post("/v1/jobs", json=spec).json()["id"]
    )  # the bundle exists: read back and evaluated
    assert again["state"] == "done" and "seconds" not in again["cells"][0]["stats"]
    for name in (*REPORT_FIGURES, "samples"):
        assert again["cells"][0]["stats"]["evaluation"][name] == pytest.approx(figures[name], rel=1e-12, abs=1e-12), (
            name
        )


def test_tdm_job_of_explicit_and_shaft_cells_with_all_objects(client, block_id):
    """Explicit cells (a box and a shaft), no ``objects`` (the whole scene), non-default options."""
    cells = [
        {"kind": "box", "lo": [10.0, 3.0, -30.0], "hi": [14.0, 7.0, -26.0]},
        {
            "kind": "shaft",
            "apex": [20.5, 7.0, 0.0],
            "direction": [0.0, 0.0, -1.0],
            "apex_angle_deg": 10.0,
            "min_distance": 60.0,
        },  # apex: the scene's centre
    ]
    spec = {
        "scene_id": block_id,
        "job_type": "tdm",
        "viewcells": cells,
        "resolution": 96,
        "options": {"enlargement": 4, "oversampling": 2},
    }
    created = client.post("/v1/jobs", json=spec)
    assert created.status_code == 201, created.text
    job = wait_for_job(client, created.json()["id"], timeout=300)
    assert job["state"] == "done", job["errors"]
    for index in (0, 1):
        manifest = client.get(f"/v1/jobs/{job['id']}/cells/{index}/manifest.json").json()
        assert manifest["technique"] == "tdm"
        assert manifest["stats"]["triangles"] <= manifest["stats"]["initial_triangles"]


def test_cli_submit_tdm(service, block_id, tmp_path):
    env_args = ("--url", service.url, "--key", service.env["FARFIELD_ADMIN_KEY"])
    grid = "-2,3,-27,2,7,-23,1,1,1"
    done = service.cli(
        "submit", block_id, "--technique", "tdm", "--grid", grid, "--objects", "block,tower", "--resolution", "96",
        "--option", "enlargement=3", "--option", "oversampling=2", "--no-evaluate", "--wait", "--download", str(tmp_path / "db"), "--json", *env_args,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    job = json.loads(done.stdout)
    assert job["state"] == "done" and job["job_type"] == "tdm" and job["counts"]["done"] == 1
    assert job["evaluate"] is False and job["evaluation"] is None
    assert job["params"]["options"] == stored_options("tdm", enlargement=3, oversampling=2)
    index = json.loads((tmp_path / "db" / "index.json").read_text())
    impostor = read_bundle(tmp_path / "db" / index["cells"][0]["bundle"])
    assert impostor.technique == "tdm" and impostor.stats["triangles"] < impostor.stats["initial_triangles"]
    bad = service.cli("submit", block_id, "--job-type", "tdm", "--grid", grid, "--option", "enlargement=0.5", *env_args)
    assert (
        bad.returncode == 2
        and len(bad.stderr.strip().splitlines()) == 1
        and "enlargement must be a number in [1, 8]" in bad.stderr
    ), bad.stderr


# --- farfield bake --technique tdm ---------------------------------------------------------------


def _farfield(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "farfield.cli.main", *args], cwd=ROOT, capture_output=True, text=True, timeout=300
    )


def test_cli_bake_tdm(tmp_path):
    scene_file = write_scene(block_scene(), tmp_path, "glb", "block")
    _register()
    out = tmp_path / "bundle"
    args = ["bake", str(scene_file), "--technique", "tdm", "--viewcell", "box:-2,3,-27,2,7,-23", "--objects", "block,tower", "--out", str(out),
            "--resolution", "96", "--enlargement", "2.5", "--oversampling", "2"]  # fmt: skip
    run = CliRunner().invoke(cli, [*args, "--json"])
    assert run.exit_code == 0, run.output
    stats = json.loads(run.output)["stats"]
    assert set(STATS) <= set(stats) and 0 < stats["triangles"] < stats["initial_triangles"]
    impostor = read_bundle(out)
    assert impostor.technique == "tdm" and impostor.stats["triangles"] == stats["triangles"]
    # The readable summary.
    run = CliRunner().invoke(cli, [*args, "--quiet"])
    assert run.exit_code == 0, run.output
    assert f"triangles: {stats['initial_triangles']} -> {stats['triangles']}" in run.output
    for word in ("layers:", "voxels:", "meshes:", "texture:", "geometry:", "seconds:"):
        assert word in run.output


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--enlargement", "0.5"], "enlargement must be a number in [1, 8]"),
        (["--option", "enlargement=0.5"], "enlargement must be a number in [1, 8]"),
        (["--option", "grid_cell=4"], "unknown option 'grid_cell'"),
        (["--oversampling", "0"], "oversampling must be an integer"),
        (["--viewcell", "box:-1,2,-1,1,4,1"], "the part touches or overlaps the view cell"),
    ],
)
@pytest.mark.slow
def test_cli_bake_tdm_refuses_bad_options(tmp_path, extra, message):
    scene_file = write_scene(block_scene(), tmp_path, "glb", "block")
    bad = _farfield(
        "bake",
        str(scene_file),
        "--technique",
        "tdm",
        "--viewcell",
        "box:-2,3,-27,2,7,-23",
        "--out",
        str(tmp_path / "x"),
        *extra,
    )
    assert bad.returncode != 0, bad.stdout
    lines = bad.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("farfield: error:") and message in lines[0], bad.stderr
    assert not (tmp_path / "x").exists()


# --- the dashboard -------------------------------------------------------------------------------


def test_dashboard_submits_a_tdm_job(service, block_id, browser):
    """The job form's technique select and tdm option fields, a refusal from the server, the job page and its statistics."""
    with dashboard_page(browser, service.url, ADMIN_KEY) as page:
        page.locator(f'{tid("job-scene")} option[value="{block_id}"]').wait_for(state="attached")
        # The form's image defaults come with GET /v1/techniques, which may answer after the scenes.
        page.locator(f'{tid("technique")} option[value="envmap"]').wait_for(state="attached")
        page.select_option(tid("job-scene"), block_id)
        assert page.locator(tid("option-enlargement")).is_hidden()
        page.select_option(tid("technique"), "envmap")
        assert page.locator(tid("job-fov")).input_value() == "90"
        page.select_option(tid("technique"), "tdm")
        assert page.locator(tid("option-enlargement")).is_visible() and page.locator(tid("option-layers")).is_hidden()
        assert page.locator(tid("job-objects")).is_visible()
        assert page.locator(tid("job-fov")).input_value() == "45"  # back from envmap's 90
        assert (
            page.locator(tid("option-enlargement")).input_value() == "2"
            and page.locator(tid("option-oversampling")).input_value() == "1"
        )
        assert (
            page.locator(tid("option-enlargement")).get_attribute("min") == "1"
            and page.locator(tid("option-enlargement")).get_attribute("max") == "8"
        )
        page.fill(tid("job-lo"), ", ".join(map(str, GRID["lo"])))
        page.fill(tid("job-hi"), ", ".join(map(str, GRID["hi"])))
        page.fill(tid("job-counts"), "2, 1, 1")
        page.fill(tid("job-resolution"), "96")
        page.fill(tid("job-objects"), "block, tower")
        page.fill(tid("option-enlargement"), "0.5")  # refused by the server
        page.click(tid("job-submit"))
        error = page.locator(tid("job-form-error"))
        error.filter(has_text="enlargement").wait_for()
        assert error.get_attribute("data-source") == "server"
        page.fill(tid("option-enlargement"), "3")
        page.fill(tid("option-oversampling"), "2")
        page.locator(tid("job-evaluate")).uncheck()
        page.click(tid("job-submit"))
        page.wait_for_url("**/#/jobs/*")
        job_id = page.url.rsplit("/", 1)[1]
        page.locator(f'{tid("job-technique-text")}[data-technique="tdm"]').wait_for()
        page.locator(f'{tid("job-state")}[data-state="done"]').wait_for(timeout=120_000)
        assert page.locator(tid("job-counts-text")).inner_text().startswith("2/2 done")
        page.locator(f'{tid("map-cell")}[data-index="1"]').click()
        stats = page.locator(tid("cell-stats"))
        stats.locator('[data-stat="initial_triangles"]').wait_for()
        assert stats.locator('[data-stat="triangles"]').count() == 1
        assert "switched off" in page.locator(tid("cell-evaluation-note")).inner_text()
        assert page.locator(tid("cell-evaluation")).locator("tr").count() == 0
        assert page.locator(tid("job-evaluation")).inner_text() == "off for this job"
        with service.client() as client:
            job = client.get(f"/v1/jobs/{job_id}").json()
        assert job["evaluate"] is False and all("evaluation" not in c["stats"] for c in job["cells"])
        assert job["technique"] == "tdm" and job["params"]["options"] == stored_options(
            "tdm", enlargement=3, oversampling=2
        )
        assert job["params"]["objects"] == PART
        page.click(tid("back-link"))
        page.locator(
            f'{tid("job-row")}[data-job-id="{job_id}"] {tid("job-row-technique")}[data-technique="tdm"]'
        ).wait_for()
        assert page.js_errors == []
