"""A technique registered from outside ``farfield.core.techniques`` (``tests/toy_technique.py``: one
fixed grey quad) is baked by the CLI and the service and listed by ``farfield techniques``,
``GET /v1/techniques`` and the dashboard's job form, with nothing else changed: what "one package
+ one registry line" promises.  ``FARFIELD_TECHNIQUE_MODULES`` names the module to every process
(CLI, API, workers); the test process itself never imports it, so the registry it shares with the
other tests stays farfield's own."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import zipfile

import numpy as np
import pytest
from service_harness import ADMIN_KEY, BUNNY, ROOT, start_service, upload, wait_for_job

from farfield.core.errors import LayerPlanError, UnknownTechniqueError, error_kind
from farfield.core.impostor.bundle import MANIFEST_NAME, read_bundle
from farfield.core.impostor.glb import impostor_glb
from farfield.core.impostor.impostor import PAYLOAD_KINDS, Payload, QuadPayload
from farfield.core.techniques import TECHNIQUES, Technique, get_technique, register

TOY_ENV = {
    "FARFIELD_TECHNIQUE_MODULES": "toy_technique",
    "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT / "tests"), os.environ.get("PYTHONPATH")])),
}
# One box cell in front of the bunny (bounds x -0.095..0.061, y 0.033..0.187, z -0.062..0.059).
CELL = "box:-0.6,0.05,-0.05,-0.4,0.15,0.05"
ONE_CELL_GRID = {"lo": [-0.6, 0.05, -0.05], "hi": [-0.4, 0.15, 0.05], "counts": [1, 1, 1]}
SHADE = 90

needs_bunny = pytest.mark.skipif(not BUNNY.exists(), reason="needs ../shared/scenes")


def farfield(*args: str, toy: bool = True) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "FARFIELD_TECHNIQUE_MODULES"}
    if toy:
        env.update(TOY_ENV)
    return subprocess.run(
        [sys.executable, "-m", "farfield.cli.main", *args],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )


def test_the_registry_refuses_what_it_cannot_hold_and_an_unknown_name_is_bad_input():
    before = dict(TECHNIQUES)
    layered = get_technique("layered")
    with pytest.raises(ValueError, match="is not a technique"):
        register(object())
    with pytest.raises(ValueError, match="a technique named 'layered' is registered already"):
        register(dataclasses.replace(layered))
    with pytest.raises(ValueError, match="unknown payload kind 'voxels'"):
        register(dataclasses.replace(layered, name="voxelised", payload_kind="voxels"))
    assert TECHNIQUES == before
    with pytest.raises(
        UnknownTechniqueError,
        match=r"unknown technique 'toy'; one of \['layered', 'envmap', 'tdm', 'points', 'ldi', 'octahedral'\]",
    ) as raised:
        get_technique("toy")
    assert not isinstance(raised.value, LayerPlanError)
    assert error_kind(raised.value).value == (422, 2)


def test_every_technique_and_payload_kind_has_the_members_consumers_call():
    """The registry's techniques are :class:`Technique`s naming a registered payload kind; every
    payload kind is a :class:`Payload`, and says how it is drawn (triangles or not) and counted."""
    for technique in TECHNIQUES.values():
        assert isinstance(technique, Technique) and technique.payload_kind in PAYLOAD_KINDS
        assert technique.describe()["payload"] == technique.payload_kind
        assert technique.describe()["placeable"] == (technique.estimate is not None)
    assert sorted(PAYLOAD_KINDS) == ["ldi", "mesh", "octahedral", "points", "quads"]
    for kind, cls in PAYLOAD_KINDS.items():
        payload = cls.empty()
        assert isinstance(payload, Payload) and payload.kind == kind
        assert payload.quad_count == 0 and payload.point_count == 0 and payload.triangle_count == 0
    one = QuadPayload(np.zeros((1, 4, 3)), np.zeros((1, 4, 2)), np.zeros(1, np.int64), np.zeros(1, np.int64))
    assert (one.quad_count, one.point_count, one.triangle_count) == (1, 0, 2)


@needs_bunny
@pytest.mark.slow
def test_the_cli_bakes_and_lists_a_technique_registered_from_outside(tmp_path):
    listed = farfield("techniques", "--json")
    assert listed.returncode == 0, listed.stderr
    described = json.loads(listed.stdout)["techniques"]
    assert [t["name"] for t in described] == [*TECHNIQUES, "toy"]
    toy = described[-1]
    assert toy["scope"] == "part" and toy["payload"] == "quads" and not toy["placeable"] and not toy["runtime"]
    assert [o["name"] for o in toy["options"]] == ["shade"] and toy["options"][0]["default"] == 200
    assert described[:-1] == [t.describe() for t in TECHNIQUES.values()]  # farfield's own, as this process has them

    out = tmp_path / "toy"
    baked = farfield(
        "bake",
        str(BUNNY),
        "--viewcell",
        CELL,
        "--technique",
        "toy",
        "--option",
        f"shade={SHADE}",
        "--out",
        str(out),
        "--quiet",
    )
    assert baked.returncode == 0, baked.stderr
    assert "toy: 1 quad, 256 texture bytes" in baked.stdout  # the technique's own summary
    impostor = read_bundle(out)
    assert impostor.technique == "toy" and impostor.parameters["shade"] == SHADE
    assert isinstance(impostor.payload, QuadPayload) and impostor.quad_count == 1 and impostor.triangle_count == 2
    assert len(impostor.pages) == 1 and np.all(impostor.pages[0][..., :3] == SHADE)
    glb = (out / "impostor.glb").read_bytes()
    assert glb == impostor_glb(impostor)
    document = json.loads(glb[20 : 20 + int.from_bytes(glb[12:16], "little")])
    assert document["nodes"][0]["extras"]["farfield"]["technique"] == "toy"
    assert [len(m["primitives"]) for m in document["meshes"]] == [1] and len(document["images"]) == 1

    # Without the setting the technique is unknown: the CLI refuses its name and its bundles (bad input, exit 2).
    unknown = farfield(
        "bake", str(BUNNY), "--viewcell", CELL, "--technique", "toy", "--out", str(tmp_path / "no"), toy=False
    )
    assert unknown.returncode == 2 and "'toy' is not one of" in unknown.stderr
    evaluated = farfield("evaluate", str(out), str(BUNNY), toy=False)
    assert evaluated.returncode == 2, evaluated.stderr
    assert (
        "farfield: error: unknown technique 'toy'; one of ['layered', 'envmap', 'tdm', 'points', 'ldi', 'octahedral']"
        in evaluated.stderr
    )
    broken = subprocess.run([sys.executable, "-m", "farfield.cli.main", "techniques"], cwd=ROOT, capture_output=True, text=True, timeout=300,
                            env={**os.environ, "FARFIELD_TECHNIQUE_MODULES": "no_such_module_here"})  # fmt: skip
    assert broken.returncode == 2 and "technique module 'no_such_module_here' cannot be imported" in broken.stderr


@pytest.fixture(scope="module")
def toy_service(tmp_path_factory):
    if not BUNNY.exists():
        pytest.skip("needs ../shared/scenes")
    running = start_service(tmp_path_factory.mktemp("farfield-home"), **TOY_ENV)
    yield running
    assert running.stop() == 0


@pytest.mark.service
def test_the_service_lists_and_bakes_a_technique_registered_from_outside(toy_service, tmp_path):
    with toy_service.client() as client:
        described = client.get("/v1/techniques").json()["techniques"]
        assert [t["name"] for t in described] == [*TECHNIQUES, "toy"]
        assert described[:-1] == [t.describe() for t in TECHNIQUES.values()]
        toy = described[-1]
        assert toy["payload"] == "quads" and [o["name"] for o in toy["options"]] == ["shade"]
        assert "toy" in json.dumps(
            client.get("/openapi.json").json()["components"]["schemas"]["JobSpec"]
        )  # the job schema names it

        scene = upload(client, BUNNY)
        assert scene.status_code == 201, scene.text
        refused = client.post(
            "/v1/jobs",
            json={"scene_id": scene.json()["id"], "technique": "toy", "grid": ONE_CELL_GRID, "options": {"shade": 300}},
        )
        assert refused.status_code == 422 and "shade" in refused.text
        created = client.post(
            "/v1/jobs",
            json={
                "scene_id": scene.json()["id"],
                "technique": "toy",
                "grid": ONE_CELL_GRID,
                "resolution": 48,
                "options": {"shade": SHADE},
            },
        )
        assert created.status_code == 201, created.text
        job = wait_for_job(client, created.json()["id"], timeout=600)
        assert job["state"] == "done", job["errors"]
        assert job["job_type"] == "toy" and job["params"]["options"] == {"shade": SHADE}
        cell = job["cells"][0]
        assert (
            cell["stats"]["quads"] == 1 and cell["stats"]["evaluation"]["viewpoints"] == 4
        )  # evaluated on the worker, drawn by its payload
        archive = client.get(f"/v1/jobs/{job['id']}/cells/0/bundle.zip")
        assert archive.status_code == 200, archive.text
        glb = client.get(f"/v1/jobs/{job['id']}/cells/0/impostor.glb")
        assert glb.status_code == 200, glb.text
    (tmp_path / "cell.zip").write_bytes(archive.content)
    with zipfile.ZipFile(tmp_path / "cell.zip") as zipped:
        zipped.extractall(tmp_path / "cell")
    (bundle,) = {p.parent for p in (tmp_path / "cell").rglob(MANIFEST_NAME)}
    impostor = read_bundle(bundle)
    assert impostor.technique == "toy" and impostor.resolution == 48 and impostor.quad_count == 1
    assert np.all(impostor.pages[0][..., :3] == SHADE)
    (tmp_path / "toy.glb").write_bytes(glb.content)  # checked by the glTF validator with the session's other GLBs
    assert glb.content == impostor_glb(impostor)


@pytest.mark.service
def test_the_dashboard_job_form_offers_a_technique_registered_from_outside(toy_service, browser):
    from browser import dashboard_page, tid

    with toy_service.client() as client:
        toy = client.get("/v1/techniques").json()["techniques"][-1]
    with dashboard_page(browser, toy_service.url, ADMIN_KEY) as page:
        select = page.locator(tid("technique"))
        select.locator('option[value="toy"]').wait_for(state="attached")
        assert select.locator("option").evaluate_all("os => os.map(o => o.value)") == [*TECHNIQUES, "toy"]
        page.select_option(tid("technique"), "toy")
        assert page.locator(tid("technique-help")).inner_text() == toy["help"]
        fields = page.locator(f'{tid("option-fields")}[data-technique="toy"] {tid("option-field")}')
        assert fields.evaluate_all("fs => fs.map(f => f.dataset.option)") == ["shade"]
        shade = page.locator(tid("option-shade"))
        assert (
            shade.input_value() == "200"
            and float(shade.get_attribute("min")) == 0
            and float(shade.get_attribute("max")) == 255
        )
        assert page.js_errors == []
