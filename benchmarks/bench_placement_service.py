"""A placement job through the real service, timed with 1 and 2 workers (issue 26, Measure: "wall time of planning and of baking with 1 and 2 workers").

Usage: ``.venv/bin/python benchmarks/bench_placement_service.py [--size 49] [--detail 64] [--resolution 128] [--factor 1.0]
[--vdi-deg 45] [--cpv-divisions 4] [--json OUT]``

The scene is the seeded procedural city of ``benchmarks/bench_placement.py`` (``city_scene(False,
size, detail)``: ``farfield.core.procedural.city(size, seed=0, detail=detail)``, its view space a box above
the roofs of its centre), written as a GLB and uploaded as a scene.  The budget is that benchmark's
too: t_max = ``--factor`` x the reference budget, half the worst view's time with no impostor by the
builtin llvmpipe cost model (``LLVMPIPE_MODEL``) at ``--resolution``; the planner's knobs
``--vdi-deg`` and a CPV size of the view space's longest side / ``--cpv-divisions``; layered
impostors at ``--resolution``.

For 1 and then 2 workers, a fresh service (``farfield up``'s processes: embedded redis-server,
uvicorn, celery workers, SQLite, a blob folder; its own home) is started, each worker is warmed with
a small grid job (EGL context, shaders), and the placement job is submitted over REST and polled
every ``--poll`` seconds (0.5: the polling takes no measurable CPU from the workers) until it ends.
Per run: the wall time from the job's creation to its end (the service's own timestamps), the time
spent queued, planning (every ``placing`` phase: the plan and each check round; split into plan and
check by the job's planning record) and baking (``running``; with the cells' own bake seconds, the
longest, and how many cells each worker baked), impostors drawn by some CPV and cells in all, cells
baked (``stats.baked``: not found by their content key), check rounds, and the database's memory
(``GET /v1/jobs/{id}/placement``: baked texture bytes of the impostors a CPV draws and their
estimate, and the baked texture bytes of every impostor the database holds).  Then the same job is
submitted again to the 2-worker service: it should bake nothing (every cell's bundle found).

The service records no per-phase timestamps (the job has ``created_at``, ``started_at`` and
``finished_at``; the planning record says the phase, not since when; a cell has its bake seconds but
no start or end time), so the phases' durations are **measured by polling**: each change of state
(or of planning phase) seen at a poll is placed midway between that poll and the one before, so
each boundary is known to within half a poll interval (0.25 s) and a phase shorter than one
interval may be missed (its time then falls to its neighbours; the ``check_rounds`` column comes
from the job's record and counts every round).  Everything runs on this machine's CPU (llvmpipe).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_placement import LLVMPIPE_MODEL, _renderer, _worst_view, city_scene  # noqa: E402

from farfield.core.scene import Scene  # noqa: E402
from farfield.service.settings import Settings  # noqa: E402
from farfield.service.supervisor import Service  # noqa: E402

KEY = "ff_bench_0123456789abcdef"
ENDED = ("done", "failed", "cancelled")


def write_glb(scene: Scene, path: Path, sides: bool = False) -> Path:
    """``scene`` as a GLB: one node per object, named after it, its base colour as the material's
    factor (the procedural city has neither textures nor vertex colours).  With ``sides`` each
    material's ``doubleSided`` is the object's ``double_sided`` (a built scene's objects are
    double-sided, so the service then reads the scene the in-process benchmarks plan); without it
    (as these benchmarks always wrote it) every material is one-sided, as glTF's default."""
    out = trimesh.Scene()
    for obj in scene.objects:
        material = trimesh.visual.material.PBRMaterial(
            name=f"{obj.name}_material",
            baseColorFactor=np.array(obj.base_color),
            doubleSided=bool(sides and obj.double_sided),
        )
        mesh = trimesh.Trimesh(
            np.array(obj.vertices),
            np.array(obj.faces),
            visual=trimesh.visual.TextureVisuals(material=material),
            process=False,
        )
        out.add_geometry(mesh, geom_name=obj.name, node_name=obj.name)
    path.write_bytes(out.export(file_type="glb"))
    return path


def start(home: Path, workers: int) -> Service:
    os.environ["FARFIELD_ADMIN_KEY"] = KEY
    settings = Settings.from_env({"FARFIELD_HOME": str(home), "FARFIELD_PORT": "0", "FARFIELD_ADMIN_KEY": KEY})
    return Service(settings, workers=workers).start()


