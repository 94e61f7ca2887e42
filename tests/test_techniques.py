"""The technique registry: one contract every registered technique keeps, and one description of
each technique's options that the library, the CLI and the HTTP API agree on."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from click.testing import CliRunner
from scenes import box_object, city, write_scene
from service_harness import service_client, service_on_each_database, upload, wait_for_job  # noqa: F401 - the service and client fixtures

from farfield.cli.main import _register, cli
from farfield.core.errors import AtlasOverflowError, LayerPlanError
from farfield.core.impostor.bundle import read_bundle, stored_stats, write_bundle
from farfield.core.options import describe_options, options_from_mapping
from farfield.core.scene import Scene
from farfield.core.techniques import TECHNIQUES, get_technique
from farfield.core.viewcells import BoxCell, SphereOutsideCell

pytestmark = pytest.mark.filterwarnings("ignore::farfield.core.scene.SceneWarning")

RESOLUTION = 96


def part_scene() -> Scene:
    """A block with a tower on top: the part of every part-scope technique's contract."""
    return Scene.from_objects(
        [
            box_object("block", (-5.0, 0.0, -5.0), (5.0, 8.0, 5.0), (0.8, 0.35, 0.2, 1.0)),
            box_object("tower", (-1.5, 8.0, -1.5), (1.5, 14.0, 1.5), (0.3, 0.4, 0.85, 1.0)),
        ],
        source="contract-block",
    )


# Per scope: a small scene and a view cell it can be seen from (the part 20 units in front of a
# 4-unit box; the whole city around a 10-unit cube between its lots).
CASES = {
    "part": (part_scene, BoxCell(np.array([-2.0, 3.0, -27.0]), np.array([2.0, 7.0, -23.0]))),
    "scene": (lambda: city(100), BoxCell.from_center([170.0, 5.0, 170.0], 10.0)),
}
# A technique whose promise holds from farther away than the part case's box: its own case.  The
# octahedral impostor of the block at 96 px is accurate beyond 479 units (its stats' accuracy_distance).
OWN_CASES = {"octahedral": (part_scene, SphereOutsideCell(np.array([0.0, 7.0, 0.0]), 500.0))}


def _equal(a, b, path: str = "impostor") -> None:
    """Field by field, arrays bit for bit."""
    if dataclasses.is_dataclass(a):
        assert type(a) is type(b), path
        for field in dataclasses.fields(a):
            _equal(getattr(a, field.name), getattr(b, field.name), f"{path}.{field.name}")
    elif isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        assert a.shape == b.shape and np.array_equal(a, b), path
    elif isinstance(a, (list, tuple)) and a and isinstance(a[0], np.ndarray):
        assert len(a) == len(b), path
        for n, (x, y) in enumerate(zip(a, b)):
            _equal(x, y, f"{path}[{n}]")
    else:
        assert json.loads(json.dumps(a, default=list)) == json.loads(json.dumps(b, default=list)), path


@pytest.mark.parametrize("name", list(TECHNIQUES))
@pytest.mark.slow
def test_every_technique_bakes_round_trips_and_has_no_hole_from_inside_its_cell(name, tmp_path):
    technique = get_technique(name)
    make_scene, cell = OWN_CASES.get(name, CASES[technique.scope])
    scene = make_scene()
    options = technique.options({}, RESOLUTION)
    technique.check(cell, options, scene.bounds if technique.scope == "part" else None)
    impostor = technique.bake(scene, cell, options, None, None)
    assert impostor.technique == name and impostor.payload.count > 0
    assert all(max(page.shape[:2]) <= getattr(options, "max_page", options.resolution) for page in impostor.pages)
    write_bundle(impostor, tmp_path / "bundle")
    back = read_bundle(tmp_path / "bundle")
    _equal(dataclasses.replace(impostor, stats=stored_stats(impostor.stats)), back)  # timings stay out of the bundle
    # A second bake of the same inputs writes the same bytes, file for file.
    write_bundle(technique.bake(scene, cell, options, None, None), tmp_path / "again")
    files = sorted(p.name for p in (tmp_path / "bundle").iterdir())
    assert files == sorted(p.name for p in (tmp_path / "again").iterdir())
    for file in files:
        assert (tmp_path / "bundle" / file).read_bytes() == (tmp_path / "again" / file).read_bytes(), file
    result = technique.evaluate(scene, back, 2, 0, 0)
    totals = result.to_dict()["totals"] if hasattr(result, "to_dict") else result["totals"]
    assert totals["hole_pixels"] == 0, totals
    text = technique.evaluation_text(result, back)  # the CLI's table: its summary counts what --check fails on
    assert "0 hole pixels" in text and f"{totals['bloat_beyond_1px']} pixels bloated beyond 1 px" in text, text
    assert "seconds:" in technique.summary(impostor.stats)


