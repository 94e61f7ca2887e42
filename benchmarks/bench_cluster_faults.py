"""Does a job survive its shared services failing?  A fault campaign on the cluster harness (issue 58).

Usage: ``.venv/bin/python benchmarks/bench_cluster_faults.py [--scenarios redis,s3] [--down 30]
[--counts 3 2 1] [--resolution 1024] [--postgres] [--env FARFIELD_S3_OUTAGE_S=0]``

A cluster (tests/cluster_harness.py: an API node and two worker nodes, each a process group with its
own FARFIELD_HOME and TMPDIR, sharing Redis over TCP, the database and moto's S3 server) bakes a
bunny grid job of several cells with the default lease settings; once a cell is running, one shared
service fails for ``--down`` seconds:

- ``redis``: the Redis server is stopped (SIGTERM: it writes its append-only file and exits; nothing
  listens on its port) and started again on the same port from that file;
- ``s3``: the S3 endpoint refuses connections: the nodes reach moto's server through a TCP gate
  (``TcpGate``) that is closed (open connections cut, new ones refused) and opened again.  moto's
  buckets live in its memory, so stopping moto itself would lose every blob; behind the gate it
  keeps them;
- ``postgres``: the PostgreSQL server (``--postgres``: one started by ``scripts/postgres-server``) is
  stopped (``pg_ctl stop -m fast``) and started again on the same port and data.

Then the job is waited for.  Printed per scenario: the job's state, cells done / failed, attempts per
cell, bundles uploaded (``PUT .../manifest.json`` in moto's log) against cells baked, bake tasks the
workers' logs say ended ``done`` (more than the cells: a cell done twice), seconds from the end of the
fault until the job ended, and the error and warning lines of the workers' and the API's logs.
Each scenario's job has its own resolution, so no job finds another's bundles.
"""

from __future__ import annotations

import argparse
import collections
import re
import sys
import tempfile
import time
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from cluster_harness import Cluster, job_or_none, wait_through_faults  # noqa: E402
from service_harness import BUNNY, BUNNY_GRID, upload  # noqa: E402

from farfield.service.settings import HEARTBEAT_S, LEASE_S, SWEEP_S  # noqa: E402

PROBLEM = re.compile(r"\b(ERROR|WARNING|CRITICAL|Traceback)\b")


def wait_running(client: httpx.Client, job_id: str, timeout: float = 300) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = job_or_none(client, job_id)
        if job and any(c["state"] == "running" and c["progress"] > 0 for c in job["cells"]):
            return
        time.sleep(0.1)
    raise RuntimeError(f"no cell of job {job_id} was running within {timeout} s")


def problems(text: str) -> collections.Counter:
    """Error and warning lines, counted by their message without ids and numbers."""
    found = collections.Counter()
    for line in text.splitlines():
        if PROBLEM.search(line):
            message = re.sub(r"\b[0-9a-f]{8,}\b|\b\d+(\.\d+)?\b", "#", line.split("] ", 1)[-1])
            found[message.strip()[:160]] += 1
    return found


def run_scenario(cluster: Cluster, client: httpx.Client, scene_id: str, fault: str, down: float, args,
                 resolution: int) -> dict:  # fmt: skip
    marks = cluster.log_marks()
    grid = {**BUNNY_GRID, "counts": list(args.counts)}
    created = client.post("/v1/jobs", json={"scene_id": scene_id, "grid": grid, "resolution": resolution,
                                            "evaluate": False})  # fmt: skip
    created.raise_for_status()
    job_id = created.json()["id"]
    submitted = time.monotonic()
    wait_running(client, job_id)
    before = job_or_none(client, job_id)["counts"]
    began = time.monotonic()
    if fault == "redis":
        cluster.stop_redis()
        time.sleep(down)
        cluster.start_redis()
    elif fault == "s3":
        cluster.s3_gate.close()
        time.sleep(down)
        cluster.s3_gate.open()
    elif fault == "postgres":
        cluster.postgres.stop()
        time.sleep(down)
        cluster.postgres.start()
    else:
        time.sleep(down)  # "none": the same job with no fault, for comparison
    restored = time.monotonic()
    job, ended = wait_through_faults(client, job_id, args.timeout)
    time.sleep(2)  # the last log lines
    logs = cluster.logs_since(marks)
    workers_text = "".join(logs[n.name] for n in cluster.workers)
    row = {
        "fault": fault, "job": job["state"] if job else "NOT ENDED", "seconds_down": restored - began,
        "before": before, "to_end_s": ended - restored, "total_s": ended - submitted,
        "cells": job["cells"] if job else job_or_none(client, job_id)["cells"],
        "manifest_puts": cluster.manifest_puts(marks), "task_outcomes": dict(cluster.bake_outcomes(marks)),
        "worker_problems": problems(workers_text), "api_problems": problems(logs["api"]),
    }  # fmt: skip
    return row


