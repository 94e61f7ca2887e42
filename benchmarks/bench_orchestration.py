"""Throughput of the orchestration itself: trivial cells through API + database + broker + blob store (issue 58, item 5).

Usage: ``.venv/bin/python benchmarks/bench_orchestration.py [--cells 2000] [--workers 1,2] [--repeats 1]
[--database sqlite|postgres] [--job-poll none|all] [--before REV] [--after REV] [--json]``

A real ``farfield up`` (embedded redis-server, uvicorn, ``--workers`` Celery workers of one pool
process each, SQLite by default or a fresh database of a ``scripts/postgres-server`` PostgreSQL, a
blob directory) with a one-building city uploaded, and one job of ``--cells`` **trivial cells**: a
layered grid job at 16 px without evaluation (the cheapest real cell the service offers: its bake
is some 10 ms on llvmpipe, against 0.03 s envmap, 0.6 s octahedral), its cells far in front of the
building.  Before it, a warm job of a few cells (each worker's scene cache, EGL context).

Measured, all from the service's own records (the job's and cells' SQL rows, read after the run):

- **cells per second**: over the bake phase (first cell claimed to the job's end) and over the
  whole job (request to end, its admission included);
- **per-cell overhead**: the bake phase's worker-seconds (wall x workers) per cell, against the
  cell's own stored seconds (``cells.seconds``: claim to outcome) and the bake's stages
  (``stats.seconds``); what lies between is the orchestration's (messages, claims, commits);
- **API latency while the job runs**: a thread asks ``GET /v1/health`` every 50 ms, another
  ``GET /v1/jobs/{id}?cells=none`` (the job's record without its cells, what ``farfield submit --wait``
  and the dashboard poll a large job with; ``--job-poll all``: ``GET /v1/jobs/{id}``, with every
  cell) every 0.5 s; p50 and p95 of each.  A revision before ``?cells=`` ignores the parameter and
  answers every cell, as its clients polled.

``--before REV`` runs the same measurements on a checkout of ``REV`` (``git archive``d to a temporary folder,
imported through ``PYTHONPATH`` ahead of this checkout's editable install), interleaved with this
checkout's, so both see the same machine load; the load average is printed with each run.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
KEY = "ff_bench_orchestration_0123456789abcdef"
RESOLUTION = 16
HEALTH_EVERY_S = 0.05
JOB_EVERY_S = 0.5
PACKAGES = ("api", "cli", "core", "service", "workers")


def grid(cells: int) -> dict:
    """``cells`` boxes of 1 unit in a square (or a row) 90 units or more in front of the one-building
    city (the square reaches away from it)."""
    side = int(round(cells**0.5))
    counts = [cells // side, 1, side] if cells % side == 0 else [cells, 1, 1]
    return {"lo": [-40.0, 5.0, -99.0 - counts[2]], "hi": [-40.0 + counts[0], 6.0, -99.0], "counts": counts}


class Poller:
    """A thread asking ``path`` every ``every_s`` and keeping each request's (start, seconds, status)."""

    def __init__(self, url: str, path: str, every_s: float) -> None:
        import httpx

        self.client = httpx.Client(base_url=url, headers={"Authorization": f"Bearer {KEY}"}, timeout=120)
        self.path, self.every_s = path, every_s
        self.samples: list[tuple[float, float, int]] = []
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.is_set():
            start = time.time()
            status = self.client.get(self.path).status_code
            self.samples.append((start, time.time() - start, status))
            self.stop.wait(self.every_s)

    def close(self) -> list[tuple[float, float, int]]:
        self.stop.set()
        self.thread.join(timeout=120)
        self.client.close()
        return self.samples


def percentiles(samples: list[float]) -> dict:
    import numpy as np

    if not samples:
        return {"n": 0, "p50_ms": None, "p95_ms": None, "max_ms": None}
    a = 1e3 * np.asarray(samples)
    return {"n": len(samples), "p50_ms": float(np.percentile(a, 50)), "p95_ms": float(np.percentile(a, 95)),
            "max_ms": float(a.max())}  # fmt: skip


def cell_rows(database_url: str, job_id: str) -> list[tuple]:
    """(started_at, finished_at, seconds, stats, attempts, state) of each cell of the job, read from its SQL rows."""
    query = "SELECT started_at, finished_at, seconds, stats, attempts, state FROM cells WHERE job_id = ?"
    if database_url.startswith("sqlite:///"):
        with sqlite3.connect(database_url.removeprefix("sqlite:///")) as connection:
            return connection.execute(query, (job_id,)).fetchall()
    from sqlalchemy import create_engine, text

    engine = create_engine(database_url)
    with engine.connect() as connection:
        rows = connection.execute(text(query.replace("?", ":job")), {"job": job_id}).fetchall()
    engine.dispose()
    return [tuple(r) for r in rows]