@pytest.mark.parametrize("name", list(TECHNIQUES))
@pytest.mark.slow
def test_every_technique_keeps_its_pages_within_max_page(name):
    technique = get_technique(name)
    make_scene, cell = CASES[technique.scope]
    scene = make_scene()
    if "max_page" not in {
        f.name for f in dataclasses.fields(technique.Options)
    }:  # an LDI's pages are its layers, as wide as its image
        pages = technique.bake(scene, cell, technique.options({}, RESOLUTION), None, None).pages
        assert pages and all(page.shape[:2] == (RESOLUTION, RESOLUTION) for page in pages)
        return
    small = technique.bake(scene, cell, technique.options({"max_page": 128}, RESOLUTION), None, None)
    assert all(max(page.shape[:2]) <= 128 for page in small.pages)
    assert technique.options({}).max_page == 4096  # the portable default
    if technique.scope == "scene":  # the city's faces need more than one small page
        large = technique.bake(scene, cell, technique.options({}, RESOLUTION), None, None)
        assert max(max(page.shape[:2]) for page in large.pages) > 128 and len(small.pages) > len(large.pages)
    if name == "points":  # its 8 x 2 tiles spread over as many pages as they need: nothing overflows
        assert all(page.shape[1] % 8 == 0 and page.shape[0] % 2 == 0 for page in small.pages)
        return
    if name in (
        "layered",
        "envmap",
    ):  # quads larger than a page are cut into quads that fit (farfield.core.layering.tiles.split_rects)
        tiny = technique.bake(scene, cell, technique.options({"max_page": 64}, RESOLUTION), None, None)
        assert all(max(page.shape[:2]) <= 64 for page in tiny.pages) and tiny.quad_count > small.quad_count
        return
    with pytest.raises(AtlasOverflowError, match="64"):  # a TDM chart is not cut
        technique.bake(scene, cell, technique.options({"max_page": 64}, RESOLUTION), None, None)


def test_every_technique_declares_bounded_documented_options():
    for technique in TECHNIQUES.values():
        described = technique.describe()
        assert described["scope"] in ("part", "scene") and described["help"]
        assert [f["name"] for f in described["image"]] == ["resolution", "fov_deg"]
        for entry in described["image"] + described["options"]:
            assert entry["help"], (technique.name, entry["name"])
            if entry["type"] in ("integer", "number"):
                assert entry["minimum"] is not None or entry["exclusive_minimum"] is not None, (
                    technique.name,
                    entry["name"],
                )
            if entry["type"] == "integer":
                assert entry["maximum"] is not None or entry["exclusive_maximum"] is not None, (
                    technique.name,
                    entry["name"],
                )
        # The declared defaults are what an Options made without arguments holds.
        made = dataclasses.asdict(technique.Options())
        for entry in described["options"]:
            default = tuple(entry["default"]) if isinstance(entry["default"], list) else entry["default"]
            if entry["default"] is not None:
                assert made[entry["name"]] == default, (technique.name, entry["name"])


