"""Listings are paged summaries (issue 24): ``GET /v1/scenes`` returned every object of every scene
(60.6 MB after one 10^5-node upload).  The API app in-process with a real SQLite database and blob
folder; scenes uploaded through the route (parsed in the real child process); jobs stored by
``create_job`` (nothing is sent to a broker: listing is what is under test)."""

from __future__ import annotations

import json
import os
import re

import pytest
from fastapi.testclient import TestClient
from scenes import city, instanced_nodes_glb, write_scene
from service_harness import fresh_postgres_database

from farfield.api.app import create_app
from farfield.core.errors import NotFoundError
from farfield.core.exchange import load_scene_bytes
from farfield.service.jobs.admission import create_job
from farfield.service.jobs.schema import JobSpec
from farfield.service.keys import authenticate, create_key
from farfield.service.scenes import get_scene_row
from farfield.service.settings import Settings

KEY = "ff-test-paging-key-0123456789"
OBJECTS = 2000
LONG_NAME = "é" + "x" * 295 + ".glb"  # 300 characters, not all path-safe


def next_link(response) -> str | None:
    found = re.search(r'<([^>]+)>; rel="next"', response.headers.get("Link", ""))
    return found.group(1) if found else None


@pytest.fixture(scope="module", params=["sqlite", "postgresql"])
def api(request, tmp_path_factory):
    """The app on SQLite and, where FARFIELD_TEST_DATABASE_URL names a server, on PostgreSQL (the
    object pages are sliced in each database's SQL)."""
    home = tmp_path_factory.mktemp("paging")
    env, drop = {"FARFIELD_HOME": str(home), "REDIS_URL": "redis://127.0.0.1:1/0", "FARFIELD_ADMIN_KEY": KEY}, None
    if request.param == "postgresql":
        if not os.environ.get("FARFIELD_TEST_DATABASE_URL"):
            pytest.skip(
                "no PostgreSQL server: set FARFIELD_TEST_DATABASE_URL (CI starts one with scripts/postgres-server)"
            )
        env["DATABASE_URL"], drop = fresh_postgres_database(os.environ["FARFIELD_TEST_DATABASE_URL"])
    app = create_app(Settings.from_env(env))
    with TestClient(app, headers={"Authorization": f"Bearer {KEY}"}) as client:
        client.glb = instanced_nodes_glb(OBJECTS)
        response = client.post("/v1/scenes", files={"file": (LONG_NAME, client.glb)})
        assert response.status_code == 201, response.text
        client.big = response.json()
        small = write_scene(city(buildings=2), home, "glb")
        client.small = [
            client.post("/v1/scenes", files={"file": (f"small{i}.glb", small.read_bytes())}).json() for i in range(3)
        ]
        yield client
    app.state.services.db.dispose()
    if drop is not None:
        drop()


def test_scene_records_are_summaries_with_the_original_name(api):
    big = api.big
    assert "objects" not in big and big["object_count"] == OBJECTS and big["triangles"] == OBJECTS
    assert big["original_name"] == LONG_NAME
    assert len(big["name"]) <= 120 and big["name"].endswith("x.glb") and "é" not in big["name"]
    assert big["bounds"] == [[0.0, 0.0, 0.0], [44.5, 0.5, 44.0]]  # a 45 x 45 grid of half-unit triangles
    # the upload's answer is the scene's record plus what the loader warned of (not stored)
    assert big["warnings"] == [] and api.get(f"/v1/scenes/{big['id']}").json() == {
        k: v for k, v in big.items() if k != "warnings"
    }
    assert big["objects_url"] == f"/v1/scenes/{big['id']}/objects"


