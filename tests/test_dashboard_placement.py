"""A placement job's page of the dashboard in a real headless browser (Debian's chromium driven by
Playwright) against a real service (``farfield up``): the planning progress while it places, then the
map of its CPVs' regions coloured by estimated time before and after against t_max, a region's CPVs
with their impostors and the objects each replaces, and the totals.

The placement jobs are real: submitted over REST (tests/test_placement_api.py,
:func:`submit_placement`), planned on the worker, baked at 64 px, checked and repaired; the placing
one is caught while its worker plans.

Needs /usr/bin/chromium (``scripts/install-browser``); skipped without it.  Set
FARFIELD_DASHBOARD_SCREENSHOT=/path.png to keep a screenshot of the placement page.
"""

from __future__ import annotations

import os

import pytest
from browser import CHROMIUM, SKIP_REASON, dashboard_page, tid
from scenes import write_scene
from service_harness import ADMIN_KEY, service_on_sqlite, upload, wait_for_job  # noqa: F401 - the service fixtures
from test_placement_api import city_request, placing_job, small_city, submit_placement

if not CHROMIUM.exists():
    pytest.skip(SKIP_REASON, allow_module_level=True)
pytest.importorskip("playwright.sync_api", reason="needs the playwright package (the test extra)")


@pytest.fixture(scope="module")
def jobs(service, tmp_path_factory):
    """Placement jobs submitted over REST: (the done one's (job id, placement, impostors, folder), a
    placing one's id, the street-level one's (job id, placement, ...) with unsolvable regions)."""
    city = small_city()
    with service.client() as client:
        made = upload(client, write_scene(city, tmp_path_factory.mktemp("city"), "glb"))
        assert made.status_code == 201, made.text
        scene_id = made.json()["id"]
        done = submit_placement(
            client, scene_id, city_request(0.5 * city.triangle_count), tmp_path_factory.mktemp("db")
        )
        # At street level with a twentieth of the triangles: the buildings around many regions exceed t_max alone.
        street = submit_placement(
            client,
            scene_id,
            city_request(0.05 * city.triangle_count, [0.0, 2.0, 0.0], [40.0, 6.0, 40.0]),
            tmp_path_factory.mktemp("street"),
        )
        assert street[1].summary["cpvs_unsolvable"] and street[1].summary["cpvs_unsolved"] and street[1].unsolvable
        return done, placing_job(client, scene_id), street


@pytest.fixture(scope="module")
def planned(jobs):
    return jobs[0]


def footprints(placement) -> dict[str, list[dict]]:
    """The CPVs by their region's footprint on x and z (the view space's two longest axes), keyed as the page keys them."""
    out: dict[str, list[dict]] = {}
    for cpv in placement.cpvs:
        (lo, hi) = cpv["region"]
        key = ",".join(
            str(int(v)) if float(v).is_integer() else repr(float(v)) for v in (lo[0], lo[2], hi[0], hi[2])
        )  # as JavaScript writes numbers
        out.setdefault(key, []).append(cpv)
    return out


