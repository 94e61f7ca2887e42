"""The service measured against baking in one process, side by side in one run.

Usage: ``.venv/bin/python benchmarks/bench_service.py [--cells N] [--json]``

1. Overhead: a job of N bunny cells (1024 output, >= 1 s each on llvmpipe) through the real
   service (``farfield up``'s processes: embedded redis-server, uvicorn, celery workers, SQLite,
   blob directory), from submit to done, against the same cells baked and written one after the
   other in this process.  Goal: <= 10%.
2. Scaling: the same job with 1 and 2 workers (goal >= 1.7x on a 2-core machine); llvmpipe renders
   with one thread per core in every worker, and a run with LP_NUM_THREADS=1 shows the alternative
   of sharing the cores out.

A job's wall time is the service's own: from the job's creation to its end (its timestamps), polled
every 0.5 s so that the polling takes no measurable CPU from the workers.
3. Upload memory: the API process's resident and peak memory before and after streaming a
   ~200 MB binary STL upload.
"""

from __future__ import annotations

import argparse
import json
import os
import struct
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from farfield.core.exchange import load_scene  # noqa: E402
from farfield.core.impostor.bundle import write_bundle  # noqa: E402
from farfield.core.render.context import renderer_info  # noqa: E402
from farfield.core.techniques.layered import BakeOptions, bake_layered  # noqa: E402
from farfield.service.jobs.schema import GridSpec, grid_cells  # noqa: E402
from farfield.service.settings import Settings  # noqa: E402
from farfield.service.supervisor import Service  # noqa: E402

BUNNY = Path(__file__).resolve().parents[2] / "shared" / "scenes" / "stanford_bunny" / "bun_zipper.ply"
KEY = "ff_bench_0123456789abcdef"
RESOLUTION = 1024


