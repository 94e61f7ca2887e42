"""The dashboard's 3D view (``api/dashboard/viewer.html``): the three.js client of an impostor
database, in headless chromium against a real service (``farfield up``: embedded redis-server, a
real celery worker, SQLite, EGL bakes).

For a fixed camera, the view's frame (three.js in chromium: ANGLE on SwiftShader) is compared with
the Python reference runtime's (:class:`farfield.core.techniques.envmap.runtime.EnvmapCellRenderer` on EGL) from the
same camera: the drawn pixels agree within one pixel (what one rasteriser draws, the other draws
within a pixel of it), so the view draws the right impostor, the right near field clipped to the
right cube, and nothing else.  Moving the camera switches to the cell that holds it and prefetches
that cell's neighbours.  Also: the routes the view reads (``index.json``, ``scene.glb``, three.js).

Set FARFIELD_VIEWER_SCREENSHOT=/path/prefix to keep the frames compared (PNG) for diagnosis;
a failing comparison writes them under pytest's tmp_path and names them in the message.
"""

from __future__ import annotations

import base64
import json
import os

import numpy as np
import PIL.Image
import pytest
from browser import CHROMIUM, SKIP_REASON, dashboard_page, new_page, tid
from scenes import city, write_scene
from service_harness import ADMIN_KEY, service_client, service_on_sqlite, upload, wait_for_job  # noqa: F401 - the service fixtures
from test_threejs import compare
from threejs import THREE_SKIP_REASON, three_available

from farfield.core.exchange import load_scene, load_scene_bytes
from farfield.core.impostor.database import ImpostorDatabase
from farfield.core.impostor.glb_compression import BASISU, MESHOPT, read_glb
from farfield.core.placement.runtime import PlacementRenderer
from farfield.core.procedural import city as procedural_city
from farfield.core.render.raster import MeshRenderer
from farfield.core.techniques.envmap.runtime import EnvmapCellRenderer, camera_at, depth_range_for

if not CHROMIUM.exists():
    pytest.skip(SKIP_REASON, allow_module_level=True)
if not three_available():
    pytest.skip(THREE_SKIP_REASON, allow_module_level=True)
pytest.importorskip("playwright.sync_api", reason="needs the playwright package (the test extra)")

# The envmap job of tests/test_service_envmap.py: 3 x 3 x 1 cubic cells of side 10 in front of a
# 16-building city, four horizontal faces recorded (so +y and -y are open: the ground below the
# cell is near-field geometry beyond the cube, in the -y pyramid).
GRID = {"lo": [15.0, 5.0, -45.0], "hi": [45.0, 35.0, -35.0], "counts": [3, 3, 1]}
SPEC = {
    "job_type": "envmap",
    "grid": GRID,
    "resolution": 64,
    "fov_deg": 90.0,
    "options": {"layers": 4, "directions": ["+x", "-x", "+z", "-z"]},
}
CENTRE = 4  # cell (1, 1, 0)
PLACEMENT = {
    "view_space": {"lo": [10.0, 2.0, 10.0], "hi": [70.0, 6.0, 70.0]},
    "budget": {"primitives": 800},
    "cpv_size": 20,
}
SIZE = 128  # the compared frames, square


@pytest.fixture(scope="module")
def city_glb(tmp_path_factory):
    return write_scene(city(buildings=16), tmp_path_factory.mktemp("city"), "glb", stem="city16")


@pytest.fixture(scope="module")
def envmap_job(client, city_glb, tmp_path_factory):
    """(job record, its database read back, the scene as loaded here)."""
    scene_id = upload(client, city_glb).json()["id"]
    created = client.post("/v1/jobs", json={"scene_id": scene_id, **SPEC})
    assert created.status_code == 201, created.text
    job = wait_for_job(client, created.json()["id"], timeout=180)
    assert job["state"] == "done", job["errors"]
    path = tmp_path_factory.mktemp("db") / "database.zip"
    path.write_bytes(client.get(f"/v1/jobs/{job['id']}/database.zip").content)
    with ImpostorDatabase(path) as db:
        yield job, db, load_scene(city_glb)