@pytest.mark.parametrize(
    "name, values, message",
    [
        ("layered", {"grid_cell": True}, "grid_cell must be an integer"),
        ("layered", {"grid_cell": "8"}, "grid_cell must be an integer"),
        ("layered", {"padding": 2**70}, "padding must be an integer in [0, 64]"),
        ("layered", {"fill_threshold": float("nan")}, "fill_threshold must be a number in (0, 1]"),
        ("layered", {"enlargement": 2.0}, "unknown layered options ['enlargement']"),
        ("tdm", {"texel_margin": 9}, "texel_margin must be an integer in [0, 8]"),
        ("envmap", {"layers": 8, "near_field": 30.0}, "exactly one of 'layers' or 'near_field'"),
        ("envmap", {"directions": ["+x", "+w"]}, "directions must be a list of strings out of"),
        ("envmap", {"gap_fill": "yes"}, "gap_fill must be true or false"),
        ("envmap", {"max_page": 3000}, "max_page must be a power of two"),
        ("layered", {"max_page": 32768}, "max_page must be an integer in [64, 16384]"),
    ],
)
def test_bad_options_are_refused_with_the_field_named(name, values, message):
    with pytest.raises(LayerPlanError) as error:
        get_technique(name).options(values)
    assert message in str(error.value)


def test_defaults_come_from_each_technique():
    assert get_technique("envmap").options({}).fov_deg == 90.0  # the paper's setting, everywhere
    assert get_technique("layered").options({}).fov_deg == 45.0
    assert get_technique("envmap").options({"near_field": 30.0}).layers is None
    assert get_technique("envmap").options({}).layers == 64
    assert get_technique("envmap").options({"directions": "-z,+x"}).directions == ("+x", "-z")  # canonical order
    with pytest.raises(LayerPlanError, match="resolution must be an integer in"):
        get_technique("tdm").options({}, resolution=0)
    with pytest.raises(LayerPlanError, match=r"\['resolution'\] are the job's own fields"):
        get_technique("tdm").options({"resolution": 64})
    # The generic parser names what it knows, without the image fields.
    with pytest.raises(LayerPlanError, match=r"known: \['grid_cell'"):
        options_from_mapping(get_technique("layered").Options, {"nope": 1}, unlisted=("resolution", "fov_deg"))
    assert {d["name"] for d in describe_options(get_technique("layered").Options)} >= {"grid_cell", "culling"}


def test_cli_bake_takes_options_and_refuses_other_techniques_flags(tmp_path):
    _register()
    scene_file = write_scene(part_scene(), tmp_path, "glb", "block")
    args = ["bake", str(scene_file), "--viewcell", "box:-2,3,-27,2,7,-23", "--resolution", "64", "--quiet"]
    run = CliRunner().invoke(
        cli, [*args, "--out", str(tmp_path / "a"), "--option", "grid_cell=4", "--option", "culling=umbra", "--json"]
    )
    assert run.exit_code == 0, run.output
    parameters = read_bundle(tmp_path / "a").parameters
    assert parameters["grid_cell"] == 4 and parameters["culling"] == "umbra" and parameters["fov_deg"] == 45.0
    wrong = CliRunner().invoke(cli, [*args, "--out", str(tmp_path / "b"), "--enlargement", "3"])
    assert wrong.exit_code == 2 and "--enlargement do not apply to the layered technique" in wrong.output
    unknown = CliRunner().invoke(cli, [*args, "--out", str(tmp_path / "c"), "--option", "nope=1"])
    assert unknown.exit_code == 2 and "unknown option 'nope'" in unknown.output
    assert not (tmp_path / "b").exists() and not (tmp_path / "c").exists()


@pytest.mark.slow
def test_evaluate_check_fails_on_a_broken_guarantee(tmp_path):
    _register()
    scene_file = write_scene(part_scene(), tmp_path, "glb", "block")
    taller = Scene.from_objects(
        [box_object("block", (-5.0, 0.0, -5.0), (5.0, 14.0, 5.0), (0.8, 0.35, 0.2, 1.0))], source="taller"
    )
    taller_file = write_scene(taller, tmp_path, "glb", "taller")
    bake = [
        "bake",
        str(scene_file),
        "--objects",
        "block",
        "--viewcell",
        "box:-2,3,-27,2,7,-23",
        "--resolution",
        "256",
        "--quiet",
        "--out",
        str(tmp_path / "b"),
    ]
    assert CliRunner().invoke(cli, bake).exit_code == 0
    evaluate = ["evaluate", str(tmp_path / "b"), "--random", "2", "--outside", "0", "--check"]
    kept = CliRunner().invoke(cli, [*evaluate[:2], str(scene_file), *evaluate[2:]])
    assert kept.exit_code == 0, kept.output
    # The same impostor against a taller block: what it lacks shows as hole pixels, and --check says so.
    broken = CliRunner().invoke(cli, [*evaluate[:2], str(taller_file), *evaluate[2:]])
    assert (
        broken.exit_code == 4
        and "hole pixels" in broken.output
        and "farfield: error: from inside the view cell" in broken.output
    )


