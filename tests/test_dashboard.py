"""The dashboard in a real headless browser (Debian's chromium driven by Playwright) against a real
service (``farfield up``): key, upload, job form errors, submit, live progress, done, the map of the
view-space grid and a cell's atlas thumbnail; the job form's technique select and option fields,
built from ``GET /v1/techniques``.

Needs /usr/bin/chromium (``scripts/install-browser`` installs it where it can); skipped without it.
Set FARFIELD_DASHBOARD_SCREENSHOT=/path.png to keep a screenshot of the job page.
"""

from __future__ import annotations

import os
import time

import pytest
from browser import CHROMIUM, SKIP_REASON, dashboard_page, new_page, tid
from scenes import instanced_nodes_glb
from service_harness import ADMIN_KEY, BUNNY, BUNNY_GRID, service_on_sqlite, stored_options, upload, wait_for_job  # noqa: F401 - the service fixtures

from farfield.api.routes_dashboard import DASHBOARD_DIR
from farfield.core.techniques import TECHNIQUES

if not CHROMIUM.exists():
    pytest.skip(SKIP_REASON, allow_module_level=True)
if not BUNNY.exists():
    pytest.skip("needs ../shared/scenes", allow_module_level=True)
sync_api = pytest.importorskip("playwright.sync_api", reason="needs the playwright package (the test extra)")


@pytest.fixture(scope="module")
def page(browser, service):
    page = new_page(browser, service.url)
    yield page
    page.context.close()


def test_static_files_need_no_key_and_stay_in_their_folder(service):
    with service.client(key=None) as anonymous:
        index = anonymous.get("/")
        assert index.status_code == 200 and "text/html" in index.headers["content-type"]
        assert '<script type="module" src="/dashboard/app.js">' in index.text
        # ES modules: a browser runs a module script only when it is served as JavaScript
        modules = [(p.name, "text/javascript") for p in DASHBOARD_DIR.glob("*.js")]
        assert {"app.js", "api.js", "viewer.js"} <= {name for name, _ in modules}
        for name, kind in [*modules, ("style.css", "text/css")]:
            served = anonymous.get(f"/dashboard/{name}")
            assert served.status_code == 200 and kind in served.headers["content-type"], name
        assert anonymous.get("/dashboard/nothing.js").status_code == 404
        assert anonymous.get("/dashboard/%2e%2e/routes_dashboard.py").status_code == 404
        assert anonymous.get("/v1/jobs").status_code == 401  # the API itself still needs the key


def test_key_is_asked_for_and_a_wrong_one_is_reported(page):
    assert page.locator(tid("key-needed")).is_visible()
    page.fill(tid("api-key"), "ff_wrong_key")
    page.click(tid("api-key-save"))
    page.locator(tid("global-error")).filter(has_text="API key rejected").wait_for()
    page.fill(tid("api-key"), ADMIN_KEY)
    page.click(tid("api-key-save"))
    page.locator(tid("global-error")).wait_for(state="hidden")
    assert page.locator(tid("key-needed")).is_hidden()
    assert page.evaluate("localStorage.getItem('farfield.apiKey')") == ADMIN_KEY