def open_viewer(browser, service, query: str):
    page = new_page(browser, service.url)
    page.evaluate(f"localStorage.setItem('farfield.apiKey', '{ADMIN_KEY}')")
    page.goto(f"{service.url}/dashboard/viewer.html?{query}")
    assert page.evaluate("window.farfieldViewer.ready") is True, page.locator(tid("viewer-error")).text_content()
    return page


@pytest.fixture(scope="module")
def viewer(browser, service, envmap_job):
    job = envmap_job[0]
    page = open_viewer(browser, service, f"job={job['id']}&size={SIZE}&paused=1")
    yield page
    assert page.js_errors == []
    page.context.close()


def show(page, camera, mode: str = "impostors", impostors: bool = True) -> tuple[np.ndarray, dict]:
    """The view's frame from ``camera`` (h, w, 4) top row first, and its state (with the triangles
    drawn); ``impostors`` False draws only what stays geometry."""
    spec = {"eye": camera.eye.tolist(), "right": camera.right.tolist(), "up": camera.up.tolist(), "forward": camera.forward.tolist(),
            "fov": camera.fov, "near": camera.near, "far": camera.far}  # fmt: skip
    answer = page.evaluate(
        "([c, mode, impostors]) => window.farfieldViewer.show(c, mode, impostors)", [spec, mode, impostors]
    )
    assert answer["error"] is None, answer["error"]
    pixels = np.frombuffer(base64.b64decode(answer["pixels"]), np.uint8).reshape(answer["height"], answer["width"], 4)
    return pixels[::-1].copy(), answer


def keep(images: dict, tmp_path) -> str:
    prefix = os.environ.get("FARFIELD_VIEWER_SCREENSHOT") or str(tmp_path / "viewer")
    for name, image in images.items():
        PIL.Image.fromarray(image, "RGBA").save(f"{prefix}-{name}.png")
    return prefix


def test_the_view_draws_what_the_reference_runtime_draws(viewer, envmap_job, tmp_path):
    job, db, scene = envmap_job
    impostor = db.impostor(CENTRE)
    runtime = EnvmapCellRenderer(scene, impostor)
    full = MeshRenderer(scene.objects)
    cell = db.cell(CENTRE).viewcell
    try:
        # off-centre in the centre cell, towards the city and down a little (the ground below is
        # near field beyond the open -y face), and along a diagonal between two recorded faces
        for eye, forward in (((31.0, 22.0, -42.0), (0.2, -0.35, 1.0)), ((27.0, 18.0, -38.0), (-1.0, -0.1, 1.0))):
            near, far = depth_range_for(scene, cell, eye, runtime.reach)
            camera = camera_at(eye, forward, 60.0, SIZE, near, far)
            reference = runtime.renderer.render(camera)
            drawn, state = show(viewer, camera)
            assert state["key"] == f"cell {CENTRE}" and state["kind"] == "grid"
            figures = compare(drawn, reference)
            # the same triangles: the near field's face ranges and the impostor's quads
            assert state["triangles"] == runtime.near_triangles + runtime.quad_triangles, (
                state["triangles"],
                runtime.near_triangles,
                runtime.quad_triangles,
            )
            # what stays geometry alone: the near field, clipped to its cube (and the open faces' pyramids)
            near_objects = runtime.near.objects(scene)
            with MeshRenderer(near_objects, [runtime.near.clip] * len(near_objects)) as near_field:
                near_reference = near_field.render(camera)
            assert (near_reference[..., 3] > 0).sum() > 100, "the camera should see near-field geometry"
            near_drawn, _ = show(viewer, camera, impostors=False)
            near_figures = compare(near_drawn, near_reference)
            assert near_figures["three_beyond_1px"] == 0 and near_figures["farfield_beyond_1px"] == 0, near_figures
            assert figures["three_pixels"] > 0.15 * SIZE * SIZE, figures
            if os.environ.get("FARFIELD_VIEWER_SCREENSHOT"):
                keep({f"view-{forward[0]}": drawn, f"reference-{forward[0]}": reference}, tmp_path)
            ok = (
                figures["three_beyond_1px"] == 0
                and figures["farfield_beyond_1px"] == 0
                and figures["colour_mean"] < 6.0
            )
            assert ok, f"{figures} (frames: {keep({'view': drawn, 'reference': reference}, tmp_path)}-*.png)"

            # The source scene: every triangle, as farfield draws it.
            source, _ = show(viewer, camera, "scene")
            figures = compare(source, full.render(camera))
            assert (
                figures["three_beyond_1px"] == 0
                and figures["farfield_beyond_1px"] == 0
                and figures["colour_mean"] < 6.0
            ), figures
    finally:
        runtime.release()
        full.release()


