"""The API answers as its OpenAPI document says (issue 24): a bounded schemathesis run over the app's
own document, in-process (ASGI) against ``create_app`` with a real SQLite database, a real blob
folder, a scene uploaded through the route and an embedded redis-server as the broker (jobs are
accepted and their cells queued; no worker takes them)."""

from __future__ import annotations

from unittest.mock import ANY

import pytest
import schemathesis
from fastapi.testclient import TestClient
from scenes import city, write_scene
from schemathesis.config import SchemathesisConfig
from schemathesis.specs.openapi.checks import ignored_auth

from farfield.api.app import create_app
from farfield.service.embedded_redis import EmbeddedRedis
from farfield.service.placement import ALGORITHMS, DEFAULT_ALGORITHM
from farfield.service.settings import Settings

KEY = "ff-test-openapi-key-0123456789"
AUTH = {"Authorization": f"Bearer {KEY}"}


@pytest.fixture(scope="module")
def service(tmp_path_factory):
    """(app, client, scene id): the app on an embedded Redis, with one uploaded scene."""
    home = tmp_path_factory.mktemp("openapi")
    redis = EmbeddedRedis(home / "redis").start()
    settings = Settings.from_env({"FARFIELD_HOME": str(home), "REDIS_URL": redis.url, "FARFIELD_ADMIN_KEY": KEY})
    app = create_app(settings)
    try:
        with TestClient(app, headers=AUTH) as client:
            path = write_scene(city(buildings=3), home, "glb")
            response = client.post("/v1/scenes", files={"file": (path.name, path.read_bytes())})
            assert response.status_code == 201, response.text
            yield app, client, response.json()["id"]
    finally:
        redis.stop()


CONFIG = {
    "seed": 24,
    "headers": AUTH,
    "generation": {"max-examples": 25, "deterministic": True, "database": "none"},
    "phases": {
        "examples": {"enabled": True},
        "coverage": {"enabled": True},
        "fuzzing": {"enabled": True},
        "stateful": {"enabled": True},
    },
    "operations": [
        # Whether an upload is a scene, or a job's view cells fit the scene's part, is more than a
        # schema can say: schema-valid bytes or cells are a 422 there.
        {"include-name": "POST /v1/scenes", "checks": {"positive_data_acceptance": {"enabled": False}}},
    ],
}


def schemathesis_run(app, config: dict) -> tuple[list[str], int, float]:
    """Run schemathesis's engine (what ``st run`` runs) over the app's own document: (one line per
    distinct failure, requests sent, seconds)."""
    from schemathesis import engine
    from schemathesis.engine import events

    schema = schemathesis.openapi.from_asgi("/openapi.json", app, config=SchemathesisConfig.from_dict(config))
    failures, requests, seconds, names = set(), 0, 0.0, set()
    for event in engine.from_schema(schema).execute():
        if isinstance(event, events.ScenarioFinished):
            requests += len(event.recorder.interactions)
            for case_id, checks in event.recorder.checks.items():
                for check in checks:
                    names.add(check.name)
                    if check.failure_info is not None:
                        failure = check.failure_info.failure
                        response = event.recorder.find_response(case_id=case_id)
                        answer = (
                            f"{response.status_code} {response.text[:200]}" if response is not None else "no response"
                        )
                        failures.add(
                            f"{check.name} | {failure.operation} | {failure.title} | {failure.message.splitlines()[0] if failure.message else ''} | {answer}"
                        )
        elif isinstance(event, (events.NonFatalError, events.FatalError)):
            failures.add(
                f"error | {getattr(event, 'label', '')} | {getattr(event, 'value', getattr(event, 'exception', ''))!r}"
            )
        elif isinstance(event, events.EngineFinished):
            seconds = event.running_time
    print("checks run:", sorted(names))
    return sorted(failures), requests, seconds


@pytest.mark.slow
def test_the_api_conforms_to_its_openapi_document(service):
    """Every check of schemathesis passes over every operation of the document: examples, the
    coverage phase (boundary values, missing and wrong-typed fields, undeclared methods, broken
    Content-Types), fuzzing with 25 examples an operation (derandomised) and the stateful phase.
    On the code before this test it found 48 distinct failures (24 undeclared 404s, 17 error bodies
    that are not the declared 422 array, Allow headers that omit a path's other methods, a job
    state filter and a view-space rule the document did not state, ...)."""
    app, _client, _scene = service
    failures, requests, seconds = schemathesis_run(app, CONFIG)
    print(f"schemathesis: {requests} requests in {seconds:.1f} s, {len(failures)} distinct failures")
    assert requests > 500  # it ran: every operation, many cases each
    assert not failures, "\n".join(failures)


@pytest.fixture(scope="module")
def document(service):
    _app, client, _scene = service
    return client.get("/openapi.json").json()


