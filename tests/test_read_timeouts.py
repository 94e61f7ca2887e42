"""Slow clients are cut off (issue 59, item 11): a connection whose headers never finish, or whose
body stops arriving, gets a JSON 408 and is closed after its deadline, where uvicorn's own protocol
held it open indefinitely.  The real API app behind a real uvicorn server using
:class:`farfield.api.read_timeouts.TimedH11Protocol`, spoken to over raw sockets."""

from __future__ import annotations

import json
import re
import socket
import threading
import time

import pytest
import uvicorn
from scenes import city, write_scene  # tests/ is on sys.path under pytest's default (prepend) import mode

from farfield.api.app import create_app
from farfield.api.read_timeouts import TimedH11Protocol
from farfield.service.settings import Settings

HEADER_S, BODY_S = 1.0, 1.5
KEY = "ff-test-timeouts-key-0123456789"


@pytest.fixture(scope="module")
def port(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    mp.setenv("FARFIELD_HEADER_TIMEOUT_S", str(HEADER_S))
    mp.setenv("FARFIELD_BODY_IDLE_TIMEOUT_S", str(BODY_S))
    home = tmp_path_factory.mktemp("timeouts")
    app = create_app(
        Settings.from_env({"FARFIELD_HOME": str(home), "REDIS_URL": "redis://127.0.0.1:1/0", "FARFIELD_ADMIN_KEY": KEY})
    )
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        free = s.getsockname()[1]
    config = uvicorn.Config(app, host="127.0.0.1", port=free, lifespan="off", log_level="error", http=TimedH11Protocol)
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    while not server.started:
        time.sleep(0.05)
    yield free
    server.should_exit = True
    thread.join(10)
    mp.undo()


def exchange(port: int, data: bytes, wait: float = 20.0, half_close: bool = False) -> tuple[bytes, float]:
    """Send ``data`` (then close the sending side, with ``half_close``) and read until the server
    closes; what came back and the seconds it took."""
    start = time.monotonic()
    with socket.create_connection(("127.0.0.1", port)) as s:
        s.settimeout(wait)
        s.sendall(data)
        if half_close:
            s.shutdown(socket.SHUT_WR)
        got = b""
        while True:
            try:
                chunk = s.recv(65536)
            except TimeoutError:
                break
            if not chunk:
                break
            got += chunk
    return got, time.monotonic() - start


def test_half_sent_headers_get_a_408_after_the_header_deadline(port):
    got, seconds = exchange(port, b"GET /v1/health HTTP/1.1\r\nHost: farfield\r\nX-Slow: ")
    assert got.startswith(b"HTTP/1.1 408 "), got
    body = json.loads(got.split(b"\r\n\r\n", 1)[1])
    assert body["error"] == "RequestTimeoutError" and "FARFIELD_HEADER_TIMEOUT_S" in body["detail"]
    assert HEADER_S * 0.9 <= seconds < 15.0  # closed at the deadline, not held for the read's 20 s


def test_a_connection_that_sends_nothing_is_closed(port):
    got, seconds = exchange(port, b"")
    assert got.startswith(b"HTTP/1.1 408 ") and seconds < 15.0


def test_a_body_that_stops_arriving_is_cut_off(port):
    head = (
        b"POST /v1/scenes HTTP/1.1\r\nHost: farfield\r\nContent-Type: multipart/form-data; boundary=b\r\n"
        b"Authorization: Bearer " + KEY.encode() + b"\r\nContent-Length: 1000\r\n\r\n"
    )
    part = b'--b\r\nContent-Disposition: form-data; name="file"; filename="a.glb"\r\n\r\nglTF'
    got, seconds = exchange(port, head + part)
    assert got.startswith(b"HTTP/1.1 408 ") and b"FARFIELD_BODY_IDLE_TIMEOUT_S" in got, got
    assert BODY_S * 0.9 <= seconds < 15.0  # uvicorn alone waited for the other 990 bytes for ever


def test_a_prompt_client_is_answered_and_kept_alive(port):
    with socket.create_connection(("127.0.0.1", port)) as s:
        s.settimeout(10)
        for _ in range(2):  # two requests on one connection, each well within the deadline
            s.sendall(b"GET /v1/health HTTP/1.1\r\nHost: farfield\r\n\r\n")
            got = b""
            while b"\r\n\r\n" not in got:
                got += s.recv(65536)
            head, body = got.split(b"\r\n\r\n", 1)
            length = int(
                next(h for h in head.split(b"\r\n") if h.lower().startswith(b"content-length:")).split(b":")[1]
            )
            while len(body) < length:
                body += s.recv(65536)
            assert head.startswith(b"HTTP/1.1 200 ") and json.loads(body)["database"] is True, got
            time.sleep(HEADER_S * 1.5)  # idle between requests: uvicorn's keep-alive (5 s) applies, not ours


@pytest.mark.parametrize("path", ["/v1/scenes", "/v1/jobs"])
def test_a_body_short_of_its_length_then_half_closed_is_a_400(port, path):
    """A client that sends fewer bytes than its Content-Length and closes its sending side got no
    reply at all: uvicorn closed the connection at the end of its input.  Now a JSON 400 that says
    the body ended early, at once (not at the body's idle timeout)."""
    kind = "multipart/form-data; boundary=b" if path == "/v1/scenes" else "application/json"
    head = (
        f"POST {path} HTTP/1.1\r\nHost: farfield\r\nContent-Type: {kind}\r\nAuthorization: Bearer {KEY}\r\n"
        "Content-Length: 1000\r\n\r\n"
    ).encode()
    part = b'--b\r\nContent-Disposition: form-data; name="file"; filename="a.glb"\r\n\r\nglTF'
    got, seconds = exchange(port, head + (part if path == "/v1/scenes" else b'{"scene_id": "x"'), 10.0, True)
    assert got.startswith(b"HTTP/1.1 400 "), got
    body = json.loads(got.split(b"\r\n\r\n", 1)[1])
    assert body["error"] == "BadRequestError" and "Content-Length: 1000" in body["detail"], body
    assert "ended before it was complete" in body["detail"] and seconds < BODY_S  # not the idle timeout's 408


def test_half_closed_cut_headers_are_a_400_and_a_whole_request_is_answered(port):
    """Headers cut by the client's half-close got nothing back either; and a complete request whose
    client then half-closes (``nc -N``) lost its response, the connection closed under it."""
    got, seconds = exchange(port, b"GET /v1/health HTTP/1.1\r\nHost: farfield\r\nX-Cut: ", 10.0, True)
    assert got.startswith(b"HTTP/1.1 400 ") and b"headers ended before" in got and seconds < HEADER_S, got
    got, _ = exchange(port, b"GET /v1/health HTTP/1.1\r\nHost: farfield\r\n\r\n", 10.0, True)
    assert got.startswith(b"HTTP/1.1 200 ") and json.loads(got.split(b"\r\n\r\n", 1)[1])["database"] is True, got


def test_after_a_response_cut_or_late_headers_still_get_their_400_or_408(port):
    """On a kept-alive connection the next request's cut headers (the client half-closed) or late
    ones (past the header deadline) were closed without a word: the 400 or 408 was written only
    while the connection had never begun a response, and the first request's had."""
    health = b"GET /v1/health HTTP/1.1\r\nHost: farfield\r\n\r\n"
    for half_close, status, said in [(True, b"400", b"headers ended before"), (False, b"408", b"HEADER_TIMEOUT_S")]:
        with socket.create_connection(("127.0.0.1", port)) as s:
            s.settimeout(10)
            s.sendall(health)
            got = b""
            while b'"database"' not in got:  # the first response, whole
                got += s.recv(65536)
            s.sendall(b"GET /v1/health HTTP/1.1\r\nHost: farfield\r\nX-Cut: ")
            if half_close:
                s.shutdown(socket.SHUT_WR)
            while chunk := s.recv(65536):
                got += chunk
        assert got.startswith(b"HTTP/1.1 200 ") and got.count(b"HTTP/1.1 ") == 2, got
        second = got[got.index(b"HTTP/1.1 ", 1) :]
        assert second.startswith(b"HTTP/1.1 " + status + b" ") and said in second, got


def test_pipelined_requests_then_a_half_close_are_each_answered(port, tmp_path):
    """A client that pipelines requests and then half-closes (``nc -N < requests``) got only the
    response of the one being answered when its end of input arrived: the connection closed after
    it, the next complete request unanswered and a cut one without its 400.  The first here is an
    upload (its scene's checks take a while), so the end of input comes while it is answered."""
    scene = write_scene(city(buildings=1), tmp_path, "glb").read_bytes()
    part = b'--b\r\nContent-Disposition: form-data; name="file"; filename="a.glb"\r\n\r\n' + scene + b"\r\n--b--\r\n"
    upload = (
        f"POST /v1/scenes HTTP/1.1\r\nHost: farfield\r\nContent-Type: multipart/form-data; boundary=b\r\n"
        f"Authorization: Bearer {KEY}\r\nContent-Length: {len(part)}\r\n\r\n"
    ).encode() + part
    health = b"GET /v1/health HTTP/1.1\r\nHost: farfield\r\n\r\n"
    got, _ = exchange(port, upload + health + b"GET /v1/health HTTP/1.1\r\nHo", 30.0, True)
    assert re.findall(rb"HTTP/1\.1 (\d{3}) ", got) == [b"201", b"200", b"400"], got
    assert b"headers ended before" in got, got