def one_run(cells: int, workers: int, database_url: str | None, job_poll: str = "none") -> dict:
    """One service, one warm job, one measured job (this process imports whichever farfield is first on the path)."""
    import httpx

    sys.path.insert(0, str(ROOT / "tests"))  # the test scenes' writer
    from scenes import city, write_scene

    from farfield.service.settings import Settings
    from farfield.service.supervisor import Service

    # A process of the stopped service may still write under the home while it is deleted: the
    # figures are not lost to that.
    with tempfile.TemporaryDirectory(prefix="farfield-bench-orch-", ignore_cleanup_errors=True) as tmp:
        env = {"FARFIELD_HOME": str(Path(tmp) / "home"), "FARFIELD_PORT": "0", "FARFIELD_ADMIN_KEY": KEY}
        if database_url:
            env["DATABASE_URL"] = database_url
        os.environ.update(env)
        settings = Settings.from_env(env)
        service = Service(settings, workers=workers).start()
        try:
            client = httpx.Client(base_url=service.url, headers={"Authorization": f"Bearer {KEY}"}, timeout=600)
            path = write_scene(city(buildings=1), Path(tmp), "glb", "city")
            with open(path, "rb") as f:
                scene_id = client.post("/v1/scenes", files={"file": (path.name, f)}).json()["id"]
            spec = {"scene_id": scene_id, "resolution": RESOLUTION, "evaluate": False}
            warm = client.post("/v1/jobs", json={**spec, "grid": grid(4 * workers)}).json()["id"]
            while client.get(f"/v1/jobs/{warm}").json()["state"] not in ("done", "failed", "cancelled"):
                time.sleep(0.1)
            load = os.getloadavg()
            posted = time.time()
            response = client.post("/v1/jobs", json={**spec, "grid": grid(cells)})
            post_s = time.time() - posted
            if response.status_code != 201:
                raise SystemExit(f"{response.status_code} {response.text}")
            job_id = response.json()["id"]
            health = Poller(service.url, "/v1/health", HEALTH_EVERY_S)
            job_poll = Poller(service.url, f"/v1/jobs/{job_id}?cells={job_poll}", JOB_EVERY_S)
            while True:
                time.sleep(0.5)
                newest = client.get("/v1/jobs", params={"limit": 1}).json()[0]  # the record without its cells
                if newest["state"] in ("done", "failed", "cancelled"):
                    break
            health_samples, job_samples = health.close(), job_poll.close()
            load_after = os.getloadavg()
            job = client.get(f"/v1/jobs/{job_id}").json()
            rows = cell_rows(service.settings.database_url, job_id)
        finally:
            service.stop()
    started = [r[0] for r in rows if r[0] is not None]
    first, end = min(started), job["finished_at"]
    bake_wall = end - first
    seconds = [r[2] for r in rows if r[2] is not None]
    stages = []
    for r in rows:
        stats = json.loads(r[3]) if isinstance(r[3], str) else r[3]
        total = ((stats or {}).get("seconds") or {}).get("total")
        if total is not None:
            stages.append(total)
    during = [(t, s) for t, s, status in health_samples if first <= t <= end]
    job_during = [(t, s) for t, s, status in job_samples if first <= t <= end]
    return {
        "cells": cells, "workers": workers, "state": job["state"], "database": service.settings.database_url.split(":")[0],
        "post_s": post_s, "admission_s": first - job["created_at"], "bake_wall_s": bake_wall, "job_wall_s": end - job["created_at"],
        "cells_per_s_bake": cells / bake_wall, "cells_per_s_job": cells / (end - job["created_at"]),
        "worker_s_per_cell_ms": 1e3 * bake_wall * workers / cells,
        "cell_seconds_mean_ms": 1e3 * statistics.fmean(seconds), "bake_stages_mean_ms": 1e3 * statistics.fmean(stages) if stages else None,
        "attempts_max": max(r[4] for r in rows), "attempts_total": sum(r[4] for r in rows),
        "health": percentiles([s for _, s in during]), "job_get": percentiles([s for _, s in job_during]),
        "errors": [s for _, _, s in health_samples + job_samples if s != 200][:5],
        "load_before": load[0], "load_after": load_after[0],
    }  # fmt: skip