def grid(cells: int) -> dict:
    return {"lo": [-0.6, 0.05, -0.05], "hi": [-0.4, 0.15, 0.05], "counts": [cells // 2, 2, 1]}


def _in_process(cells: int) -> float:
    scene = load_scene(BUNNY)
    boxes = [box for _, box in grid_cells(GridSpec(**grid(cells)))]
    bake_layered(scene, boxes[0], BakeOptions(resolution=256))  # warm: context, shaders
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for i, box in enumerate(boxes):
            write_bundle(bake_layered(scene, box, BakeOptions(resolution=RESOLUTION)), Path(tmp) / str(i))
    return time.perf_counter() - start


def start(home: Path, workers: int, **env: str) -> Service:
    os.environ.update({"FARFIELD_ADMIN_KEY": KEY, **env})
    settings = Settings.from_env({"FARFIELD_HOME": str(home), "FARFIELD_PORT": "0", "FARFIELD_ADMIN_KEY": KEY})
    return Service(settings, workers=workers).start()


CONFIGURATIONS = {  # name: (workers, extra environment)
    "service_1_worker": (1, {}),
    "service_2_workers": (2, {}),
    "service_2_workers_1_thread_each": (2, {"LP_NUM_THREADS": "1"}),
}


def interleaved(cells: int, repeats: int) -> dict:
    """Each configuration ``repeats`` times, in rounds (in-process, then each service configuration
    on a freshly started service), so that a change in the machine's load over the run falls on all
    of them alike; per configuration the fastest run counts and every run is listed."""
    walls: dict[str, list] = {"in_process": []}
    runs: dict[str, list] = {name: [] for name in CONFIGURATIONS}
    for _ in range(repeats):
        walls["in_process"].append(_in_process(cells))
        for name, (workers, env) in CONFIGURATIONS.items():
            runs[name].append(_through_service(cells, workers, **env))
    result = {"in_process_s": min(walls["in_process"]), "in_process_runs_s": walls["in_process"]}
    for name, done in runs.items():
        best = min(done, key=lambda run: run["wall_s"])
        result[name] = {**best, "walls_s": [run["wall_s"] for run in done]}
    result["scaling_per_round"] = [
        a["wall_s"] / b["wall_s"] for a, b in zip(runs["service_1_worker"], runs["service_2_workers"])
    ]
    return result


def _through_service(cells: int, workers: int, **env: str) -> dict:
    with tempfile.TemporaryDirectory() as home:
        service = start(Path(home), workers, **env)
        try:
            client = httpx.Client(base_url=service.url, headers={"Authorization": f"Bearer {KEY}"}, timeout=600)
            with open(BUNNY, "rb") as f:
                scene_id = client.post("/v1/scenes", files={"file": (BUNNY.name, f)}).json()["id"]
            # Warm each worker (EGL context, scene parse) with a small job, as the in-process run is warmed.
            warm = client.post(
                "/v1/jobs", json={"scene_id": scene_id, "grid": grid(2 * workers), "resolution": 256}
            ).json()["id"]
            while client.get(f"/v1/jobs/{warm}").json()["state"] not in ("done", "failed"):
                time.sleep(0.05)
            job_id = client.post(
                "/v1/jobs", json={"scene_id": scene_id, "grid": grid(cells), "resolution": RESOLUTION}
            ).json()["id"]
            while (job := client.get(f"/v1/jobs/{job_id}").json())["state"] not in ("done", "failed", "cancelled"):
                time.sleep(0.5)
            assert job["state"] == "done", job["errors"]
            wall = job["finished_at"] - job["created_at"]
            return {"wall_s": wall, "cell_seconds_sum": job["seconds"]["cells_total"]}
        finally:
            service.stop()
            for name in env:
                os.environ.pop(name, None)


def memory_kib(pid: int) -> dict:
    fields = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        name, _, value = line.partition(":")
        if name in ("VmRSS", "VmHWM"):
            fields[name] = int(value.split()[0])
    return fields


def big_stl(path: Path, triangles: int) -> None:
    """A binary STL of ``triangles`` random small triangles (50 bytes each), written in chunks."""
    rng = np.random.default_rng(0)
    record = np.dtype([("normal", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    with open(path, "wb") as f:
        f.write(b"farfield benchmark".ljust(80, b" "))
        f.write(struct.pack("<I", triangles))
        for start in range(0, triangles, 500_000):
            n = min(500_000, triangles - start)
            chunk = np.zeros(n, dtype=record)
            base = rng.uniform(-100, 100, (n, 1, 3)).astype("<f4")
            chunk["v"] = base + rng.uniform(0, 1, (n, 3, 3)).astype("<f4")
            f.write(chunk.tobytes())


def upload_memory(megabytes: int) -> dict:
    with tempfile.TemporaryDirectory() as home:
        path = Path(home) / "big.stl"
        big_stl(path, megabytes * 2**20 // 50)
        service = start(Path(home) / "data", 1)
        try:
            client = httpx.Client(base_url=service.url, headers={"Authorization": f"Bearer {KEY}"}, timeout=600)
            before = memory_kib(service.api.pid)
            start_s = time.perf_counter()
            with open(path, "rb") as f:
                response = client.post("/v1/scenes", files={"file": (path.name, f)})
            seconds = time.perf_counter() - start_s
            after = memory_kib(service.api.pid)
            return {"file_mb": path.stat().st_size / 2**20, "status": response.status_code, "seconds": seconds,
                    "rss_before_mib": before["VmRSS"] / 1024, "rss_after_mib": after["VmRSS"] / 1024,
                    "peak_before_mib": before["VmHWM"] / 1024, "peak_after_mib": after["VmHWM"] / 1024}  # fmt: skip
        finally:
            service.stop()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cells", type=int, default=16, help="cells per job (even)")
    parser.add_argument("--upload-mb", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=3, help="runs per configuration; the fastest counts")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    result = {
        "renderer": renderer_info().renderer,
        "cells": args.cells,
        "resolution": RESOLUTION,
        "repeats": args.repeats,
    }
    result.update(interleaved(args.cells, args.repeats))
    result["upload"] = upload_memory(args.upload_mb)
    if args.json:
        print(json.dumps(result, indent=1))
        return
    one = result["service_1_worker"]["wall_s"]
    print(
        f"renderer: {result['renderer']}; {args.cells} bunny cells at {RESOLUTION}; fastest of {args.repeats} runs each"
    )
    print("\n| run | wall s | cell seconds (sum) | vs in-process |\n|---|---|---|---|")
    print(
        f"| in one process, serial | {result['in_process_s']:.2f} (runs: {', '.join(f'{w:.1f}' for w in result['in_process_runs_s'])}) | | 1.00 |"
    )
    for name in ("service_1_worker", "service_2_workers", "service_2_workers_1_thread_each"):
        run = result[name]
        print(
            f"| {name.replace('_', ' ')} | {run['wall_s']:.2f} (runs: {', '.join(f'{w:.1f}' for w in run['walls_s'])}) | {run['cell_seconds_sum']:.2f} | {run['wall_s'] / result['in_process_s']:.2f} |"
        )
    print(f"\noverhead (1 worker vs in-process): {100 * (one / result['in_process_s'] - 1):+.1f}%")
    print(
        f"scaling 1 -> 2 workers: {one / result['service_2_workers']['wall_s']:.2f}x "
        f"({one / result['service_2_workers_1_thread_each']['wall_s']:.2f}x with LP_NUM_THREADS=1 in the two workers); "
        f"per round: {', '.join(f'{r:.2f}x' for r in result['scaling_per_round'])}"
    )
    u = result["upload"]
    print(
        f"\nupload of {u['file_mb']:.0f} MB (HTTP {u['status']}, {u['seconds']:.1f} s): API resident {u['rss_before_mib']:.0f} -> {u['rss_after_mib']:.0f} MiB, "
        f"peak {u['peak_before_mib']:.0f} -> {u['peak_after_mib']:.0f} MiB"
    )


if __name__ == "__main__":
    main()
