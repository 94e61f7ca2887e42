"""Hostile requests get a 4xx whose body is valid JSON naming the field, never a 500 (issue 24): the
API app in-process with a real SQLite database and blob folder, a scene uploaded through the route
(its parse runs in the real child process); no broker is needed, since nothing here is accepted."""

from __future__ import annotations

import json

import pytest
from fastapi.testclient import TestClient
from scenes import city, write_scene

from farfield.api.app import create_app
from farfield.service.settings import Settings

KEY = "ff-test-hostile-key-0123456789"


@pytest.fixture(scope="module")
def api(tmp_path_factory):
    home = tmp_path_factory.mktemp("hostile")
    settings = Settings.from_env(
        {"FARFIELD_HOME": str(home), "REDIS_URL": "redis://127.0.0.1:1/0", "FARFIELD_ADMIN_KEY": KEY}
    )
    with TestClient(create_app(settings), headers={"Authorization": f"Bearer {KEY}"}) as client:
        path = write_scene(city(buildings=3), home, "glb")
        response = client.post("/v1/scenes", files={"file": (path.name, path.read_bytes())})
        assert response.status_code == 201, response.text
        client.scene_id = response.json()["id"]
        yield client


def job(api, **change) -> dict:
    body = {
        "scene_id": api.scene_id,
        "resolution": 64,
        "viewcells": [{"kind": "box", "lo": [40, 1, 40], "hi": [44, 5, 44]}],
    }
    body.update(change)
    if "grid" in change:
        del body["viewcells"]
    return body


@pytest.mark.parametrize(
    "raw, field",
    [
        ('"resolution": NaN', "resolution"),
        ('"resolution": Infinity', "resolution"),
        ('"resolution": -Infinity', "resolution"),
        ('"resolution": 1e400', "resolution"),
        ('"fov_deg": NaN', "fov_deg"),
        ('"objects": [NaN]', "objects"),
        ('"grid": {"lo": [0, 0, 0], "hi": [1, 1, 1], "counts": [1e400, 1, 1]}', "counts"),
        ('"viewcells": [{"kind": "box", "lo": [NaN, 1, 40], "hi": [44, 5, 44]}]', "lo must be finite"),
        ('"grid": {"lo": [NaN, 0, 0], "hi": [1, 1, 1], "counts": [1, 1, 1]}', "grid"),
        ('"options": {"padding": Infinity}', "padding"),
    ],
)
@pytest.mark.slow
def test_non_finite_numbers_are_a_422_naming_the_field(api, raw, field):
    """JSON has no NaN or infinity, but Python's parser reads them: the 422 used to echo them back
    and fail to encode (a 500, and the client's kept-alive connection reset)."""
    base = job(api)
    if raw.startswith('"grid"') or raw.startswith('"viewcells"'):
        del base["viewcells"]
    body = json.dumps(base)[:-1] + ", " + raw + "}"
    response = api.post("/v1/jobs", content=body, headers={"Content-Type": "application/json"})
    assert response.status_code == 422, response.text
    answer = response.json()  # valid JSON
    assert answer["error"] in ("ValidationError", "ViewCellError", "LayerPlanError") and field in answer["detail"]
    assert api.get("/v1/health").status_code == 200  # the connection is still usable


@pytest.mark.parametrize("value", ["1", True, 1.5])
def test_loose_types_are_refused(api, value):
    """``"1"`` and ``true`` were taken as 1 in a grid's counts (pydantic's lax mode)."""
    response = api.post("/v1/jobs", json=job(api, resolution=value))
    assert response.status_code == 422 and "resolution" in response.json()["detail"]
    response = api.post("/v1/jobs", json=job(api, grid={"lo": [0, 0, 0], "hi": [1, 1, 1], "counts": [value, 1, 1]}))
    assert response.status_code == 422 and "counts" in response.json()["detail"]
    if value != 1.5:  # and in a view cell's coordinates (a float is a coordinate)
        cell = {"kind": "box", "lo": [40, value, 40], "hi": [44, 5, 44]}
        response = api.post("/v1/jobs", json=job(api, viewcells=[cell]))
        assert response.status_code == 422 and "lo must be 3 numbers" in response.json()["detail"], response.text