def test_a_placement_job_s_map_regions_cpvs_and_totals(browser, service, jobs, planned):
    done, placement, impostors, _ = planned
    t_max = placement.summary["t_max"]
    groups = footprints(placement)
    with dashboard_page(browser, service.url, ADMIN_KEY) as page:
        page.goto(f"{service.url}/#/jobs/{done}")
        page.locator(f'{tid("job-state")}[data-state="done"]').wait_for()
        assert page.locator(tid("placement-panel")).is_visible() and page.locator(tid("placement-planning")).is_hidden()
        regions = page.locator(tid("placement-region"))
        regions.first.wait_for()
        # One region per footprint, each holding its CPVs; fewer over t_max after placement than before.
        shown = {r.get_attribute("data-key"): r for r in regions.all()}
        assert set(shown) == set(groups)
        for key, cpvs in groups.items():
            assert int(shown[key].get_attribute("data-cpvs")) == len(cpvs)
            assert float(shown[key].get_attribute("data-time")) == pytest.approx(max(c["time_after"] for c in cpvs))
        over_after = sum(1 for cpvs in groups.values() if max(c["time_after"] for c in cpvs) > t_max)
        over_before = sum(1 for cpvs in groups.values() if max(c["time_before"] for c in cpvs) > t_max)
        assert (
            over_before > over_after
        )  # (the baked figures may leave a few over: the last round's verdict, shown as it is)
        assert page.locator(f'{tid("placement-region")}[data-over="true"]').count() == over_after
        fill_after = {r.get_attribute("data-key"): r.get_attribute("fill") for r in regions.all()}
        page.select_option(tid("placement-colour"), "before")
        page.locator(f'{tid("placement-map")}[data-colour="before"]').wait_for(state="attached")
        assert page.locator(f'{tid("placement-region")}[data-over="true"]').count() == over_before
        for r in regions.all():  # over t_max before, within it after: another colour
            assert float(r.get_attribute("data-time")) == pytest.approx(
                max(c["time_before"] for c in groups[r.get_attribute("data-key")])
            )
            if r.get_attribute("data-over") == "true":
                assert r.get_attribute("fill") != fill_after[r.get_attribute("data-key")]
        # x grows to the right, z downwards.
        boxes = {r.get_attribute("data-key"): r.bounding_box() for r in regions.all()}
        by_x = sorted(groups, key=lambda k: float(k.split(",")[0]))
        by_z = sorted(groups, key=lambda k: float(k.split(",")[1]))
        assert boxes[by_x[0]]["x"] < boxes[by_x[-1]]["x"] and boxes[by_z[0]]["y"] < boxes[by_z[-1]]["y"]

        # Totals: impostors, memory (baked and estimated), CPVs, unsolvable regions, rounds.
        drawn = [imp for imp in placement.impostors if imp["cpvs"]]
        assert page.locator(tid("placement-impostors")).inner_text().startswith(f"{len(drawn)} drawn")
        assert int(page.locator(tid("placement-memory")).get_attribute("data-baked")) == sum(
            impostors[i["id"]].stats["texture_bytes"] for i in drawn
        )
        assert (
            page.locator(tid("placement-cpvs"))
            .inner_text()
            .startswith(f"{len(placement.cpvs)} ({placement.summary['cpvs_solved']} solved")
        )
        assert page.locator(tid("placement-unsolvable")).get_attribute("data-regions") == str(len(placement.unsolvable))
        assert (
            page.locator(tid("placement-rounds"))
            .inner_text()
            .startswith(f"{placement.summary['rounds']} check-and-repair")
        )

        # Click the region with the most CPVs: its CPVs, their impostors and the objects each replaces.
        key = max(groups, key=lambda k: (len(groups[k]), k))
        page.locator(f'{tid("placement-region")}[data-key="{key}"]').click()
        page.locator(f'{tid("region-panel")}[data-key="{key}"]').wait_for()
        rows = page.locator(tid("region-cpv"))
        assert [int(r.get_attribute("data-cpv")) for r in rows.all()] == [c["id"] for c in groups[key]]
        for row, cpv in zip(rows.all(), groups[key]):
            links = row.locator(tid("region-cpv-impostor"))
            assert [int(a.get_attribute("data-index")) for a in links.all()] == cpv["impostors"]
            assert row.get_attribute("data-status") == cpv["status"]
        objects = {imp["id"]: imp["objects"] for imp in placement.impostors}
        listed = page.locator(tid("region-impostor"))
        expected = sorted({i for c in groups[key] for i in c["impostors"]})
        assert [int(li.get_attribute("data-index")) for li in listed.all()] == expected
        for li in listed.all():
            assert li.locator(tid("region-impostor-objects")).inner_text() == ", ".join(
                objects[int(li.get_attribute("data-index"))]
            )
        # An impostor's link opens it in the cell panel: its atlas from the baked bundle.
        first = expected[0]
        page.locator(f'{tid("region-impostor")}[data-index="{first}"] a').click()
        assert page.locator(tid("cell-panel")).get_attribute("data-index") == str(first)
        atlas = page.locator(f'{tid("cell-atlas")}[data-cell="{first}"]')
        atlas.wait_for(state="visible")
        assert atlas.evaluate("img => img.complete && img.naturalWidth > 0")
        if os.environ.get("FARFIELD_DASHBOARD_SCREENSHOT"):
            page.screenshot(path=os.environ["FARFIELD_DASHBOARD_SCREENSHOT"], full_page=True)
        assert page.js_errors == []


