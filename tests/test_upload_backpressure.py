"""Uploads are parsed by a bounded pool (issue 59, item 3): a burst of uploads past
``FARFIELD_SCENE_CHECKS`` + ``FARFIELD_SCENE_CHECK_QUEUE`` gets 429 with ``Retry-After`` at once,
stores nothing for the refused ones, and leaves ``/v1/health`` answering.  The real API behind a
real uvicorn server, a real SQLite database and blob folder, each check a real child process."""

from __future__ import annotations

import socket
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import httpx
import pytest
import uvicorn
from scenes import city, write_scene

from farfield.api.app import create_app
from farfield.service.settings import Settings

KEY = "ff-test-backpressure-key-0123456789"
HEADERS = {"Authorization": f"Bearer {KEY}"}


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    home = tmp_path_factory.mktemp("backpressure")
    settings = Settings.from_env(
        {
            "FARFIELD_HOME": str(home),
            "REDIS_URL": "redis://127.0.0.1:1/0",
            "FARFIELD_ADMIN_KEY": KEY,
            "FARFIELD_SCENE_CHECKS": "1",
            "FARFIELD_SCENE_CHECK_QUEUE": "1",
        }
    )
    app = create_app(settings)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, lifespan="off", log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    while not server.started:
        time.sleep(0.05)
    scene = write_scene(city(buildings=20), home, "glb")
    yield f"http://127.0.0.1:{port}", scene.read_bytes(), app
    server.should_exit = True
    thread.join(10)


def upload(url: str, data: bytes) -> httpx.Response:
    return httpx.post(f"{url}/v1/scenes", headers=HEADERS, files={"file": ("city.glb", data)}, timeout=120)


@pytest.mark.slow
def test_a_burst_of_uploads_past_the_pool_is_refused_with_429_and_stores_nothing(served):
    url, data, app = served
    burst = 10
    healthy = []
    with ThreadPoolExecutor(burst + 1) as pool:
        answers = [pool.submit(upload, url, data) for _ in range(burst)]
        while not all(a.done() for a in answers):  # the routes every tenant needs keep answering
            healthy.append(httpx.get(f"{url}/v1/health", timeout=60).status_code)
            time.sleep(0.05)
        answers = [a.result() for a in answers]
    codes = sorted(a.status_code for a in answers)
    assert set(codes) == {201, 429}, codes
    # One parses, one waits: at least two pass; the others are refused while those two are admitted.
    assert codes.count(201) >= 2 and codes.count(429) >= 1, codes
    for refused in (a for a in answers if a.status_code == 429):
        body = refused.json()
        assert body["error"] == "BusyError" and "FARFIELD_SCENE_CHECKS=1" in body["detail"], body
        assert refused.headers["Retry-After"] == "5"
    assert healthy and set(healthy) == {200}
    # Nothing half-stored: exactly the accepted uploads are scenes, and their blobs alone exist.
    listed = httpx.get(f"{url}/v1/scenes", headers=HEADERS, params={"limit": 100}).json()
    assert len(listed) == codes.count(201)
    blob_scenes = {p.name for p in (app.state.services.settings.blob_dir / "scenes").iterdir()}
    assert blob_scenes == {s["id"] for s in listed}
    assert app.state.services.scene_checks.admitted_count == 0
    # The burst over, the same upload passes.
    assert upload(url, data).status_code == 201


def test_a_refused_upload_is_answered_before_its_body_is_read(served):
    """The refusal comes from the body middleware before a byte of the body is read: a client that
    sent only the headers and 1 KiB of a 64 MiB upload gets its 429 at once (the route's own check
    answered only once the whole body had arrived and been spooled)."""
    import socket

    url, _data, app = served
    gate = app.state.services.scene_checks
    host, port = url.removeprefix("http://").split(":")
    held = [gate.admitted() for _ in range(gate.running + gate.waiting)]
    for place in held:  # every place taken, as by uploads being checked
        place.__enter__()
    try:
        with socket.create_connection((host, int(port)), timeout=20) as s:
            s.sendall(
                b"POST /v1/scenes HTTP/1.1\r\nHost: farfield\r\nAuthorization: Bearer " + KEY.encode()
                + b"\r\nContent-Type: multipart/form-data; boundary=b\r\nContent-Length: 67108864\r\n\r\n" + b"x" * 1024
            )  # fmt: skip
            answer = b""
            while b"BusyError" not in answer:  # the head, then the JSON body
                chunk = s.recv(65536)
                if not chunk:
                    break
                answer += chunk
        assert answer.startswith(b"HTTP/1.1 429 "), answer
        assert b"BusyError" in answer and b"retry-after: 5" in answer.lower()
    finally:
        for place in held:
            place.__exit__(None, None, None)