@pytest.mark.slow
def test_a_long_upload_name_is_shortened_not_a_500(api, tmp_path):
    path = write_scene(city(buildings=2), tmp_path, "glb")
    response = api.post("/v1/scenes", files={"file": ("b" * 242 + ".glb", path.read_bytes())})
    assert response.status_code == 201, response.text
    name = response.json()["name"]
    assert len(name) == 120 and name.endswith("b.glb")
    assert response.json()["original_name"] == "b" * 242 + ".glb"  # kept as metadata, never in a path


@pytest.mark.slow
def test_a_deep_node_chain_upload_is_refused_quickly_with_413(api):
    """The campaign's 2.3 MB glTF of a 100,000-deep node chain blocked its upload for 40 s."""
    from test_scene_limits import gltf_bytes

    nodes = [{"children": [i + 1]} for i in range(99_999)] + [{"mesh": 0}]
    before = api.get("/v1/scenes").json()
    response = api.post("/v1/scenes", files={"file": ("deep.gltf", gltf_bytes(nodes, [0]))})
    assert response.status_code == 413, response.text
    assert response.json()["error"] == "SceneTooCostlyError" and "FARFIELD_MAX_SCENE_NODES" in response.json()["detail"]
    assert api.get("/v1/scenes").json() == before


def test_scene_limits_come_from_the_environment():
    settings = Settings.from_env({"FARFIELD_MAX_SCENE_DEPTH": "16", "FARFIELD_MAX_SCENE_TRIANGLES": "1000"})
    assert (settings.scene_limits.depth, settings.scene_limits.triangles, settings.scene_limits.nodes) == (
        16,
        1000,
        50_000,
    )
    assert Settings.from_env(settings.environment()).scene_limits == settings.scene_limits  # handed to workers


def test_two_authorization_headers_are_refused_alike_by_the_upload_check_and_every_route(api):
    """Issue 59, item 7: the upload's early check read the last Authorization header and the route
    the first, so an upload sent with one tenant's key and then another's passed the check as one
    and was stored as the other's.  One reader now refuses several headers, before any body."""
    import httpx

    other = [("Authorization", f"Bearer {KEY}"), ("Authorization", "Bearer ff-someone-else")]
    transport = api._transport
    with httpx.Client(transport=transport, base_url=str(api.base_url)) as raw:
        listing = raw.get("/v1/scenes", headers=other)
        upload = raw.post("/v1/scenes", headers=other, files={"file": ("x.glb", b"glTF")})
    for response in (listing, upload):
        assert response.status_code == 401, response.text
        assert response.json()["detail"] == "send one Authorization header, not several"


def test_unknown_and_revoked_keys_get_one_message(api):
    """Issue 59, item 11: telling an unknown key from a revoked one tells a guesser which exist."""
    from farfield.service.keys import create_key, revoke_key

    db = api.app.state.services.db
    key, prefix = create_key(db, "guessed")
    revoke_key(db, prefix)
    revoked = api.get("/v1/scenes", headers={"Authorization": f"Bearer {key}"})
    unknown = api.get("/v1/scenes", headers={"Authorization": "Bearer ff_not_a_key_at_all"})
    assert revoked.status_code == unknown.status_code == 401
    assert revoked.json()["detail"] == unknown.json()["detail"] == "invalid API key"


@pytest.fixture(params=["sqlite", "postgresql"])
def api_on_each_database(request, tmp_path):
    """An API (no workers) on SQLite and on a fresh PostgreSQL database where one is reachable."""
    import os

    from service_harness import fresh_postgres_database

    env = {"FARFIELD_HOME": str(tmp_path), "REDIS_URL": "redis://127.0.0.1:1/0", "FARFIELD_ADMIN_KEY": KEY}
    drop = None
    if request.param == "postgresql":
        admin_url = os.environ.get("FARFIELD_TEST_DATABASE_URL")
        if not admin_url:
            pytest.skip(
                "no PostgreSQL server: set FARFIELD_TEST_DATABASE_URL (CI starts one with scripts/postgres-server)"
            )
        env["DATABASE_URL"], drop = fresh_postgres_database(admin_url)
    try:
        with TestClient(create_app(Settings.from_env(env)), headers={"Authorization": f"Bearer {KEY}"}) as client:
            yield client
    finally:
        if drop is not None:
            drop()


NUL_ROUTES = [
    ("GET", "/v1/scenes/a%00b"), ("GET", "/v1/scenes/a%00b/objects"), ("DELETE", "/v1/scenes/a%00b"),
    ("GET", "/v1/jobs/a%00b"), ("GET", "/v1/jobs/a%00b/cells"), ("POST", "/v1/jobs/a%00b/cancel"),
    ("GET", "/v1/jobs/a%00b/index.json"),
]  # fmt: skip