def test_a_placing_job_shows_its_planning_progress(browser, service, jobs):
    placing = jobs[1]
    with service.client() as client, dashboard_page(browser, service.url, ADMIN_KEY) as page:
        page.goto(f"{service.url}/#/jobs/{placing}")
        page.locator(f'{tid("job-state")}[data-state="placing"]').wait_for(timeout=120_000)
        box = page.locator(tid("placement-planning"))
        box.wait_for()
        record = client.get(f"/v1/jobs/{placing}").json()["placement"]
        assert record is not None and box.get_attribute("data-step") in {
            record["step"],
            "queued",
            "hierarchy",
            "problem views",
            "candidates",
            "greedy",
        }
        done, total = int(box.get_attribute("data-done")), int(box.get_attribute("data-total"))
        assert 0 <= done <= max(total, 1) and box.get_attribute("data-round") == str(record.get("round", 0))
        text = page.locator(tid("placement-planning-text")).inner_text()
        assert (
            text.startswith("planning: ") and "/" in text
        )  # e.g. "planning: problem views, 189/5,000" (it moves on as we read)
        # No database yet: no map, a note saying when it comes; cancel works while it plans.
        assert (
            page.locator(tid("placement-region")).count() == 0
            and "when the planned impostors are baked" in page.locator(tid("placement-note")).inner_text()
        )
        page.locator(tid("job-cancel")).click()
        page.locator(f'{tid("job-state")}[data-state="cancelled"]').wait_for()
        assert page.js_errors == []


def test_unsolvable_and_unsolved_regions_are_shown(browser, service, jobs):
    job_id, street = jobs[2][:2]
    groups = footprints(street)
    rank = {"solved": 0, "unsolved": 1, "unsolvable": 2}
    with dashboard_page(browser, service.url, ADMIN_KEY) as page:
        page.goto(f"{service.url}/#/jobs/{job_id}")
        page.locator(tid("placement-region")).first.wait_for()
        assert page.locator(tid("placement-unsolvable-region")).count() == len(street.unsolvable)
        assert page.locator(tid("placement-unsolvable")).get_attribute("data-regions") == str(len(street.unsolvable))
        s = street.summary
        assert (
            page.locator(tid("placement-cpvs")).inner_text()
            == f"{s['cpvs']} ({s['cpvs_solved']} solved, {s['cpvs_unsolved']} unsolved, {s['cpvs_unsolvable']} unsolvable)"
        )
        for r in page.locator(tid("placement-region")).all():
            cpvs = groups[r.get_attribute("data-key")]
            assert r.get_attribute("data-status") == max((c["status"] for c in cpvs), key=rank.get)
            assert r.get_attribute("data-over") == "true"  # nothing here is within t_max after placement
        key = next(k for k, cpvs in groups.items() if any(c["status"] == "unsolvable" for c in cpvs))
        page.locator(f'{tid("placement-region")}[data-key="{key}"]').click()
        rows = page.locator(tid("region-cpv"))
        rows.first.wait_for()
        assert [r.get_attribute("data-status") for r in rows.all()] == [c["status"] for c in groups[key]]
        assert page.js_errors == []


def test_a_primitive_budget_job_s_grid_points_images_and_check(browser, service, jobs, planned, tmp_path):
    """Seed 004 as a job: its grid points on the map, marked by their images, and the check of the
    guarantee in the totals; then a frame-time job's page has its own labels back."""
    from test_service_primitive_placement import REQUEST, _scene

    from farfield.service.placement.primitive_budget import DEFAULT_CHECK_VIEWS

    with service.client() as client:
        client.post(
            f"/v1/jobs/{jobs[1]}/cancel"
        )  # the slow placing job holds the worker until then (its own test cancels it; run alone, this one does)
        made = upload(client, write_scene(_scene(), tmp_path, "glb", "city25"))
        assert made.status_code == 201, made.text
        submitted = client.post(
            "/v1/jobs", json={"scene_id": made.json()["id"], "resolution": 32, "placement": REQUEST}
        )
        assert submitted.status_code == 201, submitted.text
        job = wait_for_job(client, submitted.json()["id"], timeout=300)
        assert job["state"] == "done", job["error"]
        doc = client.get(f"/v1/jobs/{job['id']}/placement").json()
    with dashboard_page(browser, service.url, ADMIN_KEY) as page:
        page.goto(f"{service.url}/#/jobs/{job['id']}")
        points = page.locator(tid("placement-point"))
        points.first.wait_for()
        assert points.count() == len(doc["points"])
        assert [int(p.get_attribute("data-images")) for p in points.all()] == [len(p["images"]) for p in doc["points"]]
        assert page.locator(f'{tid("placement-point")}[data-kind="images"]').count() == sum(
            1 for p in doc["points"] if p["images"] and not p["failure"]
        )
        assert (
            page.locator(tid("placement-impostors"))
            .inner_text()
            .startswith(f"{doc['totals']['images']} LDI images ({job['cells_total']} baked")
        )
        assert (
            int(page.locator(tid("placement-memory")).get_attribute("data-baked"))
            == doc["totals"]["memory_bytes_baked"]
            > 0
        )
        assert (
            page.locator(tid("placement-rounds"))
            .inner_text()
            .startswith(f"{DEFAULT_CHECK_VIEWS:,} random views: 100 % within P")
        )
        assert (
            page.locator("#placement-cpvs-label").inner_text() == "grid points"
            and page.locator(tid("region-panel")).is_hidden()
        )
        if os.environ.get("FARFIELD_DASHBOARD_SCREENSHOT"):
            page.screenshot(
                path=os.environ["FARFIELD_DASHBOARD_SCREENSHOT"].replace(".png", "-primitive-budget.png"),
                full_page=True,
            )
        page.goto(f"{service.url}/#/jobs/{planned[0]}")
        page.locator(tid("placement-region")).first.wait_for()
        assert (
            page.locator("#placement-cpvs-label").inner_text() == "CPVs"
            and page.locator(tid("region-panel")).is_visible()
        )
        assert page.js_errors == []