def checked(service, method: str, template: str, path: str | None = None, **request):
    """Send a request with the module's client and check its response against the operation
    ``method template`` of the document (status, content type, body schema, headers)."""
    app, client, _scene = service
    response = client.request(method, path or template, **request)
    if not hasattr(app.state, "schemathesis_schema"):
        app.state.schemathesis_schema = schemathesis.openapi.from_asgi(
            "/openapi.json", app, config=SchemathesisConfig.from_dict(CONFIG)
        )
    # ignored_auth resends the case without its key: this case has none (the client adds it); the
    # schemathesis run checks it
    app.state.schemathesis_schema[template][method].Case().validate_response(response, excluded_checks=[ignored_auth])
    return response


@pytest.mark.slow
def test_a_job_s_life_answers_as_documented(service, tmp_path):
    """The requests schemathesis rarely makes (its ids are made up): a real upload, job, cell,
    lookup, the 409s of a job still admitting (no worker runs here), cancel and delete, each response
    checked against the document."""
    _app, _client, scene_id = service
    assert checked(service, "GET", "/v1/techniques").status_code == 200
    listed = checked(service, "GET", "/v1/placement-algorithms").json()
    assert [a["name"] for a in listed["algorithms"]] == list(ALGORITHMS) and listed["default"] == DEFAULT_ALGORITHM
    assert checked(service, "GET", "/v1/health").json()["broker"] is True
    assert checked(service, "GET", "/metrics").headers["content-type"].startswith("text/plain")
    path = write_scene(city(buildings=2), tmp_path, "glb")
    other = checked(service, "POST", "/v1/scenes", files={"file": ("other.glb", path.read_bytes())})
    assert other.status_code == 201
    assert checked(service, "GET", "/v1/scenes/{scene_id}", f"/v1/scenes/{scene_id}").status_code == 200
    spec = {
        "scene_id": scene_id,
        "objects": ["building_000"],
        "resolution": 64,
        "viewcells": [{"kind": "box", "lo": [60, 2, 60], "hi": [64, 6, 64]}],
    }
    job = checked(service, "POST", "/v1/jobs", json=spec)
    assert job.status_code == 201, job.text
    job_id = job.json()["id"]
    assert checked(service, "GET", "/v1/jobs", params={"state": "admitting"}).status_code == 200
    assert checked(service, "GET", "/v1/jobs/{job_id}", f"/v1/jobs/{job_id}").json()["state"] == "admitting"
    assert checked(service, "GET", "/v1/jobs/{job_id}/cells/{index}", f"/v1/jobs/{job_id}/cells/0").status_code == 200
    assert checked(service, "GET", "/v1/jobs/{job_id}/cells/{index}", f"/v1/jobs/{job_id}/cells/1").status_code == 404
    assert (
        checked(
            service, "GET", "/v1/jobs/{job_id}/cells/{index}/bundle.zip", f"/v1/jobs/{job_id}/cells/0/bundle.zip"
        ).status_code
        == 404
    )
    assert (
        checked(
            service, "GET", "/v1/jobs/{job_id}/lookup", f"/v1/jobs/{job_id}/lookup", params={"x": 62, "y": 4, "z": 62}
        ).json()[0]["index"]
        == 0
    )
    assert (
        checked(service, "GET", "/v1/jobs/{job_id}/database.zip", f"/v1/jobs/{job_id}/database.zip").status_code == 409
    )
    assert checked(service, "POST", "/v1/jobs/{job_id}/retry", f"/v1/jobs/{job_id}/retry").status_code == 409
    assert (
        checked(service, "DELETE", "/v1/scenes/{scene_id}", f"/v1/scenes/{scene_id}").status_code == 409
    )  # the queued job uses it
    assert (
        checked(service, "POST", "/v1/jobs/{job_id}/cancel", f"/v1/jobs/{job_id}/cancel").json()["state"] == "cancelled"
    )
    assert checked(service, "POST", "/v1/jobs/{job_id}/cancel", f"/v1/jobs/{job_id}/cancel").status_code == 409
    other_id = other.json()["id"]
    assert checked(service, "DELETE", "/v1/scenes/{scene_id}", f"/v1/scenes/{other_id}").status_code == 204
    assert checked(service, "GET", "/v1/scenes/{scene_id}", f"/v1/scenes/{other_id}").status_code == 404


def test_every_error_response_is_the_one_error_body(document):
    """FastAPI's 422 schema (an array of problems) is gone; every 4xx of every operation is ErrorBody."""
    assert "HTTPValidationError" not in document["components"]["schemas"]
    assert set(document["components"]["schemas"]["ErrorBody"]["required"]) == {"detail", "error"}
    for path, item in document["paths"].items():
        for method, operation in item.items():
            for status, response in operation["responses"].items():
                if status.startswith("4"):
                    assert response["content"]["application/json"]["schema"] == {
                        "$ref": "#/components/schemas/ErrorBody"
                    }, (method, path, status)


