"""``farfield up``: embedded Redis (when no REDIS_URL), the API under uvicorn, and render workers.

Children run as separate processes, each in its own session (so a Ctrl-C on the terminal reaches
only the supervisor), with the same settings in their environment.  The supervisor restarts Redis
(its append-only file keeps the queue), workers and the API when they die (the API on its port,
after a back-off that doubles while it keeps dying young), and on SIGINT/SIGTERM, which it
handles from its first moment, stops the API, then the workers (warm shutdown: a running cell
finishes or is delivered again later), then Redis; a child that does not stop in time is killed
with its whole process group (a worker's pool processes included).
"""

from __future__ import annotations

import os
import secrets
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from farfield.service.blobs import blob_store
from farfield.service.db import Database
from farfield.service.embedded_redis import EmbeddedRedis, free_port
from farfield.service.jobs.cells import release_lost_cells, running_cells_of
from farfield.service.keys import ensure_admin_key
from farfield.service.leftovers import HomeLock, forget_children, reap, record_child, temp_dir
from farfield.service.placement.lease import planning_jobs_of, release_planning
from farfield.service.pools import QUEUES
from farfield.service.settings import Settings

STOP_GRACE_S = 20.0
# The API's restart back-off: this long after a death, doubling (to the maximum) while it keeps
# dying within a minute of its start.
API_BACKOFF_S = 0.5
API_BACKOFF_MAX_S = 30.0


def gpu_count() -> int:
    """NVIDIA GPUs on this machine (0 without nvidia-smi)."""
    try:
        out = subprocess.run(["nvidia-smi", "-L"], capture_output=True, text=True, timeout=10).stdout
        return sum(1 for line in out.splitlines() if line.startswith("GPU "))
    except (OSError, subprocess.SubprocessError):
        return 0


def render_devices() -> int:
    """How many workers to start: FARFIELD_WORKERS, else one per NVIDIA GPU, else one."""
    if os.environ.get("FARFIELD_WORKERS"):
        return max(1, int(os.environ["FARFIELD_WORKERS"]))
    return max(1, gpu_count())


def worker_command(name: str, concurrency: int = 1) -> list[str]:
    """The celery worker command line: both render queues (its heartbeat then keeps those of its kind:
    service/pools.py)."""
    return [
        sys.executable, "-m", "celery", "-A", "farfield.workers.app", "worker", "-Q", ",".join(QUEUES), "--pool", "prefork",
        "-c", str(concurrency), "-n", f"{name}@%h", "--loglevel", "INFO", "--without-gossip", "--without-mingle",
    ]  # fmt: skip


def admin_key(settings: Settings, db: Database) -> str:
    """FARFIELD_ADMIN_KEY, else the key kept in $FARFIELD_HOME/admin.key (made on first start)."""
    if settings.admin_key:
        key = settings.admin_key
    else:
        path = settings.home / "admin.key"
        if path.exists():
            key = path.read_text().strip()
        else:
            key = f"ff_admin{secrets.token_hex(4)}_{secrets.token_urlsafe(24).replace('_', '-')}"
            path.touch(mode=0o600)
            path.write_text(key + "\n")
    ensure_admin_key(db, key)
    return key