def test_moving_switches_to_the_cell_holding_the_camera_and_prefetches_its_neighbours(viewer, envmap_job):
    job, db, scene = envmap_job
    for eye in (
        (16.0, 6.0, -44.0),
        (44.0, 34.0, -36.0),
        (25.0, 10.0, -40.0),
        (35.0, 20.0, -40.0),
    ):  # cells 0, 8, and shared faces
        camera = camera_at(eye, (0.0, 0.0, 1.0), 60.0, SIZE, 0.1, 500.0)
        _, state = show(viewer, camera)
        expected = db.find(eye).index
        assert state["key"] == f"cell {expected}", (eye, state)
        assert expected in state["fetched"] + state["prefetched"]
        state = viewer.evaluate("window.farfieldViewer.settled()")
        assert set(db.cell(expected).neighbours) <= set(state["fetched"]) | set(state["prefetched"]), state
    _, state = show(viewer, camera_at((0.0, 20.0, -40.0), (0.0, 0.0, 1.0), 60.0, SIZE, 0.1, 500.0))
    assert state["key"] == "outside" and "outside every view cell" in state["info"]


def test_a_neighbour_is_there_before_the_camera_arrives(browser, service, envmap_job):
    """In a fresh view: starting in corner cell 0, its neighbours 1, 3 and 4 are prefetched; walking
    into cell 4 downloads nothing more for it."""
    job, db, scene = envmap_job
    page = open_viewer(browser, service, f"job={job['id']}&size={SIZE}&paused=1&cell=0")
    try:
        state = page.evaluate("window.farfieldViewer.settled()")
        assert (
            state["key"] == "cell 0"
            and state["fetched"] == [0]
            and state["prefetched"] == sorted(db.cell(0).neighbours) == [1, 3, 4]
        ), state
        _, state = show(page, camera_at(viewcell_centre(db, CENTRE), (0.0, 0.0, 1.0), 60.0, SIZE, 0.1, 500.0))
        assert state["key"] == f"cell {CENTRE}" and state["fetched"] == [0] and CENTRE in state["prefetched"], state
        assert page.js_errors == []
    finally:
        page.context.close()


def viewcell_centre(db, index: int) -> list[float]:
    cell = db.cell(index).viewcell
    return (0.5 * (cell.lo + cell.hi)).tolist()


@pytest.fixture(scope="module")
def placement_job(client, tmp_path_factory):
    """The quick placement job of tests/test_service_placement.py (a 25-building city at detail 8,
    whose buildings the planner splits into clusters; layered impostors at 64 px): (job, database, scene)."""
    path = write_scene(procedural_city(25, seed=1, detail=8), tmp_path_factory.mktemp("placement-city"), "glb", "city")
    scene_id = upload(client, path).json()["id"]
    created = client.post(
        "/v1/jobs", json={"scene_id": scene_id, "technique": "layered", "resolution": 64, "placement": PLACEMENT}
    )
    assert created.status_code == 201, created.text
    job = wait_for_job(client, created.json()["id"], timeout=300)
    assert job["state"] == "done", (job["error"], job["errors"])
    database = tmp_path_factory.mktemp("placement-db") / "database.zip"
    database.write_bytes(client.get(f"/v1/jobs/{job['id']}/database.zip").content)
    with ImpostorDatabase(database) as db:
        yield job, db, load_scene(path)


