"""A real farfield service for tests: ``farfield up`` in a subprocess (embedded redis-server, uvicorn,
real ``celery worker`` processes, SQLite, a blob directory), and a small HTTP client for it.

The service fixtures, the one place they are defined: import ``service_on_each_database`` (SQLite and,
where a server is reachable, PostgreSQL) or ``service_on_sqlite`` (both named ``service``), and
``service_client`` (``client``) into a test module.  A module overrides the ``service_env`` fixture
(conftest.py; empty by default) to start its service with more environment.  Every test that uses
them is marked ``service`` (conftest.py); one that calls :func:`start_service` itself is marked by
hand (``@pytest.mark.service``), or ``start_service`` refuses to run."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest

ROOT = Path(__file__).resolve().parents[1]
ADMIN_KEY = "ff_testadmin_0123456789abcdef"
BUNNY = ROOT.parent / "shared" / "scenes" / "stanford_bunny" / "bun_zipper.ply"
# A 2x2x1 grid of cells in front of the bunny (bounds x -0.095..0.061, y 0.033..0.187, z -0.062..0.059).
BUNNY_GRID = {"lo": [-0.6, 0.05, -0.05], "hi": [-0.4, 0.15, 0.05], "counts": [2, 2, 1]}


def _children(pid: int) -> list[int]:
    out = subprocess.run(["pgrep", "-P", str(pid)], capture_output=True, text=True).stdout
    return [int(p) for p in out.split()]


def cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


# Whether the running test is marked ``service`` (set by conftest.py before each test; None outside
# pytest, e.g. benchmarks/hostile_campaign.py).
SERVICE_TIER: bool | None = None
_NUMBA_SECONDS: list[float] = []


def warm_numba_kernels() -> float:
    """Compile (or load from numba's cache) every registered technique's numba kernels in this
    process (:func:`farfield.core.techniques.warm_techniques`, as a render worker does), once: it fills the on-disk cache the service's render workers then load in
    :func:`farfield.workers.tasks.warm_worker`.  Seconds taken by the first call."""
    if not _NUMBA_SECONDS:
        from farfield.core.techniques import warm_techniques

        _NUMBA_SECONDS.append(warm_techniques())
    return _NUMBA_SECONDS[0]


@dataclass
class RunningService:
    process: subprocess.Popen
    home: Path
    url: str
    env: dict
    broker: str = ""

    def client(self, key: str | None = ADMIN_KEY) -> httpx.Client:
        headers = {"Authorization": f"Bearer {key}"} if key else {}
        return httpx.Client(base_url=self.url, headers=headers, timeout=60)

    def cli(self, *args: str) -> subprocess.CompletedProcess:
        """Run ``farfield ARGS`` against this service's settings."""
        return subprocess.run(
            [sys.executable, "-m", "farfield.cli.main", *args],
            cwd=ROOT,
            env=self.env,
            capture_output=True,
            text=True,
            timeout=120,
        )

    def descendants(self) -> list[int]:
        found, todo = [], [self.process.pid]
        while todo:
            for child in _children(todo.pop()):
                found.append(child)
                todo.append(child)
        return found

    def worker_pool_children(self) -> list[int]:
        """Pids of the celery pool processes (the ones that render)."""
        mains = [p for p in _children(self.process.pid) if "celery" in cmdline(p)]
        return [c for m in mains for c in _children(m)]

    def worker_mains(self) -> list[int]:
        """Pids of the celery worker main processes farfield up started."""
        return [p for p in _children(self.process.pid) if "celery" in cmdline(p)]

    def api_pid(self) -> int:
        return next(p for p in _children(self.process.pid) if "uvicorn" in cmdline(p))

    def redis_pid(self) -> int:
        return next(p for p in _children(self.process.pid) if "redis-server" in cmdline(p))

    def stop(self) -> int:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(60)
            except subprocess.TimeoutExpired:
                for pid in self.descendants():
                    os.kill(pid, signal.SIGKILL)
                self.process.kill()
        return self.process.wait()


def start_service(home: Path, *args: str, **extra_env: str) -> RunningService:
    """``farfield up`` with ``args`` in ``home``, with a free port and one worker unless ``args`` or
    ``extra_env`` say otherwise; returns once it printed its URL and broker."""
    if SERVICE_TIER is False:
        raise RuntimeError(
            "this test starts the service: mark it @pytest.mark.service (or use the service fixtures), so ./run-tests --fast leaves it out"
        )
    warm_numba_kernels()
    env = {
        k: v for k, v in os.environ.items() if k not in ("REDIS_URL", "DATABASE_URL") and not k.startswith("FARFIELD_")
    }
    env.update({
        "FARFIELD_HOME": str(home), "FARFIELD_PORT": "0", "FARFIELD_WORKERS": "1",
        "FARFIELD_ADMIN_KEY": ADMIN_KEY, "FARFIELD_MAX_UPLOAD_MB": "5", **extra_env,
    })  # fmt: skip
    process = subprocess.Popen(
        [sys.executable, "-m", "farfield.cli.main", "up", *args],
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    url, broker, lines = None, None, []
    deadline = time.monotonic() + 120
    while broker is None and time.monotonic() < deadline:
        line = process.stdout.readline()
        if not line:
            raise RuntimeError("farfield up exited:\n" + "".join(lines))
        lines.append(line)
        if line.startswith("farfield is up: dashboard "):
            url = line.split()[4].rstrip("/")
        if line.startswith("data: "):
            broker = line.split("broker: ")[1].strip()
    if url is None or broker is None:
        process.kill()
        raise RuntimeError("farfield up did not start:\n" + "".join(lines))
    return RunningService(process, home, url, env, broker)


def wait_for_job(
    client: httpx.Client, job_id: str, states=("done", "failed", "cancelled"), timeout: float = 300
) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = client.get(f"/v1/jobs/{job_id}").json()
        if job["state"] in states:
            return job
        time.sleep(0.2)
    raise AssertionError(f"job {job_id} still {job['state']} after {timeout} s: {job['counts']}")


def upload(client: httpx.Client, path: Path, name: str | None = None) -> httpx.Response:
    with open(path, "rb") as f:
        return client.post("/v1/scenes", files={"file": (name or path.name, f)})


def fresh_postgres_database(admin_url: str) -> tuple[str, callable]:
    """A new empty database on the server of ``admin_url``: (its URL, a function that drops it)."""
    import uuid

    import sqlalchemy as sa

    name = f"farfield_test_{uuid.uuid4().hex[:12]}"
    # No connection kept between uses: the server may have restarted (bench_cluster_faults.py).
    engine = sa.create_engine(admin_url, isolation_level="AUTOCOMMIT", poolclass=sa.pool.NullPool)
    with engine.connect() as connection:
        connection.execute(sa.text(f'CREATE DATABASE "{name}"'))
    url = sa.engine.make_url(admin_url).set(database=name).render_as_string(hide_password=False)

    def drop() -> None:
        with engine.connect() as connection:
            connection.execute(sa.text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        engine.dispose()

    return url, drop


def _module_service(request, tmp_path_factory, database: str, env: dict):
    extra, drop = dict(env), None
    if database == "postgresql":
        admin_url = os.environ.get("FARFIELD_TEST_DATABASE_URL")
        if not admin_url:
            pytest.skip(
                "no PostgreSQL server: set FARFIELD_TEST_DATABASE_URL (CI starts one with scripts/postgres-server)"
            )
        extra["DATABASE_URL"], drop = fresh_postgres_database(admin_url)
    running = start_service(tmp_path_factory.mktemp("farfield-home"), **extra)
    yield running
    assert running.stop() == 0
    if drop is not None:
        drop()


@pytest.fixture(name="service", scope="module", params=["sqlite", "postgresql"])
def service_on_each_database(request, tmp_path_factory, numba_kernels, service_env):
    """A running service per test module, on the embedded SQLite database and, where a server is
    reachable (FARFIELD_TEST_DATABASE_URL; .ci/run starts one with scripts/postgres-server), on
    PostgreSQL.  Import it (and :func:`service_client`) into a test module to use it."""
    yield from _module_service(request, tmp_path_factory, request.param, service_env)


@pytest.fixture(name="service", scope="module")
def service_on_sqlite(request, tmp_path_factory, numba_kernels, service_env):
    """A running service per test module, on the embedded SQLite database only."""
    yield from _module_service(request, tmp_path_factory, "sqlite", service_env)


@pytest.fixture(name="client", scope="module")
def service_client(service):
    """An HTTP client of the module's service, authenticated as its admin."""
    with service.client() as c:
        yield c


def stored_options(technique: str, **given) -> dict:
    """The options a job of ``technique`` stores for the request's ``given`` options: every option,
    validated and normalised (:func:`farfield.core.options.stored_values`)."""
    from farfield.core.options import stored_values
    from farfield.core.techniques import get_technique

    return stored_values(get_technique(technique).options(given))


def assert_timing_adds_up(job: dict, workers: int = 1) -> dict:
    """The job record's ``timing`` (:mod:`farfield.service.jobs.timing`) against its own cells: the
    stages are the cells' ``stats.seconds`` summed, each within its cell's wall seconds, the cells
    within their busy span times ``workers``, the phases within the job's wall and the overhead the
    rest of it; returns it."""
    timing = job["timing"]
    timed = [c for c in job["cells"] if c["seconds"] is not None]
    assert timing["cells"] == len(timed) and timing["cells_s"] == pytest.approx(sum(c["seconds"] for c in timed))
    stages: dict[str, float] = {}
    for cell in timed:
        seconds = (cell["stats"] or {}).get("seconds") or {}
        assert seconds.get("total", 0.0) <= cell["seconds"], cell  # the bake is part of its cell
        for name, value in seconds.items():
            if name != "total":
                stages[name] = stages.get(name, 0.0) + value
    assert timing["stages"] == pytest.approx(stages) and timing["bake_s"] == pytest.approx(sum(stages.values()))
    assert timing["bake_s"] + timing["evaluation_s"] <= timing["cells_s"] + 1e-6
    assert (
        timing["cells_s"] <= timing["cells_busy_s"] * workers + 1e-3
    )  # cells.seconds within [started_at, finished_at]
    phases = timing["admission_s"] + timing["planning_s"] + timing["checking_s"] + timing["cells_busy_s"]
    assert phases <= timing["wall_s"] + 1e-3, timing
    assert timing["wall_s"] == pytest.approx(job["finished_at"] - job["created_at"])
    assert timing["overhead_s"] == pytest.approx(max(timing["wall_s"] - phases, 0.0), abs=1e-6)
    return timing