def test_an_id_with_a_nul_byte_is_not_found_on_every_database(api_on_each_database):
    """Issue 59, item 2: PostgreSQL cannot hold a NUL in text; nine routes answered 500
    (psycopg.DataError) where SQLite answered 404.  Such an id names no row on any backend."""
    api = api_on_each_database
    for method, path in NUL_ROUTES:
        response = api.request(method, path)
        assert response.status_code == 404 and response.json()["error"] == "NotFoundError", (
            method,
            path,
            response.text,
        )
    listed = api.get("/v1/jobs", params={"scene_id": "a\x00b"})
    assert listed.status_code == 200 and listed.json() == [], listed.text
    body = {"scene_id": "a\x00b", "resolution": 64, "viewcells": [{"kind": "box", "lo": [0, 0, 0], "hi": [1, 1, 1]}]}
    created = api.post("/v1/jobs", json=body)
    assert created.status_code == 404 and created.json()["error"] == "NotFoundError", created.text


def test_every_response_carries_the_security_headers(api):
    """Issue 59, item 11: the dashboard keeps a key in localStorage; no framing, no sniffing, no
    script from elsewhere; the viewer's import map is allowed by its hash."""
    from farfield.api.security_headers import inline_script_hashes

    for path in ("/dashboard/", "/dashboard/viewer.html", "/v1/health", "/v1/scenes/nope"):
        response = api.get(path)
        assert response.headers["x-frame-options"] == "DENY", path
        assert response.headers["x-content-type-options"] == "nosniff", path
        assert response.headers["referrer-policy"] == "no-referrer", path
        policy = response.headers["content-security-policy"]
        assert "script-src 'self'" in policy and "frame-ancestors 'none'" in policy and "unsafe" not in policy
    viewer = api.get("/dashboard/viewer.html").text
    assert all(h in policy for h in inline_script_hashes(viewer)) and inline_script_hashes(viewer)


def test_deleting_a_scene_deletes_its_jobs_blobs(api, tmp_path):
    """Issue 59, item 10: deleting a scene deleted its jobs' rows but left each job's
    ``jobs/<id>/index.json`` in the blob store, read by nothing ever again."""
    import uuid

    from farfield.service.db import JobRow, SceneRow, now

    path = write_scene(city(buildings=2), tmp_path, "glb", "doomed")
    scene_id = api.post("/v1/scenes", files={"file": (path.name, path.read_bytes())}).json()["id"]
    services = api.app.state.services
    job_id = uuid.uuid4().hex
    with services.db.session() as s:  # a finished job of the scene, as a worker leaves it
        tenant_id = s.get(SceneRow, scene_id).tenant_id
        s.add(JobRow(id=job_id, tenant_id=tenant_id, scene_id=scene_id, job_type="grid", params={}, state="done",
                     created_at=now(), finished_at=now()))  # fmt: skip
    services.blobs.put_bytes(f"jobs/{job_id}/index.json", b"[]")
    assert api.delete(f"/v1/scenes/{scene_id}").status_code in (200, 204)
    assert not services.blobs.exists(f"jobs/{job_id}/index.json")


@pytest.mark.parametrize("size", [3, 100 * 1024])
def test_a_scene_sent_as_text_not_as_a_file_is_told_so(api, size):
    """``curl -F 'file=<scene.glb'`` (or a part without a filename) sends the scene as a text field:
    the answer was pydantic's "Expected UploadFile, received: <class 'str'>" (small) or the
    parser's "Part exceeded maximum size of 64KB." (over 64 KiB), neither saying what to do."""
    before = api.get("/v1/scenes").headers["X-Total-Count"]
    response = api.post(
        "/v1/scenes",
        content=b'--b\r\nContent-Disposition: form-data; name="file"\r\n\r\n' + b"x" * size + b"\r\n--b--\r\n",
        headers={"Content-Type": "multipart/form-data; boundary=b"},
    )
    assert response.status_code in (400, 422), response.text
    detail = response.json()["detail"]
    assert "without a filename" in detail and "file=@" in detail, detail
    assert api.get("/v1/scenes").headers["X-Total-Count"] == before  # nothing stored


