"""``GET /v1/health`` on a real embedded Redis: the broker's check keeps its connection (issue 58,
item 5: it opened a new one per request), still says "degraded" when the broker is gone, and "ok"
again once it is back on the same address.  The API app in-process with a real SQLite database."""

from __future__ import annotations

import redis
from fastapi.testclient import TestClient

from farfield.api.app import create_app
from farfield.service.embedded_redis import EmbeddedRedis
from farfield.service.settings import Settings


def connections_received(inspector: redis.Redis) -> int:
    return int(inspector.info("stats")["total_connections_received"])


def test_health_keeps_its_broker_connection_and_tells_a_dead_broker(tmp_path):
    broker = EmbeddedRedis(tmp_path / "redis").start()
    try:
        settings = Settings.from_env({"FARFIELD_HOME": str(tmp_path / "home"), "REDIS_URL": broker.url})
        client = TestClient(create_app(settings))  # no lifespan: no sweeper sends to the broker
        inspector = redis.Redis.from_url(broker.url)
        before = connections_received(inspector)  # the inspector's own connection counted
        for _ in range(20):
            assert client.get("/v1/health").json() == {"status": "ok", "database": True, "broker": True}
        assert connections_received(inspector) - before <= 1  # one kept connection, not 20
        inspector.close()

        broker.stop()
        assert client.get("/v1/health").json() == {"status": "degraded", "database": True, "broker": False}

        broker.start()  # the same port: the pooled connection is stale, a new one is opened
        assert client.get("/v1/health").json() == {"status": "ok", "database": True, "broker": True}
    finally:
        broker.stop()