def test_route_cli_and_registry_agree(service, client, tmp_path):
    registry = {"techniques": [t.describe() for t in TECHNIQUES.values()]}
    response = client.get("/v1/techniques")
    assert response.status_code == 200, response.text
    assert response.json() == json.loads(json.dumps(registry))
    run = service.cli("techniques", "--json")
    assert run.returncode == 0, run.stderr
    assert json.loads(run.stdout) == response.json()
    readable = service.cli("techniques")
    for technique in TECHNIQUES.values():
        assert technique.name in readable.stdout
        for option in technique.describe()["options"]:
            assert option["name"] in readable.stdout
    # The OpenAPI document describes the request's technique field with the registry's names.
    schema = client.get("/openapi.json").json()["components"]["schemas"]["JobSpec"]["properties"]
    assert set(TECHNIQUES) <= set(json.dumps(schema["technique"]).replace('"', " ").split())
    assert (
        schema["evaluate"]["type"] == "boolean"
        and schema["evaluate"]["default"] is True
        and "SSIM" in schema["evaluate"]["description"]
    )
    documented = schema["options"]["x-technique-options"]
    for technique in TECHNIQUES.values():
        for option in technique.describe()["options"]:
            assert documented[technique.name]["properties"][option["name"]]["description"] == option["help"]


def test_jobs_name_their_technique_and_the_former_job_type_still_works(client, tmp_path):
    scene_id = upload(client, write_scene(part_scene(), tmp_path, "glb", "block")).json()["id"]
    spec = {
        "scene_id": scene_id,
        "viewcells": [{"kind": "box", "lo": [-2, 3, -27], "hi": [2, 7, -23]}],
        "resolution": 64,
    }
    new = client.post("/v1/jobs", json={**spec, "technique": "tdm", "options": {"texel_margin": 2}})
    assert new.status_code == 201, new.text
    old = client.post("/v1/jobs", json={**spec, "job_type": "layered", "options": {"grid_cell": 4}})
    assert old.status_code == 201, old.text
    assert new.json()["technique"] == "tdm" and old.json()["technique"] == old.json()["job_type"] == "layered"
    assert new.json()["params"]["fov_deg"] == 45.0  # the technique's default, stored explicitly
    clash = client.post("/v1/jobs", json={**spec, "technique": "tdm", "job_type": "layered"})
    assert clash.status_code == 422 and "both given" in clash.text
    both = client.post(
        "/v1/jobs", json={**spec, "technique": "tdm", "job_type": "tdm"}
    )  # the document allows one of them
    assert both.status_code == 422 and "both given" in both.text
    points = client.post(
        "/v1/jobs", json={**spec, "technique": "points", "options": {"min_views": 16, "max_views": 16}}
    )
    assert points.status_code == 201, points.text
    for job in (new.json(), old.json(), points.json()):
        done = wait_for_job(client, job["id"])
        assert done["state"] == "done", done["errors"]
    points_manifest = client.get(f"/v1/jobs/{points.json()['id']}/cells/0/manifest.json").json()
    assert points_manifest["technique"] == "points" and points_manifest["payload"]["counts"]["points"] > 0
    # The cell's payload arrays are served beside its manifest.
    manifest = client.get(f"/v1/jobs/{new.json()['id']}/cells/0/manifest.json").json()
    payload = client.get(f"/v1/jobs/{new.json()['id']}/cells/0/payload.bin")
    assert payload.status_code == 200 and len(payload.content) == manifest["payload"]["nbytes"] > 0