def test_scene_list_is_paged_newest_first_with_headers(api):
    everything = api.get("/v1/scenes")
    assert everything.headers["X-Total-Count"] == "4" and "Link" not in everything.headers
    listed = everything.json()
    assert [s["id"] for s in listed] == [s["id"] for s in reversed([api.big, *api.small])]
    assert all("objects" not in s for s in listed)
    assert len(everything.content) < 4 * 1024  # four summaries, whatever their object counts

    seen, url, pages = [], "/v1/scenes?limit=3", 0
    while url:
        page = api.get(url)
        assert page.status_code == 200 and page.headers["X-Total-Count"] == "4"
        seen += [s["id"] for s in page.json()]
        url, pages = next_link(page), pages + 1
    assert pages == 2 and seen == [s["id"] for s in listed]
    second = api.get("/v1/scenes", params={"limit": 3, "offset": 3})
    assert second.headers["Link"] == '</v1/scenes?limit=3&offset=0>; rel="prev"'


@pytest.mark.parametrize("query", ["limit=1001", "limit=0", "offset=-1", "limit=ten"])
def test_page_bounds_are_a_422(api, query):
    for path in ("/v1/scenes", f"/v1/scenes/{api.big['id']}/objects", "/v1/jobs"):
        response = api.get(f"{path}?{query}")
        assert response.status_code == 422, (path, response.text)
        assert response.json()["error"] == "ValidationError"
    assert api.get("/v1/scenes?limit=1000").status_code == 200


def test_object_pages_add_up_to_the_scene_in_order(api):
    expected = [obj.summary() for obj in load_scene_bytes(api.glb, "glb", "big.glb").objects]
    got, url = [], api.big["objects_url"] + "?limit=700"
    while url:
        page = api.get(url)
        assert page.headers["X-Total-Count"] == str(OBJECTS) and len(page.json()) <= 700
        got += page.json()
        url = next_link(page)
    assert got == expected  # name, triangles, bounds ... as stored, in the scene's order
    tail = api.get(api.big["objects_url"], params={"offset": OBJECTS - 5, "limit": 1000}).json()
    assert [o["name"] for o in tail] == [o["name"] for o in expected[-5:]]
    assert api.get(api.big["objects_url"], params={"offset": 5 * OBJECTS}).json() == []


def test_another_tenants_objects_are_not_found(api):
    key, _prefix = create_key(api.app.state.services.db, "someone-else")
    response = api.get(api.big["objects_url"], headers={"Authorization": f"Bearer {key}"})
    assert response.status_code == 404
    listing = api.get("/v1/scenes", headers={"Authorization": f"Bearer {key}"})
    assert listing.json() == [] and listing.headers["X-Total-Count"] == "0"


def test_job_list_has_the_same_paging_headers(api):
    db = api.app.state.services.db
    scene = get_scene_row(db, authenticate(db, KEY), api.big["id"], with_objects=True)
    spec = JobSpec(
        scene_id=scene.id,
        resolution=32,
        objects=["node000000", "node001999"],
        viewcells=[{"kind": "box", "lo": [0, 1, -9], "hi": [2, 3, -7]}],
    )
    made = [create_job(db, scene.tenant_id, scene, spec).id for _ in range(3)]
    first = api.get("/v1/jobs", params={"limit": 2, "scene_id": scene.id})
    assert first.headers["X-Total-Count"] == "3"
    assert next_link(first) == f"/v1/jobs?scene_id={scene.id}&limit=2&offset=2"
    rest = api.get(next_link(first))
    assert [j["id"] for j in first.json() + rest.json()] == made[::-1] and next_link(rest) is None
    assert api.get("/v1/jobs", params={"state": "done"}).headers["X-Total-Count"] == "0"
    with pytest.raises(NotFoundError) as missing:  # names a few of the 2,000 objects, not all
        create_job(db, scene.tenant_id, scene, spec.model_copy(update={"objects": ["nope"]}))
    assert (
        "node000019, ..." in str(missing.value)
        and "node000020" not in str(missing.value)
        and len(str(missing.value)) < 800
    )


