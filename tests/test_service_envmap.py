"""The ``envmap`` job type end to end with real parts: ``farfield up`` (embedded redis-server,
uvicorn, a real ``celery worker``, SQLite or PostgreSQL, blob directory) driven over HTTP, the CLI
and the dashboard; the downloaded impostor database read back with
:class:`farfield.core.impostor.database.ImpostorDatabase`.

A small procedural city (16 buildings) and a 3 x 3 x 1 grid of 10-unit cubic cells in front of it,
at 64 pixels, 90 degrees, 4 layers on the four horizontal faces: a few seconds of baking on llvmpipe.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from browser import dashboard_page, tid
from scenes import city, write_scene
from service_harness import ADMIN_KEY, service_client, service_on_each_database, stored_options, upload, wait_for_job  # noqa: F401 - the service and client fixtures

from farfield.core.exchange import load_scene
from farfield.core.impostor.bundle import MANIFEST_NAME
from farfield.core.impostor.database import ImpostorDatabase
from farfield.core.techniques.envmap.technique import EnvmapOptions, bake_envmap
from farfield.core.viewcells import viewcell_from_dict

# 3 x 3 x 1 cubic cells of side 10 in front of the city (lots x, z in 0..60; ground from -10).
GRID = {"lo": [15.0, 5.0, -45.0], "hi": [45.0, 35.0, -35.0], "counts": [3, 3, 1]}
OPTIONS = {"layers": 4, "directions": ["+x", "-x", "+z", "-z"]}
SPEC = {"job_type": "envmap", "grid": GRID, "resolution": 64, "fov_deg": 90.0, "options": OPTIONS}
CENTRE = 1 + 3 * 1  # the index of cell (1, 1, 0): x fastest


@pytest.fixture(scope="module")
def city_glb(tmp_path_factory) -> Path:
    return write_scene(city(buildings=16), tmp_path_factory.mktemp("city"), "glb", stem="city16")


@pytest.fixture(scope="module")
def city_id(client, city_glb):
    response = upload(client, city_glb)
    assert response.status_code == 201, response.text
    return response.json()["id"]


def test_envmap_grid_job_makes_an_impostor_database(client, city_id, city_glb, tmp_path):
    created = client.post("/v1/jobs", json={"scene_id": city_id, **SPEC})
    assert created.status_code == 201, created.text
    assert created.json()["job_type"] == "envmap" and created.json()["cells_total"] == 9
    job = wait_for_job(client, created.json()["id"], timeout=120)
    assert job["state"] == "done", job["errors"]
    assert job["counts"]["done"] == 9 and job["progress"] == 1.0
    assert job["params"]["options"] == stored_options("envmap", **OPTIONS)
    # The job report evaluates impostors of one part; an envmap cell (the whole scene) is not.
    assert (
        job["evaluate"] is True
        and job["evaluation"] is None
        and all("evaluation" not in c["stats"] for c in job["cells"])
    )

    # The lookup route serves the cell around a viewpoint, as for layered jobs.
    centre = viewcell_from_dict(job["cells"][CENTRE]["viewcell"]).center
    served = client.get(f"/v1/jobs/{job['id']}/lookup", params=dict(zip("xyz", centre.tolist()))).json()
    assert [c["index"] for c in served] == [CENTRE]

    database = client.get(f"/v1/jobs/{job['id']}/database.zip")
    assert database.status_code == 200, database.text
    path = tmp_path / "database.zip"
    path.write_bytes(database.content)
    with ImpostorDatabase(path) as db:
        assert db.technique == "envmap" and db.index["job_type"] == "envmap"
        assert len(db.cells) == 9 and [c.index for c in db.cells] == list(range(9))
        assert db.prefetch(CENTRE) == 8  # a runtime at the centre cell reads its 8 neighbours ahead
        for cell in db.cells:
            assert cell.state == "done" and cell.bundle is not None
            manifest = json.loads((cell.bundle / MANIFEST_NAME).read_text())
            assert manifest["technique"] == "envmap"
            impostor = db.impostor(cell.index)
            assert impostor.technique == "envmap"
            assert "near_field" in impostor.parameters and impostor.parameters["near_field"]["half_size"] > 0
            assert impostor.parameters["directions"] == OPTIONS["directions"]
            assert impostor.stats["faces"] == 4 and impostor.stats["layers_planned"] == 4
        # The index lists each cell's grid neighbours (26-neighbourhood): 8 around the centre, 3 at a corner.
        entries = {e["index"]: e for e in db.index["cells"]}
        assert entries[CENTRE]["neighbours"] == [0, 1, 2, 3, 5, 6, 7, 8]
        assert entries[0]["neighbours"] == [1, 3, 4]
        assert db.cell(CENTRE).neighbours == (0, 1, 2, 3, 5, 6, 7, 8)
        inside = np.array(GRID["lo"]) + np.array([1.3, 1.6, 0.5]) * 10.0  # inside cell (1, 1, 0), off its centre
        found = db.find(inside)
        assert found is not None and found.index == CENTRE
        assert db.find([0.0, 0.0, 0.0]) is None

        # What the service baked is what core bakes for that cell.
        cell = db.cell(CENTRE)
        expected = bake_envmap(
            load_scene(city_glb),
            cell.viewcell,
            EnvmapOptions(resolution=64, fov_deg=90.0, layers=4, directions=("+x", "-x", "+z", "-z")),
        )
        baked = db.impostor(CENTRE)
        assert (
            baked.stats["quads"] == expected.stats["quads"]
            and baked.stats["texels_kept"] == expected.stats["texels_kept"]
        )
        assert baked.parameters["plan"] == json.loads(json.dumps(expected.parameters["plan"]))


def test_layered_index_has_neighbours_too(client, city_id, tmp_path):
    """Every job's index lists neighbours: grid jobs their grid neighbours, explicit cells none."""
    cells = [{"kind": "box", "lo": [20.0, 5.0, -45.0], "hi": [30.0, 15.0, -35.0]}]
    created = client.post("/v1/jobs", json={"scene_id": city_id, "viewcells": cells, "resolution": 64})
    assert created.status_code == 201, created.text
    job = wait_for_job(client, created.json()["id"], timeout=120)
    assert job["state"] == "done" and job["job_type"] == "layered", job["errors"]
    path = tmp_path / "layered.zip"
    path.write_bytes(client.get(f"/v1/jobs/{job['id']}/database.zip").content)
    with ImpostorDatabase(path) as db:
        assert db.technique == "layered" and db.index["cells"][0]["neighbours"] == []
        assert db.impostor(0).technique == "layered"


