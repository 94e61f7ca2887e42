"""Planning time of the frame-time placement (issue 57 item 5), this checkout beside an older one, in one run.

Usage: ``.venv/bin/python benchmarks/bench_planning_scale.py [--against DIR] [--scenes helmet,city] [--json OUT]``

Scenes (each planned in a fresh process, so its peak memory is its own):

* ``helmet``: ``farfield place DamagedHelmet.glb --view-space -10,0,-10,10,0,10 --primitives 1000``
  (the shared scene, 15,452 triangles cut into 256 clusters; 512 px, 45°, the CLI's defaults);
* ``city``: ``benchmarks/bench_placement.py``'s city test 1 (``procedural.city(900, seed=0,
  detail=16)``, 75,674 triangles; a 225 × 10 × 225 view space above its roofs; primitives, t_max
  half the worst view's; 256 px; CPVs of a side / 8; shafts and boxes).

``--fanout PARTS``: plan each scene three times in one child process, beside one ``farfield up``
(embedded Redis, one real render worker, SQLite, a blob directory): in one process as
``farfield place`` does; with the candidate step cut into PARTS node ranges that only this process
plans (a placement job's planning task on a single worker); and with the parts shared between this
process and the service's worker through the job's protocol (Redis claims, ``plan_candidate_part``
tasks, parts in the blob store: :mod:`farfield.service.placement.candidate_fanout`), i.e. two
workers' worth of processes.  The table gives each row's seconds and whether the placement is the
one-process placement byte for byte.

``--city-blocks N --city-detail D`` (with ``--scenes city``): the city ``procedural.city(N, seed=0,
detail=D)`` (900 and 16: the 75,674-triangle city above; 3600 and 32: 1,116,722 triangles in 3,601
objects) with the same view space rule.

``--against DIR``: also plan each scene with the farfield package in DIR (e.g. ``git archive`` of an
older commit unpacked there), imported in place of this one; the table puts the two side by side
and says whether the placements are the same (their JSON, byte for byte).  Columns: seconds of each
planner step and in all, the planning process's CPU seconds in all and per step, candidates,
impostors, estimated memory, peak resident memory of the process.  ``--city-blocks 4900
--city-detail 140``: 11,466,230 triangles in 4,901 objects (Vienna's size, issue 57).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
SHARED = HERE.parent.parent / "shared" / "scenes"


def plan(scene_name: str, fanout: int = 0, blocks: int = 900, detail: int = 16) -> list[dict]:
    """Plan ``scene_name`` with whichever farfield this process imports; rows of the table (three
    with ``fanout`` parts: one process, parts planned here alone, parts shared with a worker)."""
    import resource

    import numpy as np

    from farfield.core import procedural
    from farfield.core.exchange import load_scene
    from farfield.core.placement.cost_model import primitive_model
    from farfield.core.placement.hierarchy import Elements, Hierarchy
    from farfield.core.placement.planner import PlacementSettings, place
    from farfield.core.placement.view_space import problem_view_space

    model = primitive_model()
    if scene_name == "helmet":
        scene = load_scene(str(SHARED / "damaged_helmet" / "DamagedHelmet.glb"))
        lo, hi = np.array([-10.0, 0.0, -10.0]), np.array([10.0, 0.0, 10.0])
        settings = PlacementSettings(t_max=1000.0, model=model, options={"resolution": 512, "fov_deg": 45.0})
    elif scene_name == "city":
        scene = procedural.city(blocks, seed=0, detail=detail)
        c, top, half = (
            0.5 * (scene.bounds[0] + scene.bounds[1]),
            float(scene.bounds[1][1]),
            0.1875 * float(scene.extents[0]),
        )
        lo, hi = np.array([c[0] - half, top + 10.0, c[2] - half]), np.array([c[0] + half, top + 20.0, c[2] + half])
        cpv = float(np.max(hi - lo)) / 8.0
        elements = Elements.of(scene)
        pv = problem_view_space(
            elements, Hierarchy.build(elements), lo, hi, model, 1e-9, math.radians(45.0), 256, cpv, 11.25
        )
        settings = PlacementSettings(
            t_max=0.5 * float(pv.time.max()), model=model, options={"resolution": 256}, cpv_size=cpv, cells="both"
        )
    else:
        raise SystemExit(f"unknown scene {scene_name!r}")
    cpu_steps = _count_cpu_per_step()
    hooks = [("one process", None)]
    service = None
    if fanout:
        service, fanned = _fanned(fanout)
        hooks += fanned
    rows = []
    try:
        for label, hook in hooks:
            cpu_steps.clear()
            started, cpu = time.perf_counter(), time.process_time()
            result = place(scene, lo, hi, settings, **({"candidates": hook} if hook else {}))
            wall, cpu = time.perf_counter() - started, time.process_time() - cpu
            s = result.summary
            digest = hashlib.sha256(json.dumps(result.to_dict(), sort_keys=True).encode()).hexdigest()[:16]
            rows.append({
                "scene": scene_name, "planning": label, "triangles": scene.triangle_count, "t_max": settings.t_max, "wall_s": wall, "cpu_s": cpu,
                "cpu_seconds": {k: round(v, 2) for k, v in cpu_steps.items()},
                "seconds": {k: round(v, 2) for k, v in result.seconds.items()}, "cpvs": s["cpvs"], "candidates": s["candidates"],
                "impostors": s["impostors"], "memory_mib": s["memory_bytes"] / 2**20, "unsolved": s["cpvs_unsolved"],
                "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, "placement_sha256": digest,
                "load": round(os.getloadavg()[0], 1),
            })  # fmt: skip
    finally:
        if service is not None:
            service.stop()
    return rows


def _count_cpu_per_step() -> dict:
    """This process's CPU seconds per planner step (``place``'s StageClock stages), filled in as
    they run: the wall seconds of a step on a shared machine are the load's as much as the step's."""
    from contextlib import contextmanager

    from farfield.core import stage_clock

    totals: dict = {}
    timed = stage_clock.StageClock.__call__

    @contextmanager
    def call(self, stage):
        start = time.process_time()
        try:
            with timed(self, stage):
                yield
        finally:
            totals[stage] = totals.get(stage, 0.0) + time.process_time() - start

    stage_clock.StageClock.__call__ = call
    return totals


def _fanned(parts: int):
    """A running ``farfield up`` with one worker, and two ``candidates`` hooks of ``place``: the
    parts planned by this process alone, and shared with the service's worker."""
    import redis
    from celery import Celery

    sys.path.insert(0, str(HERE.parent / "tests"))
    from service_harness import start_service

    from farfield.core.placement.candidate_parts import node_ranges
    from farfield.service.blobs import blob_store
    from farfield.service.placement.candidate_fanout import _fan_out
    from farfield.service.settings import Settings
    from farfield.workers.tasks import PLAN_CANDIDATE_PART

    home = Path(tempfile.mkdtemp(prefix="farfield-bench-fanout-"))
    service = start_service(home, FARFIELD_WORKERS="1")
    blobs = blob_store(Settings.from_env(service.env))
    claims = redis.Redis.from_url(service.broker)
    app = Celery("farfield-bench", broker=service.broker)

    def hook(send):
        def candidates(inputs, progress):
            prefix = f"jobs/bench/candidate-parts/{time.monotonic_ns()}"
            return _fan_out(blobs, claims, send, prefix, inputs, node_ranges(inputs, parts), progress)

        return candidates

    alone = hook(lambda *_: None)
    shared = hook(lambda prefix, k, a, b: app.send_task(PLAN_CANDIDATE_PART, args=[prefix, k, a, b], queue="render"))
    return service, [
        (f"{parts} parts, this process alone (1 worker)", alone),
        (f"{parts} parts, shared with 1 worker (2 workers)", shared),
    ]


