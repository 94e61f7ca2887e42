"""Failed authentication is rate-limited per client (issue 59, item 11): past
``FARFIELD_AUTH_FAILURES`` keys that do not authenticate, a client's further failures get 429 with
``Retry-After`` instead of 401, on every route and on the upload's early check, while a valid key
always passes (a stranger on a shared address cannot lock its users out) and other clients go
on.  The real app with a real SQLite database; clients told apart by address."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from farfield.api.app import create_app
from farfield.service.settings import Settings

KEY = "ff-test-authrate-key-0123456789"
LIMIT = 5


@pytest.fixture
def app(tmp_path):
    env = {
        "FARFIELD_HOME": str(tmp_path),
        "REDIS_URL": "redis://127.0.0.1:1/0",
        "FARFIELD_ADMIN_KEY": KEY,
        "FARFIELD_AUTH_FAILURES": str(LIMIT),
    }
    return create_app(Settings.from_env(env))


def client(app, address: str) -> TestClient:
    return TestClient(app, client=(address, 40000))


def test_a_client_guessing_keys_is_slowed_with_429_and_a_valid_key_still_passes(app):
    with client(app, "203.0.113.7") as guesser, client(app, "198.51.100.2") as other:
        codes = [
            guesser.get("/v1/scenes", headers={"Authorization": f"Bearer ff-guess-{k}"}).status_code
            for k in range(LIMIT)
        ]
        assert codes == [401] * LIMIT
        refused = guesser.get("/v1/scenes", headers={"Authorization": "Bearer ff-guess-next"})
        assert refused.status_code == 429 and refused.json()["error"] == "AuthRateError"
        assert "FARFIELD_AUTH_FAILURES" in refused.json()["detail"]
        assert 1 <= int(refused.headers["Retry-After"]) <= 60
        # A valid key from the same address passes: sharing an address with a guesser locks no one out.
        assert guesser.get("/v1/scenes", headers={"Authorization": f"Bearer {KEY}"}).status_code == 200
        upload = guesser.post(
            "/v1/scenes", headers={"Authorization": "Bearer ff-guess-x"}, files={"file": ("a.stl", b"solid")}
        )
        assert upload.status_code == 429 and upload.headers["Retry-After"]
        # Another client is not affected, and unauthenticated health stays open to the guesser.
        assert other.get("/v1/scenes", headers={"Authorization": f"Bearer {KEY}"}).status_code == 200
        assert guesser.get("/v1/health").status_code == 200


def test_requests_without_credentials_are_not_counted(app):
    with client(app, "192.0.2.9") as anonymous:
        assert {anonymous.get("/v1/scenes").status_code for _ in range(3 * LIMIT)} == {401}
        assert anonymous.get("/v1/scenes", headers={"Authorization": f"Bearer {KEY}"}).status_code == 200


def test_an_ipv6_client_is_counted_by_its_64(app):
    """One host usually holds a whole /64: rotating addresses inside it does not reset the count."""
    codes = []
    for k in range(LIMIT + 1):
        with client(app, f"2001:db8:0:1::{k + 1:x}") as rotating:
            codes.append(rotating.get("/v1/scenes", headers={"Authorization": "Bearer ff-guess"}).status_code)
    assert codes == [401] * LIMIT + [429]