def test_upload_submit_progress_done_atlas(page, service):
    started = time.monotonic()
    page.goto(service.url + "/#/")
    # Upload the bunny through the form.
    page.set_input_files(tid("upload-file"), str(BUNNY))
    page.click(tid("upload-submit"))
    result = page.locator(tid("upload-result"))
    result.wait_for()
    assert (
        "bun_zipper.ply" in result.inner_text()
        and "69,451 triangles" in result.inner_text()
        and "1 object(s)" in result.inner_text()
    )
    scene_id = result.get_attribute("data-scene-id")
    assert page.locator(tid("job-scene")).input_value() == scene_id
    # The grid's corners start at the chosen scene's bounds (a fixed default suited one scale only).
    lo = [float(v) for v in page.locator(tid("job-lo")).input_value().split(",")]
    hi = [float(v) for v in page.locator(tid("job-hi")).input_value().split(",")]
    assert abs(lo[0] - (-0.0946)) < 1e-3 and abs(hi[1] - 0.187) < 2e-3, (lo, hi)

    # A bad job: the server's message is shown on the form, and no job is made.
    page.fill(tid("job-lo"), ", ".join(map(str, BUNNY_GRID["lo"])))
    page.fill(tid("job-hi"), ", ".join(map(str, BUNNY_GRID["hi"])))
    page.fill(tid("job-counts"), ", ".join(map(str, BUNNY_GRID["counts"])))
    page.fill(tid("job-resolution"), "0")
    page.click(tid("job-submit"))
    error = page.locator(tid("job-form-error"))
    error.wait_for()
    assert "resolution must be an integer in [1, 16384], got 0" in error.inner_text()
    assert error.get_attribute("data-source") == "server"
    # One the form itself refuses (not three numbers).
    page.fill(tid("job-resolution"), "256")
    page.fill(tid("job-counts"), "2, two, 1")
    page.click(tid("job-submit"))
    page.locator(tid("job-form-error")).filter(has_text="three numbers").wait_for()
    assert page.locator(tid("job-form-error")).get_attribute("data-source") == "form"
    with service.client() as client:
        assert client.get("/v1/jobs").json() == []

    # Record every update of the job page's progress bar from the moment the job is submitted.
    page.evaluate(
        """() => {
            window.__seen = [];
            const bar = document.querySelector('[data-testid="job-progress"]');
            new MutationObserver(() => window.__seen.push([bar.dataset.state, Number(bar.dataset.progress)]))
                .observe(bar, {attributes: true, attributeFilter: ['data-progress', 'data-state']});
        }"""
    )
    page.fill(tid("job-counts"), ", ".join(map(str, BUNNY_GRID["counts"])))
    page.click(tid("job-submit"))
    page.wait_for_url("**/#/jobs/*")
    job_id = page.url.rsplit("/", 1)[1]
    page.locator(tid("job-page")).wait_for()
    assert page.locator(tid("job-id")).inner_text() == job_id
    page.locator(f'{tid("job-state")}[data-state="done"]').wait_for(timeout=60_000)

    seen = page.evaluate("window.__seen")
    states = [state for state, _ in seen]
    progress = [p for _, p in seen]
    assert states[0] in ("admitting", "queued", "running") and states[-1] == "done", seen
    assert progress[-1] == 1.0 and len(set(progress)) >= 2, seen  # the bar moved while we watched
    assert progress == sorted(progress), seen
    assert page.locator(tid("job-progress")).evaluate("e => e.style.width") == "100%"
    assert page.locator(tid("job-counts-text")).inner_text().startswith("4/4 done")
    assert page.locator(tid("job-eta")).inner_text() == "finished"
    assert page.locator(tid("job-cancel")).is_disabled() and page.locator(tid("job-retry")).is_disabled()
    assert page.locator(tid("job-errors-box")).is_hidden()

    # The map: 2x2x1 cells, so two y levels of 2 (x) by 1 (z) cells, all done.
    assert page.locator(tid("map-level")).is_visible()
    cells = page.locator(tid("map-cell"))
    assert cells.count() == 2
    assert sorted(cells.nth(i).get_attribute("data-index") for i in range(2)) == ["0", "1"]
    assert all(cells.nth(i).get_attribute("data-state") == "done" for i in range(2))
    box0, box1 = (cells.nth(i).bounding_box() for i in range(2))
    by_index = {cells.nth(i).get_attribute("data-index"): cells.nth(i).bounding_box() for i in range(2)}
    assert by_index["0"]["x"] < by_index["1"]["x"]  # x grows to the right
    assert abs(box0["y"] - box1["y"]) < 1  # one row: the cells share their z range
    page.select_option(tid("map-level"), "1")
    page.locator(f'{tid("map-cell")}[data-index="2"]').wait_for()
    page.select_option(tid("map-level"), "0")

    # Click a cell: its atlas page 0 and statistics appear.
    page.locator(f'{tid("map-cell")}[data-index="1"]').click()
    assert page.locator(tid("cell-panel")).get_attribute("data-index") == "1"
    atlas = page.locator(tid("cell-atlas"))
    atlas.wait_for(state="visible")
    assert atlas.evaluate("img => img.complete && img.naturalWidth > 0 && img.naturalHeight > 0")
    assert atlas.get_attribute("src").startswith("blob:")
    assert atlas.get_attribute("data-cell") == "1"
    assert page.locator(tid("cell-state")).get_attribute("data-state") == "done"
    stats = page.locator(tid("cell-stats"))
    assert stats.locator('[data-stat="quads"]').count() == 1 and stats.locator('[data-stat="atlas_pages"]').count() == 1
    # The cell's evaluation against the bunny, as the worker measured it, in its own table.
    with service.client() as client:
        record = client.get(f"/v1/jobs/{job_id}").json()
    measured = next(c for c in record["cells"] if c["index"] == 1)["stats"]["evaluation"]
    figures = page.locator(tid("cell-evaluation"))
    shown = {
        row.get_attribute("data-figure"): row.locator("td").nth(1).inner_text() for row in figures.locator("tr").all()
    }
    assert list(shown) == [
        "hole_pixels",
        "bloat_beyond_1px",
        "colour_error_mean",
        "colour_error_p99",
        "colour_error_1px_mean",
        "ssim",
        "ssim_min",
        "viewpoints",
        "seconds",
    ]
    assert (
        shown["hole_pixels"] == f"{measured['hole_pixels']:,}"
        and shown["bloat_beyond_1px"] == f"{measured['bloat_beyond_1px']:,}"
    )
    for name, places in (
        ("colour_error_mean", 2),
        ("colour_error_p99", 1),
        ("colour_error_1px_mean", 2),
        ("ssim", 3),
        ("ssim_min", 3),
    ):
        assert abs(float(shown[name]) - measured[name]) <= 0.51 * 10**-places, (name, shown[name], measured[name])
    assert shown["viewpoints"] == "4 × 2²"
    kept = measured["hole_pixels"] == 0 and measured["bloat_beyond_1px"] == 0
    assert page.locator(tid("cell-guarantee")).get_attribute("data-guarantee") == ("kept" if kept else "broken")
    assert figures.locator('[data-figure="bloat_beyond_1px"]').get_attribute("class") == (
        None if measured["bloat_beyond_1px"] == 0 else "bad"
    )
    assert stats.locator('[data-stat^="evaluation"]').count() == 0  # not repeated among the bake's statistics
    assert (
        "evaluation" in page.locator(tid("cell-seconds")).inner_text()
        and "bake" in page.locator(tid("cell-seconds")).inner_text()
    )
    summary = record["evaluation"]
    assert (
        page.locator(tid("job-evaluation"))
        .inner_text()
        .startswith(f"4 cells, {summary['cells_broken'] or 'none'} breaking the guarantee")
    )
    # The job's time, broken down: a row per figure, a bake stage per stage the record sums.
    rows = page.locator(tid("job-timing-row"))
    labels = [rows.nth(i).locator("td").first.inner_text() for i in range(rows.count())]
    assert labels[0] == "wall" and labels[-1] == "overhead" and "admission" in labels, labels
    assert [lab for lab in labels if lab.startswith("bake: ")] == [f"bake: {s}" for s in record["timing"]["stages"]]
    if os.environ.get("FARFIELD_DASHBOARD_SCREENSHOT"):
        page.screenshot(path=os.environ["FARFIELD_DASHBOARD_SCREENSHOT"], full_page=True)

    # Another cell replaces the thumbnail.
    page.locator(f'{tid("map-cell")}[data-index="0"]').click()
    page.locator(f'{tid("cell-atlas")}[data-cell="0"]').wait_for(state="visible")
    assert atlas.evaluate("img => img.naturalWidth > 0")

    # Back on the list, the job's row shows it done with a full bar.
    page.click(tid("back-link"))
    row = page.locator(f'{tid("job-row")}[data-job-id="{job_id}"]')
    row.locator(f'{tid("job-row-state")}[data-state="done"]').wait_for()
    assert row.locator(tid("job-row-progress")).evaluate("e => e.style.width") == "100%"
    assert page.js_errors == []
    assert time.monotonic() - started < 60