@dataclass
class Service:
    """The processes of one ``farfield up``."""

    settings: Settings
    workers: int = 1
    redis: EmbeddedRedis | None = None
    api: subprocess.Popen | None = None
    worker_processes: list[subprocess.Popen] = field(default_factory=list)
    worker_specs: list[tuple[list[str], dict, Path]] = field(default_factory=list)
    key: str = ""
    url: str = ""
    stop_requested: list = field(default_factory=list)
    api_spec: tuple[list[str], dict, Path] | None = None
    api_started: float = 0.0
    api_backoff: float = API_BACKOFF_S / 2.0  # the first death within a minute waits API_BACKOFF_S
    lock: HomeLock | None = None  # one farfield up per home (service/leftovers.py)

    def handle_signals(self) -> None:
        """From now on SIGINT and SIGTERM ask :meth:`watch` to return (call before :meth:`start`)."""
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            signal.signal(sig, lambda *_: self.stop_requested.append(True))

    @staticmethod
    def _spawn(command: list[str], env: dict, log_path: Path) -> subprocess.Popen:
        with open(log_path, "ab") as log:  # the child keeps its own copy of the descriptor
            return subprocess.Popen(
                command, env=env, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True
            )

    def start(self) -> Service:
        settings = self.settings
        settings.home.mkdir(parents=True, exist_ok=True)
        self.lock = HomeLock(settings.home).acquire()
        reaped, roles = reap(settings.home)  # what a killed farfield up on this home left
        for line in reaped:
            print(f"farfield: {line}", file=sys.stderr)
        db = Database(settings.database_url)
        db.migrate()
        self.key = admin_key(settings, db)
        db.dispose()
        if settings.redis_url is None:
            self.redis = EmbeddedRedis(settings.home / "redis").start()
            record_child(settings.home, "redis", self.redis.process.pid)
            settings = self.settings = settings.with_redis(self.redis.url)
        for role in roles:  # a reaped worker's cells were running: queue them again now, not in an hour
            if role.startswith("worker"):
                self.release_cells_of(role, None)
        port = settings.port or free_port()
        # TMPDIR: what killed children leave there is reaped by the next start (service/leftovers.py).
        env = {
            **os.environ,
            **settings.environment(),
            "FARFIELD_ADMIN_KEY": self.key,
            "TMPDIR": str(temp_dir(settings.home)),
        }
        logs = settings.home / "logs"
        logs.mkdir(exist_ok=True)
        gpus = gpu_count()
        for i in range(self.workers):
            # With GPUs, worker i renders on EGL device i (round robin when there are more workers).
            device = {"FARFIELD_EGL_DEVICE": str(i % gpus)} if gpus else {}
            self.worker_specs.append((worker_command(f"worker{i}"), {**env, **device}, logs / f"worker{i}.log"))
            self.worker_processes.append(self._spawn(*self.worker_specs[-1]))
            record_child(settings.home, f"worker{i}", self.worker_processes[-1].pid)
        api = [
            sys.executable,
            "-m",
            "uvicorn",
            "farfield.api.app:app_from_env",
            "--factory",
            "--host",
            settings.host,
            "--port",
            str(port),
            "--log-level",
            "warning",
            "--no-server-header",  # no "Server: uvicorn" banner (issue 59, item 11)
            "--http",  # header and body read timeouts (issue 59, item 11)
            "farfield.api.read_timeouts:TimedH11Protocol",
        ]
        self.api_spec = (api, env, logs / "api.log")
        self.api = self._spawn(*self.api_spec)
        record_child(settings.home, "api", self.api.pid)
        self.api_started = time.monotonic()
        self.url = f"http://{settings.host}:{port}"
        self._wait_for_api()
        return self

    def _restart_api(self) -> None:
        """Start the API again on its port after it died (issue 59, item 5: it took the whole service
        down), with a back-off that doubles while it keeps dying within a minute of its start."""
        lived = time.monotonic() - self.api_started
        self.api_backoff = API_BACKOFF_S if lived > 60.0 else min(2.0 * self.api_backoff, API_BACKOFF_MAX_S)
        print(
            f"farfield: the API exited with code {self.api.returncode} after {lived:.0f} s; starting it again "
            f"in {self.api_backoff:.1f} s (see {self.settings.home / 'logs' / 'api.log'})",
            file=sys.stderr,
        )
        deadline = time.monotonic() + self.api_backoff
        while time.monotonic() < deadline and not self.stop_requested:
            time.sleep(0.1)
        try:  # what the dead API started (scene checks parse in its process group) goes with it
            os.killpg(self.api.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        if not self.stop_requested:
            self.api = self._spawn(*self.api_spec)
            record_child(self.settings.home, "api", self.api.pid)
            self.api_started = time.monotonic()

    def _wait_for_api(self, timeout: float = 60.0) -> None:
        import httpx

        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.api.poll() is not None:
                raise RuntimeError(
                    f"the API exited with code {self.api.returncode}; see {self.settings.home / 'logs' / 'api.log'}"
                )
            try:
                if httpx.get(self.url + "/v1/health", timeout=2, trust_env=False).status_code == 200:
                    return
            except httpx.HTTPError:
                pass
            time.sleep(0.2)
        raise RuntimeError(f"the API did not answer at {self.url} within {timeout:.0f} s")

    def watch(self) -> None:
        """Keep Redis, the workers and the API alive until a signal arrives (see :meth:`handle_signals`)."""
        while not self.stop_requested:
            if self.redis is not None and not self.redis.alive():
                self.redis.start()
                record_child(self.settings.home, "redis", self.redis.process.pid)
            for i, process in enumerate(self.worker_processes):
                if process.poll() is not None:
                    print(
                        f"farfield: worker{i} exited with code {process.returncode}; starting it again", file=sys.stderr
                    )
                    try:  # its pool processes outlive it: stop them rendering cells that are handed out again
                        os.killpg(process.pid, signal.SIGKILL)
                    except ProcessLookupError:
                        pass
                    self.release_cells_of(f"worker{i}", process.returncode)
                    self.worker_processes[i] = self._spawn(*self.worker_specs[i])
                    record_child(self.settings.home, f"worker{i}", self.worker_processes[i].pid)
            if self.api.poll() is not None:
                self._restart_api()
            time.sleep(0.5)

    def release_cells_of(self, name: str, code: int | None) -> None:
        """Queue again at once the cells a dead worker was running (:func:`release_lost_cells`): their
        messages stay unacknowledged in Redis until the visibility timeout, so they are sent again."""
        worker = f"{name}@{socket.gethostname()}"  # the node name `-n name@%h` gives it
        db = Database(self.settings.database_url)
        try:
            blobs = blob_store(self.settings)
            changed = release_lost_cells(db, blobs, running_cells_of(db, worker), self.settings.max_attempts,
                                         f"worker {worker} exited with code {code}", worker=worker, resend=True)  # fmt: skip
            if changed:
                print(
                    f"farfield: {len(changed)} cells of {worker} released: {sorted(set(changed.values()))}",
                    file=sys.stderr,
                )
            for job_id in planning_jobs_of(db, worker):  # a placement job it planned: the sweeper sends it again
                state = release_planning(
                    db, job_id, f"worker {worker} exited with code {code}", worker, self.settings.max_attempts, blobs
                )
                print(f"farfield: the planning of job {job_id} on {worker} released: {state}", file=sys.stderr)
        except Exception as error:  # noqa: BLE001 - the cells come back after the visibility timeout anyway
            print(f"farfield: could not release the cells of {worker}: {error}", file=sys.stderr)
        finally:
            db.dispose()

    def stop(self) -> None:
        """API first (no new jobs), then the workers, then Redis."""
        procs = [p for p in [self.api] if p is not None]
        for group in (procs, self.worker_processes):
            for p in group:
                if p.poll() is None:
                    p.terminate()
            deadline = time.monotonic() + STOP_GRACE_S
            for p in group:
                try:
                    p.wait(max(0.1, deadline - time.monotonic()))
                except subprocess.TimeoutExpired:
                    os.killpg(p.pid, signal.SIGKILL)  # its own session: the group is it and its children
                    p.wait()
        if self.redis is not None:
            self.redis.stop()
        if self.lock is not None:  # this start held the home: every child it recorded is stopped
            forget_children(self.settings.home)
            self.lock.release()
            self.lock = None