def warm(client: httpx.Client, scene_id: str, obj: str, lo, hi, workers: int) -> None:
    """A job of 2 cells per worker, one building's impostors at 64 px from small boxes at the view
    space's centre: each worker's EGL context, shaders and scene cache are made before the timed job
    (its impostors are not the placement's)."""
    c = 0.5 * (np.asarray(lo) + np.asarray(hi))
    cells = [
        {"kind": "box", "lo": (c - 0.5 + [i, 0, 0]).tolist(), "hi": (c + 0.5 + [i, 0, 0]).tolist()}
        for i in range(2 * workers)
    ]
    made = client.post(
        "/v1/jobs",
        json={"scene_id": scene_id, "viewcells": cells, "objects": [obj], "resolution": 64, "evaluate": False},
    )
    assert made.status_code == 201, made.text
    while (job := client.get(f"/v1/jobs/{made.json()['id']}").json())["state"] not in ENDED:
        time.sleep(0.1)
    assert job["state"] == "done", (job["state"], job["errors"])


def phase_of(job: dict) -> str:
    """queued, plan, check (``placing`` by its planning record's phase), bake (``running``) or the end state."""
    if job["state"] == "placing":
        return "check" if (job.get("placement") or {}).get("phase") == "check" else "plan"
    return {"running": "bake"}.get(job["state"], job["state"])


def timed_job(client: httpx.Client, scene_id: str, request: dict, poll: float) -> dict:
    """Submit the placement job, poll it until it ends; its figures (see the module docstring)."""
    made = client.post(
        "/v1/jobs",
        json={
            "scene_id": scene_id,
            "technique": "layered",
            "resolution": request.pop("resolution"),
            "placement": request,
        },
    )
    assert made.status_code == 201, made.text
    job = made.json()
    seconds = dict.fromkeys(("queued", "plan", "check", "bake"), 0.0)
    phase, since, last_poll, changes = "queued", job["created_at"], job["created_at"], []
    while True:
        time.sleep(poll)
        job = client.get(f"/v1/jobs/{job['id']}").json()
        polled = time.time()
        seen = phase_of(job)
        if seen != phase:
            at = job["finished_at"] if job["state"] in ENDED else 0.5 * (last_poll + polled)
            seconds[phase] = seconds.get(phase, 0.0) + max(at - since, 0.0)
            changes.append((round(at - job["created_at"], 2), seen))
            phase, since = seen, at
        last_poll = polled
        if job["state"] in ENDED:
            break
    assert job["state"] == "done", (job["state"], job["error"], job["errors"])
    full = client.get(f"/v1/jobs/{job['id']}").json()
    database = client.get(f"/v1/jobs/{job['id']}/placement").json()
    totals = database["totals"]
    listed = sum(int(((c.get("figures") or {}).get("baked") or {}).get("texture_bytes", 0)) for c in database["cells"])
    cells = full.get("cells", [])
    baked = sum(1 for c in cells if (c.get("stats") or {}).get("baked"))
    workers = {}
    for c in cells:
        workers[c["worker"]] = workers.get(c["worker"], 0) + 1
    record = job["placement"] or {}
    return {
        "job": job["id"], "wall_s": job["finished_at"] - job["created_at"], "queued_s": seconds["queued"],
        "planning_s": seconds["plan"] + seconds["check"], "plan_s": seconds["plan"], "check_s": seconds["check"], "baking_s": seconds["bake"],
        "phases": changes, "impostors": totals["impostors"], "cells": job["cells_total"], "cells_baked": baked, "check_rounds": len(record.get("rounds") or []),
        "memory_bytes_baked": totals["memory_bytes_baked"], "memory_bytes_estimated": totals["memory_bytes_estimated"], "memory_bytes_database": listed,
        "cpvs": totals["cpvs"], "cpvs_by_status": totals["cpvs_by_status"], "cell_seconds_sum": job["seconds"]["cells_total"],
        "cell_seconds": [c["seconds"] for c in cells], "cells_by_worker": workers,
    }  # fmt: skip


def through_service(glb: Path, obj: str, lo, hi, request: dict, workers: int, poll: float, resubmit: bool) -> dict:
    with tempfile.TemporaryDirectory(prefix="farfield-bench-") as home:
        service = start(Path(home), workers)
        try:
            client = httpx.Client(base_url=service.url, headers={"Authorization": f"Bearer {KEY}"}, timeout=600)
            with open(glb, "rb") as f:
                made = client.post("/v1/scenes", files={"file": (glb.name, f)})
            assert made.status_code == 201, made.text
            scene_id = made.json()["id"]
            warm(client, scene_id, obj, lo, hi, workers)
            run = {"workers": workers, **timed_job(client, scene_id, dict(request), poll)}
            print(f"   # {workers} worker(s): {_row(run)}", flush=True)
            if resubmit:
                again = timed_job(client, scene_id, dict(request), poll)
                run["resubmitted"] = again
                print(
                    f"   # resubmitted: {again['cells_baked']} of {again['cells']} cells baked, {again['wall_s']:.1f} s",
                    flush=True,
                )
            return run
        finally:
            service.stop()