def _changed(option: dict):
    """A value other than ``option``'s default (within its bounds) and how to enter it: (value, action)."""
    name, kind, default = option["name"], option["type"], option["default"]
    control = tid(f"option-{name}")
    if kind == "boolean":
        return (not default), lambda page: page.locator(control).click()
    if kind == "array":
        first = default[0]
        return [c for c in default if c != first], lambda page: page.locator(
            f'{control} input[value="{first}"]'
        ).uncheck()
    if option["choices"]:
        other = next(c for c in option["choices"] if c != default)
        return other, lambda page: page.select_option(control, other)
    if kind == "integer":
        low = option["minimum"] if option["minimum"] is not None else 1
        value = (
            low + 1
            if default is None
            else (default + 1 if option["maximum"] is None or default + 1 <= option["maximum"] else default - 1)
        )
    else:
        low = option["minimum"] if option["minimum"] is not None else (option["exclusive_minimum"] or 0.0)
        value = (
            low + 2.5
            if default is None
            else ((default + option["maximum"]) / 2 if option["maximum"] is not None else default + 2.5)
        )
    return value, lambda page: page.fill(control, str(value))


def test_job_form_is_built_from_the_technique_registry(page, service):
    """The technique select lists exactly the registry's techniques; each one's option fields are named as
    its options, with defaults, bounds and help; a form left alone sends no options, a changed field
    exactly that option; a job submitted with one changed option is stored with it."""
    with service.client() as client:
        described = client.get("/v1/techniques").json()["techniques"]
        if not client.get("/v1/scenes").json():
            upload(client, BUNNY)
    assert described == [t.describe() for t in TECHNIQUES.values()]
    page.goto(service.url + "/#/")
    page.reload()
    select = page.locator(tid("technique"))
    select.locator(f'option[value="{described[-1]["name"]}"]').wait_for(state="attached")
    assert select.locator("option").evaluate_all("os => os.map(o => o.value)") == list(TECHNIQUES)
    assert select.input_value() == described[0]["name"]

    posted = []

    def capture(route):
        if route.request.method == "POST":
            posted.append(route.request.post_data_json)
            route.abort()
        else:
            route.continue_()

    def submit() -> dict:
        count = len(posted)
        page.click(tid("job-submit"))
        page.locator(tid("job-form-error")).filter(has_text="cannot reach the service").wait_for()
        assert len(posted) == count + 1
        return posted[-1]

    page.route("**/v1/jobs", capture)
    try:
        page.fill(tid("job-lo"), ", ".join(map(str, BUNNY_GRID["lo"])))
        page.fill(tid("job-hi"), ", ".join(map(str, BUNNY_GRID["hi"])))
        page.fill(tid("job-counts"), ", ".join(map(str, BUNNY_GRID["counts"])))
        for technique in described:
            name = technique["name"]
            page.select_option(tid("technique"), name)
            assert page.locator(tid("technique-help")).inner_text() == technique["help"]
            fields = page.locator(f'{tid("option-fields")}[data-technique="{name}"] {tid("option-field")}')
            assert fields.evaluate_all("fs => fs.map(f => f.dataset.option)") == [
                o["name"] for o in technique["options"]
            ]
            assert [o["name"] for o in technique["options"]] == [
                o["name"] for o in TECHNIQUES[name].describe()["options"]
            ]
            for option in technique["options"]:
                field = page.locator(f'{tid("option-field")}[data-option="{option["name"]}"]')
                assert field.get_attribute("title") == option["help"] and option["help"] in field.inner_text()
                control = page.locator(tid(f"option-{option['name']}"))
                if option["type"] in ("integer", "number"):
                    assert control.input_value() == ("" if option["default"] is None else f"{option['default']:g}")
                    for bound in ("minimum", "maximum"):
                        if option[bound] is not None:
                            assert float(control.get_attribute(bound[:3])) == option[bound]
                elif option["type"] == "string" and option["choices"]:
                    assert control.locator("option").evaluate_all("os => os.map(o => o.value)") == option["choices"]
                    assert control.input_value() == option["default"]
            image = {d["name"]: d for d in technique["image"]}
            assert float(page.locator(tid("job-resolution")).input_value()) == image["resolution"]["default"]
            assert float(page.locator(tid("job-fov")).input_value()) == image["fov_deg"]["default"]
            assert page.locator(tid("job-objects")).is_visible() == (technique["scope"] == "part")

            request = submit()  # nothing changed: no options
            assert request["technique"] == name and "options" not in request and "job_type" not in request
            assert "evaluate" not in request  # on unless switched off, and only techniques of one part are evaluated
            assert page.locator(tid("job-evaluate")).is_visible() == (technique["scope"] == "part")
            assert (
                request["resolution"] == image["resolution"]["default"]
                and request["fov_deg"] == image["fov_deg"]["default"]
            )
            expected = {}
            for option in technique["options"]:
                value, enter = _changed(option)
                enter(page)
                expected[option["name"]] = value
            assert submit()["options"] == expected
        # Switching back keeps the edits of each technique's fields and the technique's image defaults.
        first = described[0]
        page.select_option(tid("technique"), first["name"])
        assert set(submit()["options"]) == {o["name"] for o in first["options"]}
        page.locator(tid("job-evaluate")).uncheck()
        assert submit()["evaluate"] is False
        page.locator(tid("job-evaluate")).check()
    finally:
        page.unroute("**/v1/jobs", capture)

    # A real job with one changed option: the service stores exactly that option.
    page.reload()
    page.locator(f'{tid("technique")} option[value="layered"]').wait_for(state="attached")
    page.fill(tid("job-lo"), ", ".join(map(str, BUNNY_GRID["lo"])))
    page.fill(tid("job-hi"), ", ".join(map(str, BUNNY_GRID["hi"])))
    page.fill(tid("job-counts"), "1, 1, 1")
    page.fill(tid("job-resolution"), "64")
    page.fill(tid("option-grid_cell"), "16")
    page.click(tid("job-submit"))
    page.wait_for_url("**/#/jobs/*")
    job_id = page.url.rsplit("/", 1)[1]
    page.locator(f'{tid("job-technique-text")}[data-technique="layered"]').filter(
        has_text=TECHNIQUES["layered"].help
    ).wait_for()
    with service.client() as client:
        job = client.get(f"/v1/jobs/{job_id}").json()
        assert job["technique"] == "layered" and job["params"]["options"] == stored_options("layered", grid_cell=16), (
            job["params"]
        )
        assert job["params"]["resolution"] == 64 and job["params"]["fov_deg"] == 45.0
        wait = wait_for_job(client, job_id, timeout=60)
        assert wait["state"] == "done", wait
    page.click(tid("back-link"))
    page.locator(
        f'{tid("job-row")}[data-job-id="{job_id}"] {tid("job-row-technique")}[data-technique="layered"]'
    ).wait_for()
    assert page.js_errors == []


