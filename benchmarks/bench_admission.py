"""``POST /v1/jobs`` latency by cell count, and ``GET /v1/health`` while it runs (issue 58, item 3).

Usage: ``.venv/bin/python benchmarks/bench_admission.py [--sizes 1,100,1000,10000] [--repeats 3] [--workers 0] [--json] [--checks-only]``

First, in this process, each technique's full check per cell (what the request ran for every cell
before issue 58; a worker runs it now) and its ``bound`` per cell (what the request runs now).

A real ``farfield up`` (embedded redis-server, uvicorn, SQLite, blob directory; ``--workers`` Celery
workers, none by default so that the admission tasks wait in the queue and only the request is
measured) with a 3-building city uploaded.  For each size a layered grid job of that many cells
(512 px, in front of the city) is posted ``--repeats`` times, each cancelled after, while a thread
asks ``GET /v1/health`` every 20 ms; the table gives the POST's wall time (median and worst) and
the health requests' p50, p95 and worst latency during the POSTs.  Before issue 58 the request
planned every cell: 10,000 cells took 634 s and health answered in up to 4.2 s meanwhile.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the test scenes' writer

from scenes import city, write_scene  # noqa: E402

from farfield.service.settings import Settings  # noqa: E402
from farfield.service.supervisor import Service  # noqa: E402

KEY = "ff_bench_admission_0123456789abcdef"
HEALTH_EVERY_S = 0.02


def grid(cells: int) -> dict:
    """A grid of ``cells`` boxes (a square of them where it can be) 60 to 80 units in front of the city."""
    side = int(round(cells**0.5))
    counts = [cells // side, 1, side] if cells % side == 0 else [cells, 1, 1]
    return {"lo": [20.0, 3.0, -100.0], "hi": [40.0, 7.0, -80.0], "counts": counts}


class HealthPoller:
    """A thread asking ``GET /v1/health`` every ``HEALTH_EVERY_S``; ``window()`` collects the latencies
    of the requests that started within it."""

    def __init__(self, url: str) -> None:
        self.client = httpx.Client(base_url=url, timeout=60)
        self.samples: list[tuple[float, float]] = []  # (start, seconds)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.is_set():
            start = time.perf_counter()
            self.client.get("/v1/health")
            self.samples.append((start, time.perf_counter() - start))
            self.stop.wait(HEALTH_EVERY_S)

    def window(self, begin: float, end: float) -> list[float]:
        return [s for t, s in list(self.samples) if begin <= t <= end]

    def close(self) -> None:
        self.stop.set()
        self.thread.join(timeout=60)
        self.client.close()


def run(sizes: list[int], repeats: int, workers: int) -> list[dict]:
    with tempfile.TemporaryDirectory(prefix="farfield-bench-admission-") as tmp:
        home = Path(tmp) / "home"
        os.environ["FARFIELD_ADMIN_KEY"] = KEY
        settings = Settings.from_env({"FARFIELD_HOME": str(home), "FARFIELD_PORT": "0", "FARFIELD_ADMIN_KEY": KEY})
        service = Service(settings, workers=workers).start()
        try:
            client = httpx.Client(base_url=service.url, headers={"Authorization": f"Bearer {KEY}"}, timeout=3600)
            path = write_scene(city(buildings=3), Path(tmp), "glb", "city")
            with open(path, "rb") as f:
                scene_id = client.post("/v1/scenes", files={"file": (path.name, f)}).json()["id"]
            poller = HealthPoller(service.url)
            rows = []
            for cells in sizes:
                posts, health = [], []
                for _ in range(repeats):
                    time.sleep(0.3)  # a few health requests before
                    begin = time.perf_counter()
                    response = client.post(
                        "/v1/jobs", json={"scene_id": scene_id, "resolution": 512, "grid": grid(cells)}
                    )
                    end = time.perf_counter()
                    if response.status_code != 201:
                        raise SystemExit(f"{cells} cells: {response.status_code} {response.text}")
                    posts.append(end - begin)
                    time.sleep(2 * HEALTH_EVERY_S)
                    health += poller.window(begin, end)
                    client.post(f"/v1/jobs/{response.json()['id']}/cancel")  # frees the tenant's quota
                h = np.array(health) if health else np.array([np.nan])
                rows.append({
                    "cells": cells, "post_median_s": statistics.median(posts), "post_max_s": max(posts),
                    "health_requests": len(health), "health_p50_ms": 1e3 * float(np.percentile(h, 50)),
                    "health_p95_ms": 1e3 * float(np.percentile(h, 95)), "health_max_ms": 1e3 * float(h.max()),
                })  # fmt: skip
            poller.close()
            return rows
        finally:
            service.stop()


def check_costs(cells: int = 5, bound_cells: int = 10_000) -> list[dict]:
    """Each technique's full check (what the request ran per cell before issue 58; a worker runs it
    now) per cell, and its ``bound`` (what the request runs now) per cell over ``bound_cells``
    cells, in this process: 4-unit box cells about 80 units in front of the 3-building city, the
    techniques' default options (an octahedral impostor its own outside-the-sphere cell)."""
    from farfield.core.techniques import TECHNIQUES
    from farfield.core.viewcells import BoxCell, SphereOutsideCell

    scene = city(buildings=3)
    bounds = np.asarray(scene.bounds, dtype=np.float64)
    boxes = [BoxCell([28.0 + 0.01 * i, 3.0, -80.0], [32.0 + 0.01 * i, 7.0, -76.0]) for i in range(bound_cells)]
    rows = []
    for name, technique in TECHNIQUES.items():
        options = technique.options({})
        if name == "octahedral":
            centre = 0.5 * (bounds[0] + bounds[1])
            radius = float(np.linalg.norm(bounds[1] - bounds[0]))
            many = [SphereOutsideCell(centre, radius) for _ in range(bound_cells)]
        else:
            many = boxes
        part = bounds if technique.scope == "part" else None
        start = time.perf_counter()
        for cell in many[:cells]:
            cost = technique.check(cell, options, part)
        check_s = (time.perf_counter() - start) / cells
        bound = getattr(technique, "bound", None)
        bound_s = None
        if bound is not None:
            start = time.perf_counter()
            bound(many, options, part)
            bound_s = (time.perf_counter() - start) / len(many)
        rows.append({"technique": name, "check_ms": 1e3 * check_s, "cost": cost.describe(),
                     "bound_us": None if bound_s is None else 1e6 * bound_s})  # fmt: skip
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="1,100,1000,10000")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--workers", type=int, default=0)
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--checks-only", action="store_true", help="only the techniques' check and bound costs")
    args = parser.parse_args()
    checks = check_costs()
    print("per cell: the full check (a worker runs it) and the request's bound (10,000 cells at once)")
    print(f"{'technique':<11} {'check ms':>9} {'bound us':>9}  cost of one cell")
    for r in checks:
        bound = f"{r['bound_us']:>9.1f}" if r["bound_us"] is not None else f"{'none':>9}"
        print(f"{r['technique']:<11} {r['check_ms']:>9.2f} {bound}  {r['cost']}")
    if args.checks_only:
        return
    rows = run([int(s) for s in args.sizes.split(",")], args.repeats, args.workers)
    if args.json:
        print(json.dumps(rows, indent=2))
        return
    print(
        f"POST /v1/jobs (layered grid, 512 px), {args.repeats} each, {args.workers} workers; load average {os.getloadavg()[0]:.1f}"
    )
    print(f"{'cells':>7} {'POST median':>12} {'POST max':>9} {'health n':>9} {'p50 ms':>8} {'p95 ms':>8} {'max ms':>8}")
    for r in rows:
        print(
            f"{r['cells']:>7,} {r['post_median_s']:>11.3f}s {r['post_max_s']:>8.3f}s {r['health_requests']:>9} "
            f"{r['health_p50_ms']:>8.1f} {r['health_p95_ms']:>8.1f} {r['health_max_ms']:>8.1f}"
        )


if __name__ == "__main__":
    main()