def run_in(package: Path | None, scene_name: str, extra: tuple = ()) -> list[dict]:
    """:func:`plan` in a fresh process importing farfield from ``package`` (None: this checkout)."""
    env = dict(os.environ)
    with tempfile.TemporaryDirectory(prefix="farfield-against-") as tmp:
        if package is not None:
            (Path(tmp) / "farfield").symlink_to(package.resolve(), target_is_directory=True)
            env["PYTHONPATH"] = tmp + os.pathsep + env.get("PYTHONPATH", "")  # before the editable install
        out = subprocess.run(
            [sys.executable, __file__, "--one", scene_name, *extra],
            env=env,
            capture_output=True,
            text=True,
            check=False,
        )
    if out.returncode != 0 or not out.stdout.strip():
        raise SystemExit(f"planning {scene_name} failed (exit {out.returncode}):\n{out.stderr[-3000:]}")
    found = json.loads(out.stdout.strip().splitlines()[-1])
    return found if isinstance(found, list) else [found]  # an older checkout's plan gives one row


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--against", type=Path, default=None, help="an older farfield package to plan with too")
    parser.add_argument("--scenes", default="helmet,city")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--fanout", type=int, default=0, help="also plan in this many parts, alone and with a worker")
    parser.add_argument("--city-blocks", type=int, default=900)
    parser.add_argument("--city-detail", type=int, default=16)
    parser.add_argument("--one", default=None, help=argparse.SUPPRESS)  # a child process: one scene, a JSON line
    args = parser.parse_args(argv)
    if args.one:
        print(json.dumps(plan(args.one, args.fanout, args.city_blocks, args.city_detail)))
        return 0
    rows = []
    for name in filter(None, args.scenes.split(",")):
        for label, package in (("this", None), ("older", args.against)):
            if label == "older" and package is None:
                continue
            city = ("--city-blocks", str(args.city_blocks), "--city-detail", str(args.city_detail))
            # the older package plans the same scene, in one process only (it may predate the fan-out)
            extra = ("--fanout", str(args.fanout), *city) if label == "this" else city
            for found in run_in(package, name, extra):
                row = {"version": label, **found}
                rows.append(row)
                print(json.dumps(row), flush=True)
    print(f"\nload average at the end: {os.getloadavg()[0]:.1f} (this machine: {os.cpu_count()} CPUs)")
    print(
        "\n| scene | version, planning | plan s (hierarchy / problem views / candidates / greedy) | CPU s of this process (the same steps) | CPVs | candidates | impostors | memory MiB (est.) | peak RSS MiB | placement |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        s = r["seconds"]
        steps = " / ".join(f"{s.get(k, 0.0):.1f}" for k in ("hierarchy", "problem views", "candidates", "greedy"))
        c = r.get("cpu_seconds", {})
        cpu_steps = " / ".join(
            f"{c.get(k, math.nan):.1f}" for k in ("hierarchy", "problem views", "candidates", "greedy")
        )
        same = next(
            (o["placement_sha256"] == r["placement_sha256"] for o in rows if o["scene"] == r["scene"] and o is not r),
            None,
        )
        print(f"| {r['scene']} ({r['triangles']:,} triangles) | {r['version']}, {r.get('planning', 'one process')} | {r['wall_s']:.1f} ({steps}) | {r.get('cpu_s', float('nan')):.1f} ({cpu_steps}) | {r['cpvs']:,} | {r['candidates']:,} | "
              f"{r['impostors']} | {r['memory_mib']:.2f} | {r['peak_rss_mib']:.0f} | {r['placement_sha256']}{'' if same is None else (' (same)' if same else ' (differs)')} |")  # fmt: skip
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