def test_the_workers_panel_shows_each_worker_s_kind_renderer_and_heartbeat(page, service):
    """GET /v1/workers on the home view: the service's one worker, a CPU one rendering on llvmpipe here."""
    page.goto(f"{service.url}/#/")
    if page.locator(tid("key-needed")).is_visible():
        page.fill(tid("api-key"), ADMIN_KEY)
        page.click(tid("api-key-save"))
    page.locator(tid("worker-renderer")).filter(has_text="llvmpipe").first.wait_for(timeout=60_000)
    row = page.locator(tid("worker-row")).first
    assert row.get_attribute("data-alive") == "true" and row.get_attribute("data-worker").startswith("worker0@")
    assert row.locator(tid("worker-kind")).inner_text() == "CPU"
    assert row.locator(tid("worker-heartbeat")).inner_text().endswith(" ago")
    assert page.js_errors == []


def test_retry_is_refused_with_the_message_and_cancel_ends_a_job(page, service):
    with service.client() as client:
        scene_id = upload(client, BUNNY).json()["id"]
        grid = {**BUNNY_GRID, "counts": [4, 2, 1]}
        job = client.post("/v1/jobs", json={"scene_id": scene_id, "grid": grid, "resolution": 512}).json()
    page.goto(f"{service.url}/#/jobs/{job['id']}")
    page.locator(tid("job-page")).wait_for()
    page.click(tid("job-cancel"))
    page.locator(f'{tid("job-state")}[data-state="cancelled"]').wait_for()
    assert page.locator(tid("job-cancel")).is_disabled()
    # Retry is for failed jobs; the API's refusal is shown (the button is disabled, so call it).
    page.evaluate("document.querySelector('[data-testid=\"job-retry\"]').disabled = false")
    page.click(tid("job-retry"))
    page.locator(tid("job-action-error")).filter(has_text="only a failed job can be retried").wait_for()
    assert page.js_errors == []