def test_a_placement_job_is_drawn_as_its_reference_runtime_draws_it(browser, service, client, placement_job, tmp_path):
    """For views whose CPV draws impostors: the lookup's impostors, and every element they do not
    replace (whole objects, or objects less the replaced clusters: GET .../clusters)."""
    job, db, scene = placement_job
    clusters = client.get(f"/v1/jobs/{job['id']}/clusters").json()
    assert clusters["clusters"] and all(
        name.rsplit("#", 1)[0] == c["object"] for name, c in clusters["clusters"].items()
    )
    page = open_viewer(browser, service, f"job={job['id']}&size={SIZE}&paused=1")
    rng = np.random.default_rng(4)
    lo, hi = (np.array(PLACEMENT["view_space"][k]) for k in ("lo", "hi"))
    compared = cut = 0
    with PlacementRenderer(scene, db) as runtime:
        for _ in range(200):
            eye, forward = rng.uniform(lo, hi), rng.normal(size=3) * [1.0, 0.2, 1.0]
            camera, draws, figures = runtime.prepare(eye, forward, fov_deg=60.0, resolution=SIZE, cull=False)
            if figures.impostors_in_cpv == 0:
                continue
            reference = runtime.render(camera, draws)
            drawn, state = show(page, camera)
            assert state["kind"] == "placement" and state["key"].startswith(f"cpv {figures.cpv} "), (state, figures)
            assert state["triangles"] == figures.triangles, (state["triangles"], figures)
            geometry, _ = show(page, camera, impostors=False)  # the elements no impostor replaces, alone
            kept = compare(geometry, runtime.render(camera, draws[: figures.elements]))
            assert kept["three_beyond_1px"] == 0 and kept["farfield_beyond_1px"] == 0, kept
            result = compare(drawn, reference)
            ok = result["three_beyond_1px"] == 0 and result["farfield_beyond_1px"] == 0 and result["colour_mean"] < 6.0
            assert ok, f"{result} (frames: {keep({'view': drawn, 'reference': reference}, tmp_path)}-*.png)"
            compared += 1
            cut += any(name in clusters["clusters"] for name in runtime.lookup.find(eye, forward)["replaced"])
            if compared == 3:
                break
    assert compared == 3, "no view of the placement draws an impostor"
    assert cut > 0, "no compared view replaces a cluster of a split object"
    assert page.js_errors == []
    page.context.close()


def test_the_job_page_links_to_the_view_and_the_view_flies(browser, service, envmap_job):
    job = envmap_job[0]
    with dashboard_page(browser, service.url, ADMIN_KEY) as page:
        page.goto(f"{service.url}/#/jobs/{job['id']}")
        link = page.locator(tid("job-viewer"))
        link.wait_for()
        assert link.get_attribute("href") == f"/dashboard/viewer.html?job={job['id']}"
        page.goto(f"{service.url}{link.get_attribute('href')}&cell={CENTRE}")
        assert page.evaluate("window.farfieldViewer.ready") is True, page.locator(tid("viewer-error")).text_content()
        page.locator(tid("viewer-status")).filter(has_text=f"cell {CENTRE} (envmap)").wait_for()
        canvas = page.locator(tid("viewer-canvas"))
        canvas.click()
        page.keyboard.down("d")  # strafe right (looking +z: towards -x) out of the centre cell into cell (0, 1, 0)
        page.locator(tid("viewer-status")).filter(has_text=f"cell {CENTRE - 1} (envmap)").wait_for(timeout=60_000)
        page.keyboard.up("d")
        page.click(tid("mode-split"))
        assert "active" in page.locator(tid("mode-split")).get_attribute("class")
        assert page.js_errors == []


def test_the_view_reports_what_it_cannot_show(browser, service):
    page = new_page(browser, service.url)
    try:
        page.evaluate(f"localStorage.setItem('farfield.apiKey', '{ADMIN_KEY}')")
        page.goto(f"{service.url}/dashboard/viewer.html?job=nosuchjob")
        assert page.evaluate("window.farfieldViewer.ready") is False
        assert "nosuchjob" in page.locator(tid("viewer-error")).text_content()
    finally:
        page.context.close()