@pytest.mark.parametrize(
    "change, message",
    [
        ({"grid": {**GRID, "hi": [45.0, 35.0, -25.0]}}, "cubic"),  # 10 x 10 x 20 cells
        ({"grid": None, "viewcells": [{"kind": "box", "lo": [0, 5, -40], "hi": [10, 15, -35]}]}, "cubic"),
        (
            {
                "grid": None,
                "viewcells": [
                    {
                        "kind": "shaft",
                        "apex": [0, 5, -40],
                        "direction": [0, 0, 1],
                        "apex_angle_deg": 10,
                        "min_distance": 1,
                    }
                ],
            },
            "cubic box",
        ),
        ({"options": {**OPTIONS, "pixel_model": "exact"}}, "unknown envmap options ['pixel_model']"),
        ({"options": {**OPTIONS, "near_field": 200.0}}, "exactly one of 'layers' or 'near_field'"),
        ({"options": {"near_field": "far"}}, "near_field must be a number > 0"),
        ({"options": {"directions": ["+x", "+w"]}}, "directions must be a list of strings out of ['+x'"),
        ({"options": {"directions": ["+x", "+x"]}}, "directions must be distinct cube faces"),
        ({"options": {"layers": 0}}, "layers must be an integer in [1, 4096]"),
        ({"options": {"culling": "maybe"}}, "culling must be a string out of"),
        ({"options": {"gap_fill": "yes"}}, "gap_fill must be true or false"),
        ({"objects": ["ground"]}, "whole scene"),
        ({"job_type": "bogus"}, "job_type"),
        ({"technique": "bogus"}, "technique"),
    ],
)
def test_bad_envmap_jobs_are_refused(client, city_id, change, message):
    before = client.get("/v1/jobs").json()
    spec = {"scene_id": city_id, **SPEC, **change}
    spec = {k: v for k, v in spec.items() if v is not None}
    response = client.post("/v1/jobs", json=spec)
    assert response.status_code == 422, response.text
    assert message in response.text
    assert client.get("/v1/jobs").json() == before


def test_envmap_near_field_option_picks_the_layers(client, city_id):
    spec = {**SPEC, "grid": {**GRID, "counts": [3, 3, 1]}, "options": {"near_field": 300.0, "directions": ["+z"]}}
    created = client.post("/v1/jobs", json={"scene_id": city_id, **spec})
    assert created.status_code == 201, created.text
    job = wait_for_job(client, created.json()["id"], timeout=120)
    assert job["state"] == "done", job["errors"]
    manifest = client.get(f"/v1/jobs/{job['id']}/cells/0/manifest.json").json()
    assert manifest["technique"] == "envmap"
    assert manifest["parameters"]["layers"] is None and manifest["stats"]["near_field"] <= 300.0