def test_a_job_s_cells_are_paged_and_its_record_can_omit_them(api):
    """GET /v1/jobs/{id}/cells pages the cells by index with the listings' headers, and
    ?cells=none answers the record without its cells (what a poller asks for: issue 58)."""
    db = api.app.state.services.db
    scene = get_scene_row(db, authenticate(db, KEY), api.small[0]["id"], with_objects=True)
    grid = {"lo": [-40, 5, -110], "hi": [-35, 6, -99], "counts": [5, 1, 2]}
    job = create_job(db, scene.tenant_id, scene, JobSpec(scene_id=scene.id, resolution=16, grid=grid)).id
    first = api.get(f"/v1/jobs/{job}/cells", params={"limit": 4})
    assert first.status_code == 200 and first.headers["X-Total-Count"] == "10"
    assert next_link(first) == f"/v1/jobs/{job}/cells?limit=4&offset=4"
    pages, link = [first.json()], next_link(first)
    while link:
        page = api.get(link)
        pages.append(page.json())
        link = next_link(page)
    full = api.get(f"/v1/jobs/{job}").json()
    assert [len(p) for p in pages] == [4, 4, 2] and sum(pages, []) == full["cells"]
    brief = api.get(f"/v1/jobs/{job}", params={"cells": "none"}).json()
    assert "cells" not in brief and brief["counts"] == full["counts"] and brief["cells_total"] == 10
    assert {k: v for k, v in full.items() if k not in ("cells", "evaluation", "timing", "seconds")} == {
        k: v for k, v in brief.items() if k != "seconds"
    }
    assert api.get(f"/v1/jobs/{job}", params={"cells": "some"}).status_code == 422
    assert api.get("/v1/jobs/nope/cells").status_code == 404


def test_a_scene_fetched_without_objects_does_not_load_them(api):
    """``objects`` is deferred: the rows of listings and of workers never carry it."""
    row = get_scene_row(api.app.state.services.db, authenticate(api.app.state.services.db, KEY), api.big["id"])
    assert "objects" not in row.__dict__


@pytest.fixture(scope="module")
def served(api):
    """The module's app behind a real HTTP server (uvicorn in a thread), for the CLI."""
    import socket
    import threading
    import time

    import uvicorn

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(api.app, host="127.0.0.1", port=port, lifespan="off", log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    while not server.started:
        time.sleep(0.05)
    yield f"http://127.0.0.1:{port}"
    server.should_exit = True
    thread.join(10)


def cli(url: str, *args: str):
    import subprocess
    import sys

    env = {**os.environ, "FARFIELD_API_KEY": KEY, "FARFIELD_URL": url}
    return subprocess.run(
        [sys.executable, "-m", "farfield.cli.main", *args],
        check=False,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )


@pytest.mark.slow
def test_cli_pages_scenes_objects_and_jobs(api, served):
    one = cli(served, "scenes", "--limit", "3")
    assert one.returncode == 0, one.stderr
    assert len(one.stdout.splitlines()) == 3 and "scenes 1-3 of 4: --offset 3" in one.stderr
    every = cli(served, "scenes", "--all", "--limit", "3", "--json")
    assert [s["id"] for s in json.loads(every.stdout)] == [
        s["id"] for s in api.get("/v1/scenes").json()
    ] and every.stderr == ""
    objects = cli(served, "scenes", api.big["id"], "--objects", "--all", "--limit", "1000", "--json")
    assert [o["name"] for o in json.loads(objects.stdout)] == [f"node{i:06d}" for i in range(OBJECTS)]
    shown = cli(served, "scenes", api.big["id"])
    assert shown.returncode == 0 and f"{OBJECTS} objects" in shown.stdout
    assert cli(served, "scenes", "--limit", "1001").returncode == 2  # click's usage error, before any request
    jobs = [j["id"] for j in api.get("/v1/jobs").json()]
    listed = cli(served, "jobs", "--all", "--limit", "1", "--json")
    assert [j["id"] for j in json.loads(listed.stdout)] == jobs
