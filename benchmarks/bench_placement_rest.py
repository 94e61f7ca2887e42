"""Issue 26's "done when", end to end as a user runs it: a placement job over REST, walked by ``farfield walkthrough``.

Usage: ``.venv/bin/python benchmarks/bench_placement_rest.py [--scene downtown|city] [--factor 1.0] [--views 200]
[--workers 1] [--keep DIR] [--json OUT]``

1. The scene of ``benchmarks/bench_placement.py`` (``downtown_scene`` by default, or the dense
   ``city_scene(False, 49, 64)``) is written as a GLB, and t_max is that benchmark's: ``--factor``
   x half the worst view's time with no impostor by the builtin llvmpipe cost model at 128 px.
2. A fresh service (``farfield up``'s processes: the embedded redis-server, uvicorn, ``--workers``
   celery workers, SQLite, a blob folder, in a home of its own) is started.
3. ``farfield submit SCENE.glb --placement --view-space ... --frame-ms T_MAX --cost-model llvmpipe
   --resolution 128 --vdi-deg 45 --cpv-size S --no-evaluate --wait --download DIR --json``, the
   command line a user types (the CLI as a subprocess, talking to the service over HTTP).
4. ``GET /v1/jobs/{id}/placement`` for the memory the database ships.
5. ``farfield walkthrough DIR SCENE.glb --random VIEWS --seed 0 --json``: the reference runtime
   against plain geometry on random views (positions uniform in the view space, directions uniform).

It prints the commands, the job's phases and the walkthrough's summary: share of views within
t_max (the goal: >= 99 %), p99 / max frame time of runtime and plain geometry, hole pixels against
the full scene (the goal: 0), colour error, memory and impostors.  Frame times are measured on this
machine's renderer (llvmpipe on a CPU machine), so nothing else should run beside it.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_placement import LLVMPIPE_MODEL, _renderer, _worst_view, city_scene, downtown_scene  # noqa: E402
from bench_placement_service import KEY, start, write_glb  # noqa: E402

FARFIELD = Path(sys.executable).with_name("farfield")
RESOLUTION = 128


def _cli(args: list[str], env: dict) -> dict:
    """One ``farfield`` command with ``--json``; its JSON (the command is echoed first)."""
    print("$ farfield " + " ".join(args), flush=True)
    started = time.perf_counter()
    done = subprocess.run([str(FARFIELD), *args, "--json"], env=env, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"farfield {args[0]} exited {done.returncode}: {done.stderr.strip()[-2000:]}")
    print(f"   # {time.perf_counter() - started:.1f} s", flush=True)
    return json.loads(done.stdout)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", choices=("downtown", "city"), default="downtown")
    parser.add_argument(
        "--factor", type=float, default=1.0, help="t_max as this multiple of half the worst view's time"
    )
    parser.add_argument(
        "--cpv-divisions",
        type=int,
        default=None,
        help="CPV size = the view space's longest side / this [downtown 8, city 4]",
    )
    parser.add_argument("--views", type=int, default=200, help="random views walked")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--keep", default=None, help="keep the GLB and the downloaded database here")
    parser.add_argument("--json", default=None, help="write the results here")
    args = parser.parse_args()

    scene, lo, hi = downtown_scene(False) if args.scene == "downtown" else city_scene(False, 49, 64)
    divisions = args.cpv_divisions or (8 if args.scene == "downtown" else 4)
    worst = _worst_view(scene, lo, hi, LLVMPIPE_MODEL, RESOLUTION)
    t_max = args.factor * 0.5 * worst
    cpv = float(np.max(hi - lo)) / divisions
    print(
        f"# {args.scene}: {scene.object_count} objects, {scene.triangle_count:,} triangles; EGL {_renderer()}; {os.cpu_count()} CPUs"
    )
    print(
        f"# worst view by the builtin llvmpipe model {worst:.4g} ms; t_max {t_max:.4g} ms; CPV size {cpv:.4g}; {args.workers} worker(s)"
    )
    with tempfile.TemporaryDirectory(prefix="farfield-bench-rest-") as tmp:
        out = Path(args.keep or tmp)
        out.mkdir(parents=True, exist_ok=True)
        glb = write_glb(scene, out / f"{args.scene}.glb")
        database = out / f"{args.scene}-placed"
        service = start(Path(tmp) / "home", args.workers)
        try:
            env = {**os.environ, "FARFIELD_URL": service.url, "FARFIELD_API_KEY": KEY}
            space = ",".join(f"{x:g}" for x in (*lo, *hi))
            job = _cli(["submit", str(glb), "--placement", "--view-space", space, "--frame-ms", f"{t_max:.6g}", "--cost-model", "llvmpipe",
                        "--resolution", str(RESOLUTION), "--vdi-deg", "45", "--cpv-size", f"{cpv:g}", "--no-evaluate",
                        "--wait", "--download", str(database)], env)  # fmt: skip
            client = httpx.Client(base_url=service.url, headers={"Authorization": f"Bearer {KEY}"}, timeout=600)
            record = client.get(f"/v1/jobs/{job['id']}").json()
            totals = client.get(f"/v1/jobs/{job['id']}/placement").json()["totals"]
        finally:
            service.stop()
        walk = _cli(["walkthrough", str(database), str(glb), "--random", str(args.views), "--seed", "0"], env)
    s = walk["summary"]
    plain_within = float(np.mean([f["plain_ms"] <= t_max for f in walk["frames"]]))
    result = {
        "scene": args.scene, "t_max_ms": t_max, "worst_ms": worst, "cpv_size": cpv, "workers": args.workers, "job": job["id"],
        "wall_s": record["finished_at"] - record["created_at"], "cells": record["cells_total"], "check_rounds": len((record.get("placement") or {}).get("rounds") or []),
        "impostors": totals["impostors"], "memory_bytes_baked": totals["memory_bytes_baked"], "memory_bytes_estimated": totals["memory_bytes_estimated"],
        "share_within_t_max": s["share_within_t_max"], "plain_share_within_t_max": plain_within,
        "runtime_ms_p99": s["runtime_ms_p99"], "runtime_ms_max": s["runtime_ms_max"], "plain_ms_p99": s["plain_ms_p99"], "plain_ms_max": s["plain_ms_max"],
        "hole_pixels": s["hole_pixels"], "colour_error_mean": s["colour_error_mean"], "share_estimate_within_t_max_solvable": s["share_estimate_within_t_max_solvable"],
        "over_t_max": s["over_t_max"],
    }  # fmt: skip
    mib = result["memory_bytes_baked"] / 2**20
    print(f"job {job['id']}: {result['wall_s']:.1f} s from submission to done, {result['cells']} cells, {result['check_rounds']} check rounds; "
          f"{result['impostors']} impostors, {mib:.1f} MiB shipped (baked)")  # fmt: skip
    print(f"walk of {args.views} random views: {100 * result['share_within_t_max']:.1f} % within t_max (plain geometry {100 * plain_within:.1f} %), "
          f"runtime p99 / max {result['runtime_ms_p99']:.2f} / {result['runtime_ms_max']:.2f} ms, plain {result['plain_ms_p99']:.2f} / {result['plain_ms_max']:.2f} ms, "
          f"hole pixels {result['hole_pixels']}, colour error {result['colour_error_mean']:.3f}, "
          f"estimate within t_max on {100 * result['share_estimate_within_t_max_solvable']:.1f} % of solvable views")  # fmt: skip
    for f in result["over_t_max"]:
        print(
            f"   over t_max: view {f['frame']}: {f['measured']:.3g} ms, estimate {f['estimate']:.3g} ({f['status']}, cpv {f['cpv']})"
        )
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
