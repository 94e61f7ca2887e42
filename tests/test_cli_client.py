"""The service commands' HTTP client (``cli/client_cmds.py``) against a real HTTP server."""

from __future__ import annotations

import json
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest


class _Service(BaseHTTPRequestHandler):
    def do_GET(self):  # noqa: N802 (http.server's name)
        found = self.path == "/v1/jobs"
        body = json.dumps([] if found else {"detail": f"no such path {self.path!r}", "error": "NotFoundError"})
        self.send_response(200 if found else 404)
        self.send_header("Content-Type", "application/json")
        self.end_headers()
        self.wfile.write(body.encode())

    def log_message(self, *args):
        pass


@pytest.fixture(scope="module")
def service_url():
    server = ThreadingHTTPServer(("127.0.0.1", 0), _Service)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield f"http://127.0.0.1:{server.server_port}"
    server.shutdown()


@pytest.mark.parametrize("suffix", ["", "/", "/v1", "/v1/"])
def test_the_api_url_farfield_up_prints_is_a_service_url(service_url, suffix):
    """``farfield up`` prints ``API http://HOST:PORT/v1``: given as ``--url`` (``FARFIELD_URL``), every
    request went to ``/v1/v1/...`` and came back "no such path '/v1/v1/jobs'" (exit 3)."""
    from farfield.cli.client_cmds import Client

    assert Client(service_url + suffix, None).request("GET", "/v1/jobs").json() == []