def test_cli_submit_envmap(service, city_id, tmp_path):
    env_args = ("--url", service.url, "--key", service.env["FARFIELD_ADMIN_KEY"])
    grid = "20,5,-45,30,15,-35,1,1,1"
    done = service.cli(
        "submit", city_id, "--technique", "envmap", "--grid", grid, "--resolution", "64", "--fov", "90",
        "--option", "layers=3", "--option", "directions=+x,-x", "--wait", "--download", str(tmp_path / "db"), "--json", *env_args,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    job = json.loads(done.stdout)
    assert job["state"] == "done" and job["job_type"] == "envmap" and job["counts"]["done"] == 1
    assert job["params"]["options"] == stored_options("envmap", layers=3, directions=["+x", "-x"])
    index = json.loads((tmp_path / "db" / "index.json").read_text())
    assert index["job_type"] == "envmap" and index["cells"][0]["neighbours"] == []
    manifest = json.loads((tmp_path / "db" / index["cells"][0]["bundle"] / MANIFEST_NAME).read_text())
    assert manifest["technique"] == "envmap" and manifest["parameters"]["directions"] == ["+x", "-x"]
    bad = service.cli("submit", city_id, "--job-type", "envmap", "--grid", grid, "--option", "nope=1", *env_args)
    assert (
        bad.returncode == 2
        and len(bad.stderr.strip().splitlines()) == 1
        and "unknown envmap options ['nope']" in bad.stderr
    )
    wrong = service.cli("submit", city_id, "--job-type", "cubes", "--grid", grid, *env_args)
    assert wrong.returncode != 0 and "cubes" in wrong.stderr


def test_dashboard_submits_an_envmap_job(service, city_id, browser):
    """The job form's technique select and envmap option fields, the job page's technique and map, the list's technique column."""
    with dashboard_page(browser, service.url, ADMIN_KEY) as page:
        page.locator(f'{tid("job-scene")} option[value="{city_id}"]').wait_for(state="attached")
        # The form's image defaults come with GET /v1/techniques, which may answer after the scenes.
        page.locator(f'{tid("technique")} option[value="envmap"]').wait_for(state="attached")
        page.select_option(tid("job-scene"), city_id)
        assert page.locator(tid("option-layers")).is_hidden() and page.locator(tid("job-fov")).input_value() == "45"
        page.select_option(tid("technique"), "envmap")
        assert page.locator(tid("option-layers")).is_visible() and page.locator(tid("job-objects")).is_hidden()
        assert page.locator(tid("job-fov")).input_value() == "90"
        assert (
            page.locator(tid("option-gap_fill")).is_visible() and not page.locator(tid("option-gap_fill")).is_checked()
        )
        page.fill(tid("job-lo"), ", ".join(map(str, GRID["lo"])))
        page.fill(tid("job-hi"), ", ".join(map(str, [45.0, 35.0, -25.0])))  # not cubic: refused by the server
        page.fill(tid("job-counts"), "3, 3, 1")
        page.fill(tid("job-resolution"), "64")
        page.fill(tid("option-layers"), "4")
        for face in ("+x", "-x", "+y", "-y"):  # all six are checked: keep +z, -z
            page.locator(f'{tid("option-directions")} input[value="{face}"]').uncheck()
        page.click(tid("job-submit"))
        error = page.locator(tid("job-form-error"))
        error.filter(has_text="cubic").wait_for()
        assert error.get_attribute("data-source") == "server"
        page.fill(tid("job-hi"), ", ".join(map(str, GRID["hi"])))
        page.click(tid("job-submit"))
        page.wait_for_url("**/#/jobs/*")
        job_id = page.url.rsplit("/", 1)[1]
        page.locator(f'{tid("job-technique-text")}[data-technique="envmap"]').wait_for()
        page.locator(f'{tid("job-state")}[data-state="done"]').wait_for(timeout=60_000)
        assert page.locator(tid("job-counts-text")).inner_text().startswith("9/9 done")
        # The map: 3 y levels of 3 (x) by 1 (z) cells, all done; level 1 holds cells 3..5.
        cells = page.locator(tid("map-cell"))
        assert cells.count() == 3 and all(cells.nth(i).get_attribute("data-state") == "done" for i in range(3))
        page.select_option(tid("map-level"), "1")
        page.locator(f'{tid("map-cell")}[data-index="{CENTRE}"]').click()
        page.locator(f'{tid("cell-atlas")}[data-cell="{CENTRE}"]').wait_for(state="visible")
        assert page.locator(tid("cell-stats")).locator('[data-stat="near_field"]').count() == 1
        with service.client() as client:
            job = client.get(f"/v1/jobs/{job_id}").json()
        assert job["technique"] == "envmap" and job["params"]["options"] == stored_options(
            "envmap", layers=4, directions=["+z", "-z"]
        )
        page.click(tid("back-link"))
        row = page.locator(f'{tid("job-row")}[data-job-id="{job_id}"]')
        row.locator(f'{tid("job-row-technique")}[data-technique="envmap"]').wait_for()

        # With 2 layers everything the cell sees lies in its near field: no atlas page, and the panel says so.
        with service.client() as client:
            spec = {
                **SPEC,
                "grid": {**GRID, "counts": [1, 1, 1], "hi": [25.0, 15.0, -35.0]},
                "options": {"layers": 2, "directions": ["+z", "-z"]},
            }
            near = wait_for_job(
                client, client.post("/v1/jobs", json={"scene_id": city_id, **spec}).json()["id"], timeout=60
            )
        assert near["state"] == "done" and near["cells"][0]["stats"]["atlas_pages"] == 0, near
        page.goto(f"{service.url}/#/jobs/{near['id']}")
        page.locator(f'{tid("job-state")}[data-state="done"]').wait_for()
        page.locator(f'{tid("map-cell")}[data-index="0"]').click()
        page.locator(tid("cell-atlas-note")).filter(has_text="near field").wait_for()
        assert page.locator(tid("cell-atlas")).is_hidden()
        assert page.js_errors == []