def test_the_document_lists_each_operation_s_errors(document):
    paths = document["paths"]
    for path, item in paths.items():
        for method, operation in item.items():
            keyed = (path.startswith("/v1/") and path != "/v1/health") or path == "/metrics"
            assert ("401" in operation["responses"]) == keyed == bool(operation.get("security")), (method, path)
            assert ("429" in operation["responses"]) == keyed, (method, path)  # failed authentication
            assert ("404" in operation["responses"]) >= ("{" in path), (method, path)
    assert {"400", "401", "404", "413", "422", "429"} <= set(paths["/v1/jobs"]["post"]["responses"])
    assert {"400", "401", "413", "422"} <= set(paths["/v1/scenes"]["post"]["responses"])
    assert "409" in paths["/v1/scenes/{scene_id}"]["delete"]["responses"]
    assert document["components"]["securitySchemes"]["BearerKey"] == {
        "type": "http",
        "scheme": "bearer",
        "description": ANY,
    }
    assert list(paths["/v1/jobs/{job_id}/cells/{index}/atlas/{page}.png"]["get"]["responses"]["200"]["content"]) == [
        "image/png"
    ]
    assert paths["/v1/jobs"]["get"]["parameters"][0]["schema"]["enum"] == [
        "admitting",
        "queued",
        "placing",
        "running",
        "done",
        "failed",
        "cancelled",
    ]


def test_every_extra_status_names_an_operation(document):
    """The table of statuses a route's shape does not tell must not outlive a renamed route."""
    from farfield.api.openapi import EXTRA_STATUSES, QUERY_VALUES, REQUIRED_FORM_FIELDS

    for method, path, *_ in (*EXTRA_STATUSES, *QUERY_VALUES, *REQUIRED_FORM_FIELDS):
        assert method in document["paths"].get(path, {}), (method, path)


@pytest.mark.parametrize(
    "method, path, allow",
    [
        ("PUT", "/v1/scenes/abc", "DELETE, GET"),  # Starlette said "GET" (the route it tried)
        ("PATCH", "/v1/scenes", "GET, POST"),
        ("OPTIONS", "/v1/scenes/abc", "DELETE, GET"),
        ("HEAD", "/v1/jobs/abc", "GET"),
        ("DELETE", "/v1/jobs/abc/cells/0/atlas/1.png", "GET"),
        ("POST", "/v1/health", "GET"),
    ],
)
def test_an_undeclared_method_is_a_405_listing_the_path_s_methods(service, method, path, allow):
    _app, client, _scene = service
    response = client.request(method, path)
    assert response.status_code == 405 and response.headers["allow"] == allow
    if method != "HEAD":
        assert response.json()["error"] == "MethodNotAllowedError" and allow in response.json()["detail"]


@pytest.mark.parametrize(
    "request_, status, error",
    [
        ({"method": "GET", "url": "/v1/nothing"}, 404, "NotFoundError"),
        (
            {"method": "GET", "url": "/v1/scenes", "headers": {"Authorization": "Bearer wrong-key-0123456789"}},
            401,
            "AuthError",
        ),
        ({"method": "GET", "url": "/v1/scenes", "headers": {"Authorization": "Basic abc"}}, 401, "AuthError"),
        (
            {
                "method": "POST",
                "url": "/v1/jobs",
                "content": b"\xff\xfe{",
                "headers": {"Content-Type": "application/json"},
            },
            400,
            "BadRequestError",
        ),
        (
            {"method": "POST", "url": "/v1/jobs", "content": b"{", "headers": {"Content-Type": "application/json"}},
            422,
            "ValidationError",
        ),
        (
            {
                "method": "POST",
                "url": "/v1/jobs",
                "content": b"{}",
                "headers": {"Content-Type": "application/json", "Content-Length": str(2**30)},
            },
            413,
            "UploadTooLargeError",
        ),
        (
            {
                "method": "POST",
                "url": "/v1/scenes",
                "content": b"--x\r\nbroken",
                "headers": {"Content-Type": "multipart/form-data"},
            },
            400,
            "BadRequestError",
        ),
        ({"method": "POST", "url": "/v1/scenes", "files": {"other": ("a.txt", b"x")}}, 422, "SceneLoadError"),
    ],
)
def test_every_error_has_the_error_body(service, request_, status, error):
    """Starlette's own errors (unknown path, broken body) and the body limit answer like ours."""
    _app, client, _scene = service
    response = client.request(**request_)
    assert response.status_code == status, response.text
    assert response.headers["content-type"] == "application/json"
    assert set(response.json()) == {"detail", "error"} and response.json()["error"] == error
    if status == 401:
        assert response.headers["www-authenticate"] == "Bearer"


@pytest.mark.parametrize(
    "change, field",
    [
        ({"resolution": True}, "resolution"),
        ({"fov_deg": True}, "fov_deg"),
        ({"grid": {"lo": [0, 0, 0], "hi": [1, 1, 1], "counts": ["1", 1, 1]}}, "counts"),
        ({"grid": {"lo": [0, 0, 0], "hi": [1, 1, 1], "counts": [True, 1, 1]}}, "counts"),
    ],
)
def test_no_loose_coercion(service, change, field):
    """Issue 24, defect 8: the document says integer and number; a string or a boolean is not one."""
    _app, client, scene_id = service
    body = {
        "scene_id": scene_id,
        "resolution": 64,
        "viewcells": [{"kind": "box", "lo": [40, 1, 40], "hi": [44, 5, 44]}],
        **change,
    }
    if "grid" in change:
        del body["viewcells"]
    response = client.post("/v1/jobs", json=body)
    assert response.status_code == 422 and field in response.json()["detail"], response.text
