"""Listing scenes after a 10^5-object upload: time, bytes and the API process's memory per request.

Usage: ``.venv/bin/python benchmarks/bench_listing.py [--nodes N] [--repeats R] [--json]``

Issue 24 found ``GET /v1/scenes`` returning every object of every scene: 60.6 MB in 3.75 s after
one 10^5-node upload, the API process growing from 493 to 892 MB during the request, and
``GET /v1/scenes/{id}`` 18.9 MB.  This starts the real API process (``farfield up``'s uvicorn,
SQLite, blob directory; no workers: nothing is baked) with the scene limits raised to admit the
upload, uploads a GLB of N instanced one-triangle nodes (``tests/scenes.py``), then requests each
route R times and prints, per route, the slowest and fastest time, the body size, and the API
process's resident memory (psutil) before the first and after the last request, with its peak
(VmHWM) after.  Run against an older checkout (its package first on PYTHONPATH) for the "before":
routes it lacks show as HTTP 404.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import httpx
import psutil

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from scenes import instanced_nodes_glb  # noqa: E402

from farfield.service.settings import Settings  # noqa: E402
from farfield.service.supervisor import Service  # noqa: E402

KEY = "ff_bench_0123456789abcdef"


def peak_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def measure(client: httpx.Client, pid: int, path: str, repeats: int) -> dict:
    process = psutil.Process(pid)
    before = process.memory_info().rss / 2**20
    seconds, size, status = [], 0, 0
    for _ in range(repeats):
        start = time.perf_counter()
        response = client.get(path)
        seconds.append(time.perf_counter() - start)
        size, status = len(response.content), response.status_code
    return {"path": path, "status": status, "bytes": size, "seconds_max": max(seconds), "seconds_min": min(seconds),
            "rss_before_mib": before, "rss_after_mib": process.memory_info().rss / 2**20, "peak_after_mib": peak_mib(pid),
            "total_count": response.headers.get("X-Total-Count")}  # fmt: skip


def run(nodes: int, repeats: int) -> dict:
    limits = {
        "FARFIELD_MAX_SCENE_NODES": str(2 * nodes),
        "FARFIELD_MAX_SCENE_PRIMITIVES": str(2 * nodes),
        "FARFIELD_MAX_UPLOAD_MB": "100",
    }
    with tempfile.TemporaryDirectory() as home:
        os.environ.update({"FARFIELD_ADMIN_KEY": KEY, **limits})
        settings = Settings.from_env(
            {"FARFIELD_HOME": str(home), "FARFIELD_PORT": "0", "FARFIELD_ADMIN_KEY": KEY, **limits}
        )
        service = Service(settings, workers=0).start()
        try:
            client = httpx.Client(base_url=service.url, headers={"Authorization": f"Bearer {KEY}"}, timeout=600)
            glb = instanced_nodes_glb(nodes)
            api = psutil.Process(service.api.pid)
            rss_idle = api.memory_info().rss / 2**20
            start = time.perf_counter()
            response = client.post("/v1/scenes", files={"file": ("many.glb", glb)})
            upload_s = time.perf_counter() - start
            response.raise_for_status()
            scene = response.json()
            result = {"nodes": nodes, "glb_mb": len(glb) / 2**20, "upload_s": upload_s, "upload_response_bytes": len(response.content),
                      "rss_idle_mib": rss_idle, "rss_after_upload_mib": api.memory_info().rss / 2**20,
                      "peak_after_upload_mib": peak_mib(service.api.pid), "routes": []}  # fmt: skip
            for path in ("/v1/scenes", f"/v1/scenes/{scene['id']}", f"/v1/scenes/{scene['id']}/objects?limit=1000",
                         f"/v1/scenes/{scene['id']}/objects?limit=1000&offset={max(0, nodes - 1000)}"):  # fmt: skip
                result["routes"].append(measure(client, service.api.pid, path, repeats))
            return result
        finally:
            service.stop()
            for name in limits:
                os.environ.pop(name, None)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--nodes", type=int, default=100_000)
    parser.add_argument("--repeats", type=int, default=3, help="requests per route")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    result = run(args.nodes, args.repeats)
    if args.json:
        print(json.dumps(result, indent=1))
        return
    print(f"{result['nodes']:,} nodes, a {result['glb_mb']:.1f} MB GLB: upload {result['upload_s']:.1f} s (response {result['upload_response_bytes']:,} bytes); "
          f"API resident {result['rss_idle_mib']:.0f} MiB idle, {result['rss_after_upload_mib']:.0f} MiB after the upload (peak {result['peak_after_upload_mib']:.0f} MiB)")  # fmt: skip
    print(
        f"\n| route ({args.repeats} requests each) | HTTP | body bytes | X-Total-Count | s (slowest / fastest) | API resident MiB before -> after | API peak MiB after |"
    )
    print("|---|---|---|---|---|---|---|")
    for r in result["routes"]:
        path = (
            r["path"].replace(r["path"].split("/")[3].split("?")[0], "{id}") if r["path"].count("/") > 2 else r["path"]
        )
        print(f"| GET {path} | {r['status']} | {r['bytes']:,} | {r['total_count'] or '-'} | {r['seconds_max']:.3f} / {r['seconds_min']:.3f} | "
              f"{r['rss_before_mib']:.0f} -> {r['rss_after_mib']:.0f} | {r['peak_after_mib']:.0f} |")  # fmt: skip


if __name__ == "__main__":
    main()