def test_scene_info_and_listings_use_the_paged_routes(browser, service):
    """Scenes are listed as summaries; the job form names a scene's first objects from its paged
    objects route (a 2,000-object scene: its list was once in every listing); each list says when
    it shows only the newest page."""
    with service.client() as client:
        made = client.post("/v1/scenes", files={"file": ("many.glb", instanced_nodes_glb(2000))})
        assert made.status_code == 201, made.text
        scene_id = made.json()["id"]
        total_jobs = int(client.get("/v1/jobs", params={"limit": 1}).headers["X-Total-Count"])
    with dashboard_page(browser, service.url, ADMIN_KEY) as page:
        page.locator(f'[data-testid="job-scene"] option[value="{scene_id}"]').wait_for(state="attached")
        page.select_option(tid("job-scene"), scene_id)
        info = page.locator(tid("job-scene-info"))
        info.filter(has_text="node000007, …").wait_for()
        assert "2,000 object(s): node000000, node000001" in info.inner_text() and "node000008" not in info.inner_text()
        assert page.locator(tid("scenes-more")).is_hidden() and page.locator(tid("jobs-more")).is_hidden() == (
            total_jobs <= 100
        )
        assert page.js_errors == []


def test_uploading_a_scene_s_several_files_at_once(page, service):
    """The duck's OBJ, MTL and texture chosen together: one textured scene, as loaded from its folder;
    without the texture, the upload says so."""
    from scenes import SHARED_SCENES

    from farfield.core.exchange import load_scene

    duck = SHARED_SCENES / "duck"
    page.goto(service.url + "/#/")
    page.set_input_files(tid("upload-file"), [str(duck / "duck.obj"), str(duck / "duck.mtl"), str(duck / "duckCM.png")])
    page.click(tid("upload-submit"))
    result = page.locator(tid("upload-result"))
    result.wait_for()
    assert "duck.obj" in result.inner_text() and "4,212 triangles" in result.inner_text()
    with service.client() as client:
        stored = client.get(f"/v1/scenes/{result.get_attribute('data-scene-id')}").json()
    assert stored["content_hash"] == load_scene(duck / "duck.obj").content_hash  # the texture came with it
    assert page.locator(tid("upload-warning")).count() == 0
    page.set_input_files(tid("upload-file"), [str(duck / "duck.obj"), str(duck / "duck.mtl")])
    page.click(tid("upload-submit"))
    page.locator(tid("upload-warning")).first.wait_for()
    assert "duckCM.png" in page.locator(tid("upload-warning")).first.inner_text()
    assert page.js_errors == []