def report(row: dict) -> None:
    cells = row["cells"]
    states = collections.Counter(c["state"] for c in cells)
    baked = sum(1 for c in cells if c["state"] == "done" and (c.get("stats") or {}).get("baked"))
    attempts = [c["attempts"] for c in sorted(cells, key=lambda c: c["index"])]
    print(f"\n## {row['fault']}: down {row['seconds_down']:.1f} s (fault began with cells {row['before']})")
    print(f"job {row['job']}; cells done {states['done']}, failed {states['failed']}, other "
          f"{len(cells) - states['done'] - states['failed']}; attempts per cell {attempts}")  # fmt: skip
    print(f"bundles uploaded (manifest PUTs) {row['manifest_puts']}, cells that baked {baked}; bake tasks by "
          f"outcome {row['task_outcomes']}")  # fmt: skip
    print(f"fault end -> job ended {row['to_end_s']:.1f} s; submitted -> ended {row['total_s']:.1f} s")
    for c in cells:
        if c["state"] != "done" or c["error"]:
            print(f"  cell {c['index']}: {c['state']}, attempts {c['attempts']}, error {c['error']!r}")
    for who in ("worker", "api"):
        found = row[f"{who}_problems"]
        print(f"{who} log: {sum(found.values())} error/warning lines")
        for message, n in found.most_common(8):
            print(f"  {n} x {message}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", default="redis,s3", help="comma-separated: none, redis, s3, postgres")
    parser.add_argument("--down", type=float, default=30.0, help="seconds each service stays down")
    parser.add_argument("--counts", type=int, nargs=3, default=[3, 2, 1], help="the bunny grid's cells per axis")
    parser.add_argument("--resolution", type=int, default=1024)
    parser.add_argument("--timeout", type=float, default=900.0, help="seconds to wait for a job after its fault")
    parser.add_argument("--postgres", action="store_true", help="the database on a PostgreSQL server of our own")
    parser.add_argument("--env", action="append", default=[], metavar="NAME=VALUE", help="a setting for every node")
    args = parser.parse_args()
    scenarios = args.scenarios.split(",")
    env = dict(item.split("=", 1) for item in args.env)
    if "postgres" in scenarios and not args.postgres:
        print("the postgres scenario needs --postgres (a server of scripts/postgres-server); skipped")
        scenarios.remove("postgres")
    rows = []
    with tempfile.TemporaryDirectory(prefix="farfield-faults-") as tmp:
        with Cluster(Path(tmp) / "cluster", workers=2, env=env, s3_gate=True, own_postgres=args.postgres) as cluster:
            if args.postgres and cluster.postgres is None:
                print(f"{cluster.postgres_missing}; skipped")
                return
            cluster.wait_for_workers(2)
            with cluster.client() as client:
                scene_id = upload(client, BUNNY).json()["id"]
                for i, fault in enumerate(scenarios):
                    row = run_scenario(cluster, client, scene_id, fault, args.down, args, args.resolution - 8 * i)
                    report(row)
                    rows.append(row)
            database = cluster.shared_env()["DATABASE_URL"].split(":")[0]
    cells = args.counts[0] * args.counts[1] * args.counts[2]
    print(f"\nlease {LEASE_S} s, heartbeat {HEARTBEAT_S} s, sweep {SWEEP_S} s; database {database}; bunny grid of "
          f"{cells} cells at about {args.resolution} px; 2 worker nodes; settings {env or 'default'}")  # fmt: skip
    print("| fault | down (s) | job | done / failed | attempts | bundles uploaded / baked | fault end -> job end (s) |")
    print("|---|---|---|---|---|---|---|")
    for row in rows:
        states = collections.Counter(c["state"] for c in row["cells"])
        baked = sum(1 for c in row["cells"] if c["state"] == "done" and (c.get("stats") or {}).get("baked"))
        attempts = sum(c["attempts"] for c in row["cells"])
        print(f"| {row['fault']} | {row['seconds_down']:.0f} | {row['job']} | {states['done']} / {states['failed']} | "
              f"{attempts} for {len(row['cells'])} cells | {row['manifest_puts']} / {baked} | {row['to_end_s']:.1f} |")  # fmt: skip


if __name__ == "__main__":
    main()