def test_equal_requests_store_equal_options_and_image_fields_are_strict(client, tmp_path):
    scene_id = upload(client, write_scene(part_scene(), tmp_path, "glb", "block")).json()["id"]
    spec = {
        "scene_id": scene_id,
        "viewcells": [{"kind": "box", "lo": [-2, 3, -27], "hi": [2, 7, -23]}],
        "resolution": 64,
        "technique": "tdm",
    }
    stored = []
    for options in ({}, {"enlargement": 2}, {"enlargement": 2.0, "culling": "penumbra"}):
        created = client.post("/v1/jobs", json={**spec, "options": options})
        assert created.status_code == 201, created.text
        stored.append(created.json()["params"])
        client.post(f"/v1/jobs/{created.json()['id']}/cancel")
    assert (
        stored[0] == stored[1] == stored[2]
        and stored[0]["options"]["enlargement"] == 2.0
        and stored[0]["fov_deg"] == 45.0
    )
    envmap = [client.post("/v1/jobs", json={**spec, "technique": "envmap", "grid": None, "viewcells": [{"kind": "box", "lo": [100, 0, 100], "hi": [110, 10, 110]}],
                                            "options": {"layers": 4, "directions": d}}) for d in ("+x,-z", ["-z", "+x"])]  # fmt: skip
    assert [e.status_code for e in envmap] == [201, 201], envmap[0].text
    assert envmap[0].json()["params"] == envmap[1].json()["params"] and envmap[0].json()["params"]["options"][
        "directions"
    ] == ["+x", "-z"]
    for job in envmap:
        client.post(f"/v1/jobs/{job.json()['id']}/cancel")
    for field, value in (("resolution", True), ("resolution", "64"), ("fov_deg", True), ("fov_deg", "45")):
        refused = client.post("/v1/jobs", json={**spec, field: value})
        assert refused.status_code == 422 and field in refused.text, (field, value, refused.text)


def test_a_refused_cell_of_a_request_is_named_as_the_request_gave_it():
    """A job's cell that touches its part is refused naming its index and the cell as JSON, the form
    the request used (it showed a Python dict: ``{'kind': 'box', ...}``)."""
    import json

    from farfield.core.errors import FarfieldError
    from farfield.core.techniques.part import bound_part_cells
    from farfield.core.viewcells import BoxCell

    options = get_technique("layered").options({}, 64)
    bounds = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    cells = [BoxCell(np.array([5.0, 0.0, 0.0]), np.array([6.0, 1.0, 1.0])), BoxCell(np.zeros(3), np.ones(3))]
    with pytest.raises(FarfieldError) as refused:
        bound_part_cells(cells, options, bounds)
    assert str(refused.value).startswith(f"view cell 1 {json.dumps(cells[1].to_dict())}: ")


# Two triangles whose corners are collinear: a scene with no surface to see.
COLLINEAR_OBJ = "o flat\nv 0 0 0\nv 1 0 0\nv 2 0 0\nv 0 1 0\nv 0 2 0\nf 1 2 3\nf 1 4 5\n"


