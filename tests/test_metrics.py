"""``/metrics`` needs a key and shows the key's tenant's figures; the admin key shows the service's
(issue 24: counts across tenants were open to anyone).  The API app in-process with a real SQLite
database; scenes uploaded through the route."""

from __future__ import annotations

import re

import pytest
from fastapi.testclient import TestClient
from scenes import city, write_scene

from farfield.api.app import create_app
from farfield.service.db import Database
from farfield.service.keys import create_key
from farfield.service.settings import Settings

KEY = "ff-test-metrics-admin-0123456789"


def scenes_shown(client: TestClient) -> int:
    response = client.get("/metrics")
    assert response.status_code == 200, response.text
    return int(re.search(r"^farfield_scenes (\d+)$", response.text, re.M).group(1))


@pytest.mark.slow
def test_metrics_show_the_key_s_tenant(tmp_path):
    settings = Settings.from_env(
        {"FARFIELD_HOME": str(tmp_path), "REDIS_URL": "redis://127.0.0.1:1/0", "FARFIELD_ADMIN_KEY": KEY}
    )
    app = create_app(settings)
    other_key, _ = create_key(Database(settings.database_url), "tenant-b")
    path = write_scene(city(buildings=2), tmp_path, "glb")
    with TestClient(app) as anonymous:
        response = anonymous.get("/metrics")
        assert response.status_code == 401 and response.json()["error"] == "AuthError"
        admin = TestClient(app, headers={"Authorization": f"Bearer {KEY}"})
        other = TestClient(app, headers={"Authorization": f"Bearer {other_key}"})
        for client in (admin, admin, other):
            assert client.post("/v1/scenes", files={"file": (path.name, path.read_bytes())}).status_code == 201
        assert scenes_shown(other) == 1  # its own, not the admin's two
        assert scenes_shown(admin) == 3  # the service's
        assert anonymous.get("/v1/health").status_code == 200  # health stays open
