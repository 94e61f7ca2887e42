"""A primitive-budget placement (seed 004) as a service job against the same placement in one process,
side by side in one run.

Usage: ``.venv/bin/python benchmarks/bench_primitive_job.py [--buildings 64] [--share 0.5] [--resolution 128] [--json]``

1. **In one process**: ``place_primitives`` and the check of ``--check-views`` random views, then
   every image's LDI baked and written (``write_image_database``), after one warm-up bake (EGL
   context, shaders, numba kernels), as ``farfield place --bake`` does.
2. **Through the service** (``farfield up``'s processes: embedded redis-server, uvicorn, Celery
   workers, SQLite, the blob folder), with 1 and with 2 workers: the same request as a placement job
   (``"algorithm": "primitive-budget"``), from its creation to done (the job's own timestamps),
   after a warm-up job on another budget.  Then the same request again: every image found, none
   baked.
3. **Equality**: the job's grid against the one made in this process (grid points, images, their
   cells), and each image's LDI payload (``payload.bin``, its samples) and pages byte for byte.

The scene is the procedural city of ``benchmarks/bench_primitive_budget.py`` (64 buildings, detail 8)
and its view space, a box at street level over the city's middle, written as a GLB that both sides
load.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import os
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from scenes import write_scene  # noqa: E402

from farfield.core import procedural  # noqa: E402
from farfield.core.exchange import load_scene  # noqa: E402
from farfield.core.placement.image_database import bake_image, image_entries, write_image_database  # noqa: E402
from farfield.core.placement.solution_grid import BudgetSettings, check_views, place_primitives  # noqa: E402
from farfield.core.render.context import renderer_info  # noqa: E402
from farfield.service.settings import Settings  # noqa: E402
from farfield.service.supervisor import Service  # noqa: E402

KEY = "ff_bench_0123456789abcdef"


def view_space(scene) -> tuple[list[float], list[float]]:
    lo, hi = scene.bounds
    a, b = 0.75 * lo + 0.25 * hi, 0.25 * lo + 0.75 * hi
    return [float(a[0]), 3.0, float(a[2])], [float(b[0]), 7.0, float(b[2])]


def request(scene, share: float, max_level: int, check: int) -> dict:
    lo, hi = view_space(scene)
    return {"view_space": {"lo": lo, "hi": hi}, "budget": {"primitives": round(share * scene.triangle_count)}, "algorithm": "primitive-budget",
            "max_level": max_level, "check_views": check}  # fmt: skip


def in_process(scene, req: dict, resolution: int, out: Path) -> dict:
    settings = BudgetSettings(primitives=req["budget"]["primitives"], max_level=req["max_level"])
    warm = place_primitives(scene, req["view_space"]["lo"], req["view_space"]["hi"], settings)
    bake_image(scene, image_entries(warm, resolution)[0], warm.cells)  # warm: EGL context, shaders, numba
    start = time.perf_counter()
    placement = place_primitives(scene, req["view_space"]["lo"], req["view_space"]["hi"], settings)
    checked = check_views(placement, req["check_views"])
    planned = time.perf_counter()
    write_image_database(out, scene, placement, resolution)
    end = time.perf_counter()
    return {"plan_s": planned - start, "bake_s": end - planned, "wall_s": end - start, "images": placement.images, "within_p": checked["within_p"],
            "grid": placement.to_dict()}  # fmt: skip


def through_service(path: Path, req: dict, warm_req: dict, resolution: int, workers: int, keep: Path | None) -> dict:
    with tempfile.TemporaryDirectory() as home:
        os.environ["FARFIELD_ADMIN_KEY"] = KEY
        settings = Settings.from_env({"FARFIELD_HOME": home, "FARFIELD_PORT": "0", "FARFIELD_ADMIN_KEY": KEY})
        service = Service(settings, workers=workers).start()
        try:
            client = httpx.Client(base_url=service.url, headers={"Authorization": f"Bearer {KEY}"}, timeout=600)
            with open(path, "rb") as f:
                scene_id = client.post("/v1/scenes", files={"file": (path.name, f)}).json()["id"]

            def run(body: dict) -> dict:
                made = client.post("/v1/jobs", json={"scene_id": scene_id, "resolution": resolution, "placement": body})
                assert made.status_code == 201, made.text
                while (job := client.get(f"/v1/jobs/{made.json()['id']}").json())["state"] not in (
                    "done",
                    "failed",
                    "cancelled",
                ):
                    time.sleep(0.5)
                assert job["state"] == "done", (job["error"], job["errors"][:3])
                return job

            run(warm_req)  # warm every worker: EGL, shaders, the scene parsed
            job = run(req)
            again = run(req)
            archive = zipfile.ZipFile(io.BytesIO(client.get(f"/v1/jobs/{job['id']}/database.zip").content))
            if keep is not None:
                archive.extractall(keep / f"job-{workers}-workers")
            index = json.loads(archive.read("index.json"))
            files = {
                n: hashlib.sha256(archive.read(n)).hexdigest() for n in archive.namelist() if n.startswith("cells/")
            }
            return {
                "wall_s": job["finished_at"] - job["created_at"], "cells": job["cells_total"], "cell_seconds_sum": job["seconds"]["cells_total"],
                "baked": sum(bool(c["stats"]["baked"]) for c in job["cells"]), "again_wall_s": again["finished_at"] - again["created_at"],
                "again_baked": sum(bool(c["stats"]["baked"]) for c in again["cells"]), "within_p": job["placement"]["summary"]["check"]["within_p"],
                "index": index, "files": files,
            }  # fmt: skip
        finally:
            service.stop()


def equal_bundles(local: Path, job: dict) -> tuple[int, int]:
    """(images whose payload and pages are byte-identical to the in-process bundle, images)."""
    same = 0
    for name, folder in job["index"]["bundles"].items():
        mine = local / "images" / name
        theirs = {n.split("/", 2)[2]: h for n, h in job["files"].items() if n.startswith(folder)}
        ours = {
            p.name: hashlib.sha256(p.read_bytes()).hexdigest()
            for p in mine.iterdir()
            if p.name != "manifest.json" and p.name != "impostor.glb"
        }
        same += all(theirs.get(n) == h for n, h in ours.items())
    return same, len(job["index"]["bundles"])


def same_grid(grid: dict, index: dict) -> bool:
    def strip(points):
        return [{k: p[k] for k in ("position", "level", "radius", "breaks", "image", "images")} for p in points]

    return strip(grid["points"]) == strip(index["points"]) and grid["cells"] == index["cells"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--buildings", type=int, default=64)
    parser.add_argument("--detail", type=int, default=8)
    parser.add_argument("--share", type=float, default=0.5, help="P as a share of the model")
    parser.add_argument("--max-level", type=int, default=2)
    parser.add_argument("--resolution", type=int, default=128, help="each LDI's resolution")
    parser.add_argument("--check-views", type=int, default=2000)
    parser.add_argument("--workers", default="1,2", help="service configurations: workers, comma-separated")
    parser.add_argument("--keep", default=None, help="keep the databases under this folder")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    scene = procedural.city(args.buildings, seed=1, detail=args.detail)
    req = request(scene, args.share, args.max_level, args.check_views)
    warm_req = request(scene, min(1.0, args.share + 0.1), args.max_level, 0)
    keep = Path(args.keep) if args.keep else None
    with tempfile.TemporaryDirectory() as tmp:
        path = write_scene(scene, Path(tmp), "glb", "city")
        scene = load_scene(path)  # as the service loads it (float32 positions in the GLB)
        local = (keep or Path(tmp)) / "in-process"
        result = {
            "renderer": renderer_info().renderer,
            "triangles": scene.triangle_count,
            "request": req,
            "resolution": args.resolution,
        }
        result["in_process"] = mine = in_process(scene, req, args.resolution, local)
        for workers in (int(w) for w in args.workers.split(",")):
            run = through_service(path, req, warm_req, args.resolution, workers, keep)
            run["same_grid"] = same_grid(mine["grid"], run["index"])
            run["identical_bundles"], run["bundles"] = equal_bundles(local, run)
            del run["index"], run["files"]
            result[f"service_{workers}"] = run
    del mine["grid"]
    if args.json:
        print(json.dumps(result, indent=1))
        return
    p = req["budget"]["primitives"]
    print(f"renderer: {result['renderer']}; city of {result['triangles']:,} triangles, P = {p:,} ({args.share:.0%}), max level {args.max_level}, "
          f"LDIs at {args.resolution} px, {mine['images']} images")  # fmt: skip
    print(
        "\n| run | wall s | plan s | bake s (cells' sum) | images baked | within P | same grid | identical LDIs | again: wall s, baked |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    print(
        f"| in one process | {mine['wall_s']:.1f} | {mine['plan_s']:.1f} | {mine['bake_s']:.1f} | {mine['images']} | {mine['within_p']:.0%} | | | |"
    )
    for key in [k for k in result if k.startswith("service_")]:
        r = result[key]
        print(f"| service, {key.split('_')[1]} worker(s) | {r['wall_s']:.1f} | | {r['cell_seconds_sum']:.1f} | {r['baked']} of {r['cells']} | {r['within_p']:.0%} | "
              f"{'yes' if r['same_grid'] else 'NO'} | {r['identical_bundles']} of {r['bundles']} | {r['again_wall_s']:.1f}, {r['again_baked']} |")  # fmt: skip
    one = result.get("service_1")
    if one:
        print(f"\nservice (1 worker) against one process: {one['wall_s'] / mine['wall_s']:.2f}x")
    two = result.get("service_2")
    if one and two:
        print(f"1 -> 2 workers: {one['wall_s'] / two['wall_s']:.2f}x")


if __name__ == "__main__":
    main()