@pytest.mark.parametrize("name", [name for name, t in TECHNIQUES.items() if t.scope == "part"])
def test_every_part_technique_refuses_a_part_of_collinear_triangles_only(name, tmp_path):
    """Layered, tdm and ldi refused such a part; octahedral wrote a full atlas of nothing and points
    baked the conservative LDIs' samples along the segments.  Now each is one line and exit code 2,
    and no bundle is written."""
    _register()
    scene_file = tmp_path / "flat.obj"
    scene_file.write_text(COLLINEAR_OBJ)
    out = tmp_path / "out"
    args = ["bake", str(scene_file), "--viewcell", "box:-1,-1,8,1,1,10", "--technique", name]
    run = CliRunner().invoke(cli, [*args, "--resolution", "64", "--quiet", "--out", str(out)])
    lines = run.output.strip().splitlines()
    assert run.exit_code == 2 and len(lines) == 1 and lines[0].startswith("farfield: error: "), run.output
    assert "nothing to make" in lines[0] or "no visible texel" in lines[0], lines[0]
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.parametrize(
    "scene_text", [COLLINEAR_OBJ, COLLINEAR_OBJ + "p 1 2 3\nl 1 4 5\n"], ids=["faces", "points and lines"]
)
def test_an_envmap_bake_of_a_scene_of_collinear_triangles_only_is_refused(scene_text, tmp_path):
    """An envmap bake of such a scene (besides points and lines, no triangles at all being refused
    when the scene loads) kept 0 of 384 layers, wrote a bundle of nothing and exited 0."""
    _register()
    scene_file = tmp_path / "flat.obj"
    scene_file.write_text(scene_text)
    out = tmp_path / "out"
    args = ["bake", str(scene_file), "--viewcell", "box:-1,-1,8,1,1,10", "--technique", "envmap", "--resolution", "64"]
    run = CliRunner().invoke(cli, [*args, "--quiet", "--out", str(out)])
    lines = run.output.strip().splitlines()
    assert run.exit_code == 2 and len(lines) == 1 and lines[0].startswith("farfield: error: "), run.output
    assert "no triangle of any area" in lines[0] and "envmap" in lines[0], lines[0]
    assert not out.exists() or not any(out.iterdir())
    if "p 1 2 3" in scene_text:
        return
    envmap, cell = get_technique("envmap"), BoxCell(np.array([-1.0, -1, 8]), np.array([1.0, 1, 10]))
    kept = Scene.from_objects(
        [box_object("box", (-20.0, -20.0, -101.0), (20.0, 20.0, -100.0), (0.5, 0.5, 0.5, 1.0))], source="box"
    )
    baked = envmap.bake(kept, cell, envmap.options({"layers": 2}, resolution=64), None, None)  # a surface: baked
    assert baked.stats["layers"] > 0 and baked.stats["texels_kept"] > 0


def test_octahedral_points_and_envmap_jobs_of_collinear_triangles_fail_with_the_reason(client, tmp_path):
    scene_file = tmp_path / "flat.obj"
    scene_file.write_text(COLLINEAR_OBJ)
    uploaded = upload(client, scene_file)
    assert uploaded.status_code in (200, 201), uploaded.text
    spec = {
        "scene_id": uploaded.json()["id"],
        "viewcells": [{"kind": "box", "lo": [-1, -1, 8], "hi": [1, 1, 10]}],
        "resolution": 64,
    }
    expected = {
        "octahedral": "no visible texel in any frame",
        "points": "no triangle of any area",
        "envmap": "no triangle of any area",
    }
    jobs = {}
    for technique in expected:
        created = client.post("/v1/jobs", json={**spec, "technique": technique})
        assert created.status_code == 201, created.text
        jobs[technique] = created.json()["id"]
    for technique, job_id in jobs.items():
        done = wait_for_job(client, job_id)
        assert done["state"] == "failed", done
        assert any(expected[technique] in str(error) for error in done["errors"]), done["errors"]


def test_points_bakes_a_small_far_part_that_no_view_resolves(tmp_path):
    """A 1 cm triangle 90 m from the cell covers a hundredth of a pixel of every view: the appearance
    sees nothing, but the part is there (layered bakes its 4 texels, octahedral its frames).  The
    refusal of "no view saw any point" failed such a part ("is it empty, degenerate or fully
    transparent?"); its points keep their LDI colour, as before that refusal."""
    _register()
    scene_file = tmp_path / "tiny.obj"
    scene_file.write_text("o tiny\nv 0 0 0\nv 0.01 0 0\nv 0 0.01 0\nf 1 2 3\n")
    out = tmp_path / "out"
    args = ["bake", str(scene_file), "--viewcell", "box:-1,-1,80,1,1,100", "--technique", "points"]
    run = CliRunner().invoke(cli, [*args, "--resolution", "64", "--quiet", "--out", str(out)])
    assert run.exit_code == 0, run.output
    assert read_bundle(out).payload.positions.shape[0] >= 1
