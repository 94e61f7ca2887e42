"""A hostile-input and failure campaign against a real ``farfield up`` (issue 24's, rerun on demand).

Usage: ``.venv/bin/python benchmarks/hostile_campaign.py [--mutations N] [--concurrent N] [--schemathesis N] [--json]``

Starts ``farfield up`` (embedded redis-server, uvicorn, one celery worker, SQLite, blob directory)
in a temporary home and runs, phase by phase:

1. **non-finite / loose numbers**: job bodies with NaN, Infinity, 1e400, strings and booleans where
   numbers belong, out-of-bounds options;
2. **mutated uploads**: seeded byte flips, truncations, insertions and header damage of valid
   glb, gltf, obj, ply and stl files;
3. **hostile names**: path traversal, 300-character, NUL, unicode and extension-less names;
4. **costly requests**: a 16384-resolution job, a 100,000-deep node chain, 200,000 primitives,
   10^5 instanced nodes (refused, and how long the refusal took);
5. **cross-tenant probes**: a second tenant reads, deletes, cancels and downloads the first one's;
6. **concurrent submissions**: N one-cell jobs at once, each must end done with one impostor;
7. **kills**: pool processes SIGKILLed three times, the whole worker once and Redis once under a
   6-cell job, which must end done.

It counts requests, 2xx, 4xx, 5xx and connection errors per phase, and at the end crashes (the API
or supervisor gone), leaks (temporary upload files left, blobs of refused uploads) and lost or
duplicated cells.  Optionally (``--schemathesis N``, needs the ``schemathesis`` command) a
schemathesis run of N examples per operation against the live server's OpenAPI document.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from scenes import city, write_scene  # noqa: E402
from service_harness import ADMIN_KEY, BUNNY, start_service  # noqa: E402

from farfield.service.db import Database  # noqa: E402
from farfield.service.keys import create_key  # noqa: E402


class Tally:
    """Requests of one phase by status class, with the unexpected ones kept."""

    def __init__(self) -> None:
        self.phases: dict[str, Counter] = {}
        self.notes: dict[str, list[str]] = {}

    def record(self, phase: str, response: httpx.Response | None, error: str | None = None) -> None:
        counts = self.phases.setdefault(phase, Counter())
        notes = self.notes.setdefault(phase, [])
        counts["requests"] += 1
        if response is None:
            counts["connection_errors"] += 1
            notes.append(error or "no response")
            return
        counts[f"{response.status_code // 100}xx"] += 1
        if response.status_code >= 500:
            notes.append(
                f"{response.request.method} {response.request.url.path}: {response.status_code} {response.text[:200]}"
            )
        if response.status_code >= 400:
            try:
                body = response.json()
                assert isinstance(body.get("detail"), str) and isinstance(body.get("error"), str)
            except Exception:  # noqa: BLE001 - counted, not raised
                counts["bad_error_bodies"] += 1
                notes.append(f"{response.request.url.path}: error body not {{detail, error}}: {response.text[:120]}")

    def note(self, phase: str, text: str) -> None:
        self.notes.setdefault(phase, []).append(text)
        self.phases.setdefault(phase, Counter())


def send(tally: Tally, phase: str, client: httpx.Client, method: str, path: str, **kwargs) -> httpx.Response | None:
    try:
        response = client.request(method, path, **kwargs)
    except httpx.HTTPError as error:
        tally.record(phase, None, f"{method} {path}: {type(error).__name__}: {error}")
        return None
    tally.record(phase, response)
    return response


def wait_job(client: httpx.Client, job_id: str, timeout: float) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = client.get(f"/v1/jobs/{job_id}").json()
        if job["state"] in ("done", "failed", "cancelled"):
            return job
        time.sleep(0.25)
    return client.get(f"/v1/jobs/{job_id}").json()


# --- phase inputs ------------------------------------------------------------------------------

NON_FINITE = [
    '"resolution": NaN', '"resolution": Infinity', '"resolution": -Infinity', '"resolution": 1e400', '"resolution": "64"',
    '"resolution": true', '"resolution": 1.5', '"resolution": -1', '"resolution": 0', '"resolution": 99999999999999999999',
    '"fov_deg": NaN', '"fov_deg": true', '"fov_deg": "45"', '"fov_deg": 1e400', '"fov_deg": 180', '"objects": [NaN]',
    '"objects": [1]', '"options": {"padding": Infinity}', '"options": {"padding": 1e18}', '"options": {"padding": 1180591620717411303424}',
    '"options": {"grid_cell": 1e18}', '"options": {"grid_cell": "8"}', '"options": {"nope": 1}', '"options": []', '"evaluate": "yes"',
    '"technique": "nope"', '"technique": "envmap", "job_type": "tdm"',
]  # fmt: skip
GRIDS = [
    '{"lo": [0, 0, 0], "hi": [1, 1, 1], "counts": [1e400, 1, 1]}', '{"lo": [0, 0, 0], "hi": [1, 1, 1], "counts": ["1", 1, 1]}',
    '{"lo": [0, 0, 0], "hi": [1, 1, 1], "counts": [true, 1, 1]}', '{"lo": [NaN, 0, 0], "hi": [1, 1, 1], "counts": [1, 1, 1]}',
    '{"lo": [0, 0, 0], "hi": [1, 1, 1], "counts": [100000, 100000, 100000]}', '{"lo": [0, 0, 0], "hi": [1, 1, 1], "counts": [0, 1, 1]}',
    '{"lo": [1, 1, 1], "hi": [0, 0, 0], "counts": [1, 1, 1]}', '{"lo": [0, 0], "hi": [1, 1, 1], "counts": [1, 1, 1]}',
]  # fmt: skip


def mutations(data: bytes, count: int, rng: random.Random) -> list[bytes]:
    out = []
    for n in range(count):
        b = bytearray(data)
        kind = n % 5
        if kind == 0:  # flip bytes
            for _ in range(rng.randint(1, 64)):
                b[rng.randrange(len(b))] = rng.randrange(256)
        elif kind == 1:  # truncate
            b = b[: rng.randrange(1, len(b))]
        elif kind == 2:  # insert junk
            at = rng.randrange(len(b))
            b[at:at] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 512)))
        elif kind == 3:  # damage the header
            for i in range(min(32, len(b))):
                if rng.random() < 0.3:
                    b[i] = rng.randrange(256)
        else:  # replace a number-like run with a huge or non-finite one
            text = bytes(b)
            spots = [m.start() for m in re.finditer(rb"[0-9]+", text[:200_000])]
            if spots:
                at = rng.choice(spots)
                b[at:at] = rng.choice([b"1e400", b"nan", b"-99999999999", b"4294967295"])
        out.append(bytes(b))
    return out


def gltf(nodes: list[dict], scene_nodes: list[int], primitives: int = 1) -> bytes:
    """A glTF with one triangle in an embedded buffer, ``nodes`` and a mesh of ``primitives``."""
    import base64

    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float32).tobytes()
    uri = "data:application/octet-stream;base64," + base64.b64encode(positions).decode()
    document = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": scene_nodes}], "nodes": nodes,
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}} for _ in range(primitives)]}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]}],
        "bufferViews": [{"buffer": 0, "byteLength": len(positions)}], "buffers": [{"byteLength": len(positions), "uri": uri}],
    }  # fmt: skip
    return json.dumps(document).encode()


def run(args) -> dict:
    tally = Tally()
    home = Path(tempfile.mkdtemp(prefix="farfield-campaign-"))
    # Attempts enough that the five kills, which may all land on one cell, do not use its attempts up
    # (a cell that keeps killing its worker is failed after FARFIELD_MAX_ATTEMPTS by design).
    service = start_service(home, FARFIELD_MAX_UPLOAD_MB="64", FARFIELD_MAX_ATTEMPTS="8")
    tmp_before = {p.name for p in Path(tempfile.gettempdir()).glob("farfield-upload-*")} | {
        p.name for p in Path(tempfile.gettempdir()).glob("farfield-ingest-*")
    }
    client = service.client()
    client.timeout = httpx.Timeout(120)
    result: dict = {}
    try:
        files = home / "files"
        files.mkdir()
        small = city(buildings=4)
        valid = {ext: write_scene(small, files, ext).read_bytes() for ext in ("glb", "obj", "ply", "stl")}
        valid["gltf"] = gltf([{"mesh": 0}], [0])
        scene_id = send(
            tally, "setup", client, "POST", "/v1/scenes", files={"file": ("city.glb", valid["glb"])}
        ).json()["id"]
        cell = {"kind": "box", "lo": [50, 1, 50], "hi": [54, 5, 54]}
        base = {"scene_id": scene_id, "resolution": 64, "viewcells": [cell]}

        # 1. non-finite and loose numbers
        for raw in NON_FINITE:
            body = json.dumps(base)[:-1] + ", " + raw + "}"
            send(
                tally,
                "1 non-finite/loose numbers",
                client,
                "POST",
                "/v1/jobs",
                content=body,
                headers={"content-type": "application/json"},
            )
        for raw in GRIDS:
            body = json.dumps({k: v for k, v in base.items() if k != "viewcells"})[:-1] + ', "grid": ' + raw + "}"
            send(
                tally,
                "1 non-finite/loose numbers",
                client,
                "POST",
                "/v1/jobs",
                content=body,
                headers={"content-type": "application/json"},
            )
        accepted = tally.phases["1 non-finite/loose numbers"]["2xx"]
        if accepted:
            tally.note("1 non-finite/loose numbers", f"{accepted} accepted (should be none)")

        # 2. mutated uploads
        rng = random.Random(24)
        blob_root = home / "blobs" / "scenes"
        stored_before = {p.parent.name for p in blob_root.glob("*/*")}
        made = 0
        for ext, data in valid.items():
            for mutated in mutations(data, args.mutations, rng):
                response = send(
                    tally, "2 mutated uploads", client, "POST", "/v1/scenes", files={"file": (f"m.{ext}", mutated)}
                )
                made += response is not None and response.status_code == 201
        stored_after = {p.parent.name for p in blob_root.glob("*/*")}
        if len(stored_after - stored_before) != made:
            tally.note(
                "2 mutated uploads",
                f"leak: {len(stored_after - stored_before)} scene folders for {made} accepted uploads",
            )
        tally.note("2 mutated uploads", f"{made} accepted (still valid files), the rest refused")

        # 3. hostile names
        names = ["../../../../etc/passwd.obj", "..\\..\\boot.ini.obj", "a" * 300 + ".obj", "b" * 242 + ".obj", "nul\x00byte.obj",
                 "ünï cødé ☃.obj", "noextension", ".obj", "....obj", "/abs/path.obj", "x.OBJ", "x.obj.exe", "%2e%2e%2fenc.obj"]  # fmt: skip
        for name in names:
            response = send(
                tally, "3 hostile names", client, "POST", "/v1/scenes", files={"file": (name, valid["obj"])}
            )
            if response is not None and response.status_code == 201:
                key_parts = list(blob_root.glob(f"{response.json()['id']}/*"))
                if not all(p.resolve().is_relative_to(blob_root.resolve()) for p in key_parts):
                    tally.note("3 hostile names", f"escaped the blob folder: {name!r}")

        # 4. costly requests
        costly = {
            "16384 resolution job": ("POST", "/v1/jobs", {"json": {**base, "resolution": 16384}}),
            "100,000-deep node chain": ("POST", "/v1/scenes", {"files": {"file": ("deep.gltf", gltf([{"children": [i + 1]} for i in range(99_999)] + [{"mesh": 0}], [0]))}}),
            "200,000 primitives": ("POST", "/v1/scenes", {"files": {"file": ("prims.gltf", gltf([{"mesh": 0}], [0], primitives=200_000))}}),
            "10^5 instanced nodes": ("POST", "/v1/scenes", {"files": {"file": ("inst.gltf", gltf([{"children": list(range(1, 100_001))}] + [{"mesh": 0}] * 100_000, [0]))}}),
        }  # fmt: skip
        result["costly"] = {}
        for label, (method, path, kwargs) in costly.items():
            start = time.perf_counter()
            response = send(tally, "4 costly requests", client, method, path, **kwargs)
            seconds = time.perf_counter() - start
            status = response.status_code if response is not None else None
            detail = response.json().get("detail", "")[:160] if response is not None and status >= 400 else ""
            result["costly"][label] = {"status": status, "seconds": round(seconds, 2), "detail": detail}
            if status is not None and status < 400:
                tally.note("4 costly requests", f"{label}: accepted ({status})")

        # 5. cross-tenant probes
        other_key, _ = create_key(Database(f"sqlite:///{home / 'farfield.db'}"), "stranger")
        job = client.post("/v1/jobs", json=base).json()
        wait_job(client, job["id"], 120)
        with service.client(key=other_key) as stranger:
            probes = [("GET", f"/v1/scenes/{scene_id}"), ("DELETE", f"/v1/scenes/{scene_id}"), ("GET", f"/v1/jobs/{job['id']}"),
                      ("POST", f"/v1/jobs/{job['id']}/cancel"), ("POST", f"/v1/jobs/{job['id']}/retry"), ("GET", f"/v1/jobs/{job['id']}/database.zip"),
                      ("GET", f"/v1/jobs/{job['id']}/cells/0/bundle.zip"), ("GET", f"/v1/jobs/{job['id']}/cells/0/manifest.json"),
                      ("GET", f"/v1/jobs/{job['id']}/lookup?x=52&y=3&z=52"), ("POST", "/v1/jobs", base)]  # fmt: skip
            for method, path, *body in probes:
                response = send(
                    tally, "5 cross-tenant probes", stranger, method, path, **({"json": body[0]} if body else {})
                )
                if response is not None and response.status_code < 400:
                    tally.note("5 cross-tenant probes", f"LEAK: {method} {path} answered {response.status_code}")
            listed = stranger.get("/v1/scenes").json()
            if listed:
                tally.note("5 cross-tenant probes", f"LEAK: the stranger lists {len(listed)} scenes")

        # 6. concurrent submissions
        def submit(n: int) -> str | None:
            with service.client() as c:
                spec = {
                    **base,
                    "viewcells": [{"kind": "box", "lo": [50 + 0.01 * n, 1, 50], "hi": [54 + 0.01 * n, 5, 54]}],
                }
                response = send(tally, "6 concurrent submissions", c, "POST", "/v1/jobs", json=spec)
                return response.json()["id"] if response is not None and response.status_code == 201 else None

        with concurrent.futures.ThreadPoolExecutor(32) as pool:
            ids = [i for i in pool.map(submit, range(args.concurrent)) if i]
        ends = Counter(wait_job(client, i, 900)["state"] for i in ids)
        result["concurrent"] = {"submitted": args.concurrent, "accepted": len(ids), "ended": dict(ends)}
        if ends.get("done", 0) != len(ids):
            tally.note("6 concurrent submissions", f"LOST: {dict(ends)} of {len(ids)}")

        # 7. kills under a 6-cell job
        bunny = send(
            tally, "7 kills", client, "POST", "/v1/scenes", files={"file": (BUNNY.name, BUNNY.read_bytes())}
        ).json()["id"]
        grid = {"lo": [-0.6, 0.05, -0.05], "hi": [-0.4, 0.15, 0.05], "counts": [3, 2, 1]}
        job_id = send(
            tally, "7 kills", client, "POST", "/v1/jobs", json={"scene_id": bunny, "grid": grid, "resolution": 768}
        ).json()["id"]
        kills = []
        for victim in ("pool", "pool", "pool", "worker", "redis"):
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline:
                cells = client.get(f"/v1/jobs/{job_id}").json()["cells"]
                if any(c["state"] == "running" and c["progress"] > 0 for c in cells) or victim == "redis":
                    break
                time.sleep(0.05)
            pids = {
                "pool": service.worker_pool_children,
                "worker": service.worker_mains,
                "redis": lambda: [service.redis_pid()],
            }[victim]()
            for pid in pids:
                os.kill(pid, signal.SIGKILL)
            kills.append(victim)
            time.sleep(2)
        job = wait_job(client, job_id, 900)
        attempts = [c["attempts"] for c in job["cells"]]
        result["kills"] = {"killed": kills, "state": job["state"], "done": job["counts"]["done"], "attempts": attempts}
        if job["state"] != "done":
            tally.note("7 kills", f"LOST: job {job['state']} {job['counts']} {job['errors'][:2]}")

        # schemathesis, if asked
        if args.schemathesis:
            exe = shutil.which("schemathesis") or str(Path(sys.executable).parent / "schemathesis")
            command = [exe, "run", f"{service.url}/openapi.json", "--header", f"Authorization: Bearer {ADMIN_KEY}", "--max-examples", str(args.schemathesis),
                       "--checks", "all", "--seed", "24", "--exclude-path", "/v1/scenes", "--exclude-method", "DELETE"]  # fmt: skip
            done = subprocess.run(command, capture_output=True, text=True, timeout=1800, check=False)
            tail = done.stdout.strip().splitlines()[-12:]
            result["schemathesis"] = {"returncode": done.returncode, "summary": tail}

        # the end: crashes and leaks
        result["crashes"] = {
            "supervisor_alive": service.process.poll() is None,
            "health": client.get("/v1/health").json(),
        }
        tmp_after = {p.name for p in Path(tempfile.gettempdir()).glob("farfield-upload-*")} | {
            p.name for p in Path(tempfile.gettempdir()).glob("farfield-ingest-*")
        }
        result["leaks"] = {"temporary_upload_files_left": len(tmp_after - tmp_before)}
    finally:
        client.close()
        service.stop()
        shutil.rmtree(home, ignore_errors=True)
    result["phases"] = {phase: dict(counts) for phase, counts in tally.phases.items()}
    result["notes"] = {phase: notes[:20] for phase, notes in tally.notes.items() if notes}
    return result


def table(result: dict) -> str:
    lines = [
        "| phase | requests | 2xx | 4xx | 5xx | connection errors | error bodies not {detail, error} |",
        "|---|---|---|---|---|---|---|",
    ]
    total = Counter()
    for phase, counts in result["phases"].items():
        total.update(counts)
        lines.append(
            f"| {phase} | {counts.get('requests', 0)} | {counts.get('2xx', 0)} | {counts.get('4xx', 0)} | {counts.get('5xx', 0)} | {counts.get('connection_errors', 0)} | {counts.get('bad_error_bodies', 0)} |"
        )
    lines.append(
        f"| **all** | {total['requests']} | {total['2xx']} | {total['4xx']} | {total['5xx']} | {total['connection_errors']} | {total['bad_error_bodies']} |"
    )
    lines.append("")
    for label, outcome in result.get("costly", {}).items():
        lines.append(f"- {label}: HTTP {outcome['status']} in {outcome['seconds']} s: {outcome['detail']}")
    if "concurrent" in result:
        lines.append(f"- concurrent: {result['concurrent']}")
    if "kills" in result:
        lines.append(f"- kills: {result['kills']}")
    lines.append(f"- crashes: {result['crashes']}; leaks: {result['leaks']}")
    if "schemathesis" in result:
        lines.append(
            f"- schemathesis (exit {result['schemathesis']['returncode']}):\n    "
            + "\n    ".join(result["schemathesis"]["summary"])
        )
    for phase, notes in result.get("notes", {}).items():
        lines.append(f"- notes, {phase}: " + "; ".join(notes))
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mutations", type=int, default=40, help="mutations per valid file (5 formats)")
    parser.add_argument("--concurrent", type=int, default=100, help="one-cell jobs submitted at once")
    parser.add_argument(
        "--schemathesis", type=int, default=0, help="examples per operation of a schemathesis run (0: none)"
    )
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    if not BUNNY.exists():
        raise SystemExit(f"needs {BUNNY} (../shared/scenes)")
    result = run(args)
    print(json.dumps(result, indent=1) if args.json else table(result))


if __name__ == "__main__":
    main()