def _row(r: dict) -> str:
    longest = max((s or 0.0 for s in r["cell_seconds"]), default=0.0)
    return (f"wall {r['wall_s']:.1f} s, queued {r['queued_s']:.1f}, planning {r['planning_s']:.1f} (plan {r['plan_s']:.1f} + check {r['check_s']:.1f}), "
            f"baking {r['baking_s']:.1f} (cells {r['cell_seconds_sum']:.1f} s in all, longest {longest:.1f} s; cells by worker {sorted(r['cells_by_worker'].values())}); "
            f"{r['impostors']} impostors drawn, {r['cells_baked']}/{r['cells']} cells baked, {r['check_rounds']} check rounds")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=49, help="buildings of the city (farfield.core.procedural.city)")
    parser.add_argument("--detail", type=int, default=64, help="the city's most quads per building face side")
    parser.add_argument(
        "--resolution", type=int, default=128, help="impostor resolution (and the cost model's view resolution)"
    )
    parser.add_argument(
        "--factor",
        type=float,
        default=1.0,
        help="t_max as this multiple of the reference budget (half the worst view's time)",
    )
    parser.add_argument(
        "--vdi-deg", type=float, default=45.0, help="the planner's smallest view-direction interval, degrees"
    )
    parser.add_argument("--cpv-divisions", type=int, default=4, help="CPV size = the view space's longest side / this")
    parser.add_argument("--poll", type=float, default=0.5, help="seconds between polls of the job")
    parser.add_argument("--json", default=None, help="write the results here")
    args = parser.parse_args()

    scene, lo, hi = city_scene(False, args.size, args.detail)
    model = LLVMPIPE_MODEL
    worst = _worst_view(scene, lo, hi, model, args.resolution)
    t_max = args.factor * 0.5 * worst
    cpv = float(np.max(hi - lo)) / args.cpv_divisions
    request = {
        "view_space": {"lo": lo.tolist(), "hi": hi.tolist()}, "budget": {"frame_ms": t_max, "cost_model": "llvmpipe"},
        "vdi_deg": args.vdi_deg, "cpv_size": cpv, "resolution": args.resolution,
    }  # fmt: skip
    print(
        f"cost model: {model.renderer} ({model.source}); layered impostors at {args.resolution} px; EGL {_renderer()}; {os.cpu_count()} CPUs"
    )
    print(
        f"# city: {scene.object_count} objects, {scene.triangle_count:,} triangles; view space {lo.round(2).tolist()} .. {hi.round(2).tolist()}"
    )
    print(
        f"# worst view {worst:.4g} ms; t_max {t_max:.4g} ms ({args.factor:g} x half of it); CPV size {cpv:.4g}, vdi {args.vdi_deg:g}°; polled every {args.poll:g} s"
    )
    with tempfile.TemporaryDirectory(prefix="farfield-bench-scene-") as tmp:
        glb = write_glb(scene, Path(tmp) / "city.glb")
        building = next(o.name for o in scene.objects if o.name != "ground")
        runs = [
            through_service(glb, building, lo, hi, request, workers, args.poll, resubmit=workers == 2)
            for workers in (1, 2)
        ]
    one, two = runs
    ratio = lambda key: one[key] / two[key] if two[key] > 0 else math.nan  # noqa: E731
    ratios = {key: ratio(key) for key in ("wall_s", "planning_s", "baking_s")}
    again = two["resubmitted"]

    print("\n| workers | wall s | queued s | planning s (plan + check) | baking s | impostors drawn / cells | cells baked | check rounds "
          "| MiB baked (drawn) | MiB estimated (drawn) | MiB baked in all (drawn or not) |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name, r in (("1", one), ("2", two), ("2, resubmitted", again)):
        print(f"| {name} | {r['wall_s']:.1f} | {r['queued_s']:.1f} | {r['planning_s']:.1f} ({r['plan_s']:.1f} + {r['check_s']:.1f}) | {r['baking_s']:.1f} | "
              f"{r['impostors']} / {r['cells']} | {r['cells_baked']} | {r['check_rounds']} | {r['memory_bytes_baked'] / 2**20:.2f} | "
              f"{r['memory_bytes_estimated'] / 2**20:.2f} | {r['memory_bytes_database'] / 2**20:.2f} |")  # fmt: skip
    print(
        f"\n1 -> 2 workers: wall {ratios['wall_s']:.2f}x, planning {ratios['planning_s']:.2f}x, baking {ratios['baking_s']:.2f}x"
    )
    print(
        f"resubmitted: {again['cells_baked']} of {again['cells']} cells baked (every other bundle found by its content key)"
    )
    if args.json:
        result = {
            "renderer": _renderer(), "size": args.size, "detail": args.detail, "resolution": args.resolution, "factor": args.factor, "t_max_ms": t_max,
            "worst_view_ms": worst, "vdi_deg": args.vdi_deg, "cpv_size": cpv, "poll_s": args.poll, "objects": scene.object_count,
            "triangles": scene.triangle_count, "runs": runs, "ratio_1_to_2_workers": ratios,
        }  # fmt: skip
        Path(args.json).write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