def test_the_routes_the_view_reads(client, service, envmap_job, city_glb):
    job, db, scene = envmap_job
    index = client.get(f"/v1/jobs/{job['id']}/index.json")
    assert index.status_code == 200 and index.json() == db.index
    assert client.get("/v1/jobs/nosuchjob/index.json").status_code == 404

    glb = client.get(f"/v1/scenes/{job['scene_id']}/scene.glb")
    assert glb.status_code == 200 and glb.headers["content-type"] == "model/gltf-binary"
    again = load_scene_bytes(glb.content, ".glb", "scene.glb")
    assert again.names == scene.names and [o.faces.shape[0] for o in again.objects] == [
        o.faces.shape[0] for o in scene.objects
    ]
    assert client.get(f"/v1/scenes/{job['scene_id']}/scene.glb").content == glb.content  # written once, then read back
    assert client.get("/v1/scenes/nosuchscene/scene.glb").status_code == 404
    # an upload called scene.glb is still exported (its objects' names in the extras), not sent back as uploaded
    named = upload(client, city_glb, name="scene.glb").json()["id"]
    document = read_glb(client.get(f"/v1/scenes/{named}/scene.glb").content)[0]
    assert {m["extras"]["farfield_object"] for m in document["meshes"]} == set(scene.names)

    # a cell's GLB, plain as stored, or compressed on request (core/impostor/glb_compression.py)
    route = f"/v1/jobs/{job['id']}/cells/{CENTRE}/impostor.glb"
    plain = client.get(route)
    assert plain.status_code == 200 and plain.content == (db.cell(CENTRE).bundle / "impostor.glb").read_bytes()
    packed = client.get(route, params={"textures": "ktx2", "geometry": "meshopt", "codec": "uastc"})
    assert packed.status_code == 200 and read_glb(packed.content)[0]["extensionsRequired"] == [MESHOPT, BASISU]
    for bad in ({"textures": "webp"}, {"geometry": "draco"}, {"codec": "bc7"}):
        refused = client.get(route, params=bad)
        assert refused.status_code == 422 and next(iter(bad)) in refused.json()["detail"], refused.text

    # another tenant sees none of it
    made = service.cli("keys", "create", "--tenant", "viewer-other", "--json")
    assert made.returncode == 0, made.stderr
    with service.client(key=json.loads(made.stdout)["key"]) as other:
        for path in (f"/v1/jobs/{job['id']}/index.json", f"/v1/scenes/{job['scene_id']}/scene.glb", route):
            assert other.get(path).status_code == 404, path

    with service.client(key=None) as anonymous:
        assert anonymous.get(f"/v1/scenes/{job['scene_id']}/scene.glb").status_code == 401
        served = anonymous.get("/dashboard/three/build/three.module.js")
        assert served.status_code == 200 and "javascript" in served.headers["content-type"]
        assert anonymous.get("/dashboard/three/examples/jsm/loaders/GLTFLoader.js").status_code == 200
        for outside in ("package.json", "build/../package.json", "src/Three.js", "%2e%2e/%2e%2e/api/app.py"):
            assert anonymous.get(f"/dashboard/three/{outside}").status_code == 404, outside