def checkout(rev: str, where: Path) -> Path:
    """The files of ``rev`` (``git archive``) under ``where`` and a folder holding a ``farfield``
    namespace of its packages (to put first on ``PYTHONPATH``); returns that folder."""
    (where / "src").mkdir(parents=True)
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(where / "src")], input=archive, check=True)
    package = where / "path" / "farfield"
    package.mkdir(parents=True)
    for name in PACKAGES:
        (package / name).symlink_to(where / "src" / name)
    return where / "path"


def run_child(args: list[str], pythonpath: Path | None) -> dict:
    env = dict(os.environ)
    if pythonpath is not None:
        env["PYTHONPATH"] = f"{pythonpath}{os.pathsep}{env.get('PYTHONPATH', '')}"
    out = subprocess.run([sys.executable, __file__, "--one", *args], env=env, capture_output=True, text=True)
    if out.returncode != 0:
        raise SystemExit(f"run {args} failed:\n{out.stderr[-4000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def postgres_url() -> str:
    """A fresh database on the ``scripts/postgres-server`` server ($FARFIELD_TEST_DATABASE_URL)."""
    import uuid

    from sqlalchemy import create_engine, text

    base = os.environ.get("FARFIELD_TEST_DATABASE_URL")
    if not base:
        raise SystemExit("--database postgres needs FARFIELD_TEST_DATABASE_URL (scripts/postgres-server prints it)")
    name = f"bench_orch_{uuid.uuid4().hex[:8]}"
    engine = create_engine(base, isolation_level="AUTOCOMMIT")
    with engine.connect() as connection:
        connection.execute(text(f"CREATE DATABASE {name}"))
    engine.dispose()
    return base.rsplit("/", 1)[0] + "/" + name


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cells", type=int, default=2000)
    parser.add_argument("--workers", default="1,2")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--database", choices=("sqlite", "postgres"), default="sqlite")
    parser.add_argument("--before", help="a git revision to measure beside this checkout, interleaved")
    parser.add_argument("--after", help="a git revision to measure instead of this checkout's working tree")
    parser.add_argument("--job-poll", choices=("none", "all"), default="none", help="the job GET's ?cells=")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--one", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--database-url", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(one_run(args.cells, int(args.workers), args.database_url, args.job_poll)))
        return
    tmp = Path(tempfile.mkdtemp(prefix="farfield-bench-orch-rev-"))
    versions: list[tuple[str, Path | None]] = [("this checkout", None)]
    try:
        if args.after:  # the working tree may change while the runs go on
            versions = [(f"after ({args.after})", checkout(args.after, tmp / "after"))]
        if args.before:
            versions.insert(0, (f"before ({args.before})", checkout(args.before, tmp / "before")))
        rows = []
        for _ in range(args.repeats):
            for workers in [int(w) for w in args.workers.split(",")]:
                for name, path in versions:
                    child = ["--cells", str(args.cells), "--workers", str(workers), "--job-poll", args.job_poll]
                    if args.database == "postgres":
                        child += ["--database-url", postgres_url()]
                    rows.append({"version": name, **run_child(child, path)})
                    print(f"# {name}, {workers} workers: {rows[-1]['cells_per_s_bake']:.1f} cells/s", file=sys.stderr)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    if args.json:
        print(json.dumps(rows, indent=1))
        return
    print(
        f"{args.cells} trivial cells (layered, {RESOLUTION} px, no evaluation), {args.database}; ms are per cell; "
        f"job GET ?cells={args.job_poll}"
    )
    print("| version | workers | cells/s (bake) | cells/s (job) | admission s | worker-ms per cell | cell's own ms | bake ms "
          "| health p50/p95 ms | job GET p50/p95 ms | attempts | load before/after |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        h, g = r["health"], r["job_get"]
        stages = f"{r['bake_stages_mean_ms']:.1f}" if r["bake_stages_mean_ms"] is not None else "-"
        print(f"| {r['version']} | {r['workers']} | {r['cells_per_s_bake']:.1f} | {r['cells_per_s_job']:.1f} | {r['admission_s']:.1f} "
              f"| {r['worker_s_per_cell_ms']:.0f} | {r['cell_seconds_mean_ms']:.0f} | {stages} "
              f"| {h['p50_ms']:.0f} / {h['p95_ms']:.0f} | {g['p50_ms']:.0f} / {g['p95_ms']:.0f} "
              f"| {r['attempts_total']} (max {r['attempts_max']}) | {r['load_before']:.1f} / {r['load_after']:.1f} |")  # fmt: skip


if __name__ == "__main__":
    main()
