"""The broker's reachability as ``GET /v1/health`` reports it: one pooled Redis client, a ``PING`` per ask.

Asking Celery for a connection on every health request (``connection_for_write`` and
``ensure_connection``) built a new kombu connection and channel each time, and under a large job
that was most of the request's time (``benchmarks/bench_orchestration.py``).  This client keeps its
connections (redis-py's pool is thread-safe: health runs in the API's thread pool) and answers a
``PING`` on one.  A connection the broker dropped (Redis restarted) is opened again once at once,
with no back-off; a broker that refuses answers "unreachable" at once, one that does not answer
within ``timeout_s``.
"""

from __future__ import annotations

import redis
from redis.backoff import NoBackoff
from redis.retry import Retry


class BrokerProbe:
    """PINGs the Redis broker at ``url`` on pooled connections."""

    def __init__(self, url: str, timeout_s: float = 1.0) -> None:
        # One retry, on a connection error only (a stale pooled connection); none on a timeout.
        retry = Retry(NoBackoff(), 1, supported_errors=(redis.exceptions.ConnectionError,))
        self.client = redis.Redis.from_url(url, socket_connect_timeout=timeout_s, socket_timeout=timeout_s, retry=retry)

    def reachable(self) -> bool:
        """True when the broker answers ``PING``."""
        try:
            return bool(self.client.ping())
        except Exception:  # noqa: BLE001 - any failure means "not reachable"
            return False

    def close(self) -> None:
        self.client.close()