def test_an_octahedral_job_is_drawn_by_the_shipped_module_as_its_reference_runtime(browser, service, client, tmp_path):
    """A part job of technique ``octahedral`` (one outside-sphere cell): the view finds the cell
    holding the camera, draws the GLB's card with ``octahedral-impostor.js`` (the three frames
    blended, depth marched), as ``Payload.renderer`` draws the bundle, within one pixel."""
    from test_octahedral import tree
    from test_octahedral_threejs import cameras

    from farfield.core.techniques.octahedral.frames import Sphere

    scene_path = write_scene(tree(), tmp_path, "glb", stem="tree")
    scene_id = upload(client, scene_path).json()["id"]
    sphere = Sphere.of_objects(load_scene(scene_path).objects)
    cell = {
        "kind": "outside-sphere",
        "centre": sphere.centre.tolist(),
        "radius": 3.0 * sphere.radius,
        "hemisphere": False,
    }
    options = {"grid": 9, "frame_resolution": 32, "channels": "albedo+normal+depth"}
    created = client.post(
        "/v1/jobs",
        json={
            "scene_id": scene_id,
            "job_type": "octahedral",
            "viewcells": [cell],
            "resolution": 64,
            "options": options,
        },
    )
    assert created.status_code == 201, created.text
    job = wait_for_job(client, created.json()["id"], timeout=180)
    assert job["state"] == "done", job["errors"]
    path = tmp_path / "database.zip"
    path.write_bytes(client.get(f"/v1/jobs/{job['id']}/database.zip").content)
    page = open_viewer(browser, service, f"job={job['id']}&size={SIZE}&paused=1")
    try:
        with ImpostorDatabase(path) as db:
            impostor = db.impostor(0)
            views = cameras(impostor, 3.5 * sphere.radius, SIZE, 7)[5:9]  # four at 45°, 3.5 radii away
            with impostor.payload.renderer(impostor) as reference:
                for camera in views:
                    drawn, state = show(page, camera)
                    assert state["key"] == "cell 0" and state["triangles"] == 2, state  # one card, not the scene
                    figures = compare(drawn, reference.render(camera))
                    assert figures["farfield_pixels"] > 1000, figures
                    assert (
                        figures["three_beyond_1px"] + figures["farfield_beyond_1px"]
                        <= 0.002 * figures["farfield_pixels"]
                    ), figures
                    assert figures["colour_mean"] < 1.0, figures
        assert page.js_errors == []
    finally:
        page.context.close()


def test_a_placement_with_visibility_hides_what_its_pvs_lacks(browser, service, client, tmp_path):
    """Issue 57 item 2: a wall between the view space and a dense block (split into clusters);
    planned with visibility, the lookup answers the region's PVS (the wall and a box beside) and
    the view draws those alone, as the reference runtime does."""
    from farfield.core import procedural
    from farfield.core.scene import Scene, SceneObject

    def box(name, low, high, n=1):
        return SceneObject(name, *procedural.subdivided_box(low, high, n))

    scene = Scene.from_objects([box("wall", (10, -50, -50), (11, 50, 50)), box("hidden", (20, -2, -2), (24, 2, 2), 24),
                                box("beside", (-5, 0, 30), (-4, 1, 31))], "walled")  # fmt: skip
    path = write_scene(scene, tmp_path, "glb", "walled")
    request = {"view_space": {"lo": [-10.0, -2.0, -10.0], "hi": [0.0, 2.0, 10.0]}, "budget": {"primitives": 0.5 * scene.triangle_count},
               "cpv_size": 10, "vdi_deg": 45.0, "visibility": True}  # fmt: skip
    created = client.post("/v1/jobs", json={"scene_id": upload(client, path).json()["id"], "technique": "layered",
                                            "resolution": 64, "placement": request})  # fmt: skip
    assert created.status_code == 201, created.text
    job = wait_for_job(client, created.json()["id"], timeout=300)
    assert job["state"] == "done", (job["error"], job["errors"])
    database = tmp_path / "database.zip"
    database.write_bytes(client.get(f"/v1/jobs/{job['id']}/database.zip").content)
    page = open_viewer(browser, service, f"job={job['id']}&size={SIZE}&paused=1")
    with ImpostorDatabase(database) as db, PlacementRenderer(load_scene(path), db) as runtime:
        for eye, forward in (([-5.0, 0.0, 0.0], [1.0, 0.0, 0.0]), ([-8.0, 1.0, 6.0], [1.0, 0.1, -0.2])):
            camera, draws, figures = runtime.prepare(eye, forward, fov_deg=60.0, resolution=SIZE, cull=False)
            assert figures.pvs == 2 and figures.triangles == 24  # the wall and the box beside, 12 triangles each
            drawn, state = show(page, camera)
            assert state["kind"] == "placement" and " pvs " in state["key"], state
            assert state["triangles"] == figures.triangles, (state["triangles"], figures)
            result = compare(drawn, runtime.render(camera, draws))
            assert result["three_beyond_1px"] == 0 and result["farfield_beyond_1px"] == 0, result
    assert page.js_errors == []
    page.context.close()