def test_the_job_form_submits_a_placement_job(browser, service, jobs, tmp_path):
    """The form's placement mode: the view space, a budget (one of the two), the algorithm (the
    primitive-budget one switches the technique to ldi) and more knobs as JSON; the job is planned,
    baked and shown."""
    from test_service_primitive_placement import VIEW_SPACE, P, _scene

    with service.client() as client:
        client.post(f"/v1/jobs/{jobs[1]}/cancel")  # the slow placing job would hold the worker
        made = upload(client, write_scene(_scene(), tmp_path, "glb", "form-city"))
        assert made.status_code == 201, made.text
        scene_id = made.json()["id"]
    with dashboard_page(browser, service.url, ADMIN_KEY) as page:
        page.goto(f"{service.url}/#/")
        page.locator(f'{tid("job-scene")} option[value="{scene_id}"]').wait_for(state="attached")
        page.locator(f'{tid("technique")} option[value="ldi"]').wait_for(state="attached")  # the techniques have loaded
        page.select_option(tid("job-scene"), scene_id)
        page.check(tid("job-mode-placement"))
        assert page.locator(tid("placement-fields")).is_visible() and page.locator(tid("job-counts")).is_hidden()
        assert page.locator(tid("objects-field")).is_hidden() and page.locator(tid("evaluate-field")).is_hidden()
        page.fill(tid("job-lo"), ", ".join(map(str, VIEW_SPACE["lo"])))
        page.fill(tid("job-hi"), ", ".join(map(str, VIEW_SPACE["hi"])))
        page.select_option(tid("job-placement-algorithm"), "primitive-budget")
        assert page.locator(tid("technique")).input_value() == "ldi"
        page.fill(tid("job-resolution"), "32")
        page.fill(tid("job-frame-ms"), "10")
        page.fill(tid("job-primitives"), str(P))
        page.click(tid("job-submit"))  # both budgets: the form refuses
        error = page.locator(tid("job-form-error"))
        error.wait_for()
        assert "one of them" in error.inner_text() and error.get_attribute("data-source") == "form"
        page.fill(tid("job-frame-ms"), "")
        page.fill(tid("job-placement-knobs"), '{"grid_points": 2, "max_level": 1, "check_views": 500}')
        page.click(tid("job-submit"))
        page.wait_for_url("**/#/jobs/*")
        page.locator(f'{tid("job-state")}[data-state="done"]').wait_for(timeout=240_000)
        page.locator(tid("placement-point")).first.wait_for()
        assert page.locator(tid("placement-rounds")).inner_text().startswith("500 random views: 100 % within P")
        job_id = page.url.rsplit("/", 1)[-1]
        assert page.js_errors == []
    with service.client() as client:
        job = client.get(f"/v1/jobs/{job_id}").json()
    assert (
        job["technique"] == "ldi"
        and job["params"]["placement"]["algorithm"] == "primitive-budget"
        and job["params"]["resolution"] == 32
    )