def test_an_empty_job_request_is_told_to_send_json(api):
    """An empty body was answered "Field required, got null", naming no field."""
    response = api.post("/v1/jobs", content=b"", headers={"Content-Type": "application/json"})
    assert response.status_code == 422 and "no body" in response.json()["detail"], response.text
    assert "JSON object" in api.post("/v1/jobs").json()["detail"]


@pytest.mark.parametrize("values", [["both", "one"], ["one", "one"]])
def test_a_single_valued_form_field_sent_twice_is_a_422_naming_it(api, tmp_path, values):
    """Two ``sides`` fields in one upload: FastAPI took the last silently (even a mistyped first).
    Each single-valued field of a route is checked alike (api/forms.py); ``file`` takes any number."""
    from farfield.api.forms import single_valued_fields
    from farfield.api.routes_scenes import router

    before = api.get("/v1/scenes").headers["X-Total-Count"]
    path = write_scene(city(buildings=1), tmp_path, "glb")
    response = api.post("/v1/scenes", files={"file": (path.name, path.read_bytes())}, data={"sides": values})
    assert response.status_code == 422 and response.json()["error"] == "ValidationError", response.text
    assert response.json()["detail"].startswith("sides: sent 2 times"), response.text
    assert api.get("/v1/scenes").headers["X-Total-Count"] == before  # nothing stored
    once = api.post("/v1/scenes", files={"file": (path.name, path.read_bytes())}, data={"sides": "both"})
    assert once.status_code == 201 and once.json()["sides"] == "both", once.text
    upload = next(r for r in router.routes if r.path == "/v1/scenes" and "POST" in r.methods)
    assert single_valued_fields(upload) == ["sides"]  # the upload's other field, file, is a list


@pytest.mark.parametrize("cut", [False, True])
def test_a_json_route_sent_a_form_content_type_is_not_read_as_a_form(api, cut):
    """``/v1/jobs`` takes a JSON body (``spec``): the one-value-per-field check read such a body as a
    form, before the route's key check, so a request without a key was answered 422 "spec: sent 2
    times" (or 400 "cut short") instead of 401, and the JSON route's body was parsed as multipart."""
    boundary = "farfieldboundary"
    part = f'--{boundary}\r\nContent-Disposition: form-data; name="spec"\r\n\r\n{{}}\r\n'
    body = (part * 2 + ("" if cut else f"--{boundary}--\r\n")).encode()
    headers = {"Content-Type": f"multipart/form-data; boundary={boundary}"}
    anonymous = api.post("/v1/jobs", content=body, headers={**headers, "Authorization": ""})
    assert anonymous.status_code == 401, anonymous.text
    keyed = api.post("/v1/jobs", content=body, headers=headers)
    assert keyed.status_code == 422 and "sent 2 times" not in keyed.text and "boundary" not in keyed.text, keyed.text
    urlencoded = {"Content-Type": "application/x-www-form-urlencoded", "Authorization": ""}
    assert api.post("/v1/jobs", content=b"spec=1&spec=2", headers=urlencoded).status_code == 401


@pytest.mark.parametrize("kind", ["multipart/form-data; boundary=b", "multipart/form-data"])
def test_an_empty_multipart_body_is_a_form_without_its_file_field(api, kind):
    """A multipart upload with no body at all read "the multipart body ends before its closing
    boundary (--b--): it was cut short" (or "Missing boundary in multipart."): an empty body is an
    empty form, whose missing field is named (a 422, as for a form without it)."""
    before = api.get("/v1/scenes").headers["X-Total-Count"]
    response = api.post("/v1/scenes", content=b"", headers={"Content-Type": kind})
    assert response.status_code == 422, response.text
    detail = response.json()["detail"]
    assert detail.startswith("file: missing from the form") and "cut short" not in detail, detail
    assert api.get("/v1/scenes").headers["X-Total-Count"] == before
    cut = api.post("/v1/scenes", content=b"\r\n", headers={"Content-Type": "multipart/form-data; boundary=b"})
    assert cut.status_code == 400 and "cut short" in cut.json()["detail"], cut.text  # a byte: not empty
    sides_only = api.post("/v1/scenes", data={"sides": "both"}, files={"x": ("x.txt", b"x")})  # a body, no 'file'
    detail = sides_only.json()["detail"]
    assert sides_only.status_code == 422 and detail.startswith("file: missing") and "empty" not in detail, detail
