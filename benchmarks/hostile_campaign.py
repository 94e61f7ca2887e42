"""A hostile-input and failure campaign against a real ``farfield up`` (issue 24's, rerun on demand).

Usage: ``.venv/bin/python benchmarks/hostile_campaign.py [--database sqlite|postgresql] [--mutations N]
[--concurrent N] [--schemathesis N] [--schemathesis-seconds S] [--json]``

Starts ``farfield up`` (embedded redis-server, uvicorn, one celery worker, SQLite or a throwaway
PostgreSQL server from ``scripts/postgres-server``, blob directory) in a temporary home and runs,
phase by phase:

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
   6-cell job, which must end done;
8. **upload burst** (issue 59): 45 uploads at once while ``GET /v1/health`` is timed (p50/p95);
   past the scene-check pool an upload is a 429 with ``Retry-After`` and stores nothing;
9. **texture bomb**: a ~421 KB GLB holding a real 12000 x 12000 PNG, refused (413) before decoding;
10. **NUL ids**: a NUL byte in the id of every route taking one, a query and a JSON body (404/422);
11. **far view cells**: cells and grids at 1e300 for layered, tdm and envmap (no 500, and the
    keep-alive connection still answers);
12. **two Authorization headers**: on the upload and on routes, in either order (401, nothing stored);
13. **multipart parts**: 257 and 300 parts (400);
14. **half-sent headers**: a raw connection that never finishes its headers gets a JSON 408 within
    ``FARFIELD_HEADER_TIMEOUT_S``;

then, on a second service (fresh home and database) with small quotas and the default failed-auth
limit:

15. **quotas**: simultaneous jobs past ``FARFIELD_MAX_TENANT_CELLS`` and placement jobs past
    ``FARFIELD_MAX_TENANT_PLACEMENTS`` (nothing past the quota stored);
16. **dedup without disclosure**: a second tenant submitting the first one's content bakes it
    (``stats.baked`` true);
17. **failed authentication**: 60 wrong keys (401s, then 429 with ``Retry-After``);
18. **API SIGKILL** under ``farfield up``: downtime until ``/v1/health`` answers again, Redis and the
    workers untouched;
19. **supervisor SIGKILL**, then a new ``farfield up`` on the same home: the old children are gone.

It counts requests, 2xx, 4xx, 5xx and connection errors per phase, and at the end crashes (the API
or supervisor gone), leaks (temporary upload files left, blobs of refused uploads) and lost or
duplicated cells.  Optionally (``--schemathesis N`` and/or ``--schemathesis-seconds S``, needs the
``schemathesis`` command) a schemathesis run of N examples per operation (or for S seconds) against the
live server's OpenAPI document with every check (``positive_data_acceptance`` named among them), and
the requests it sent, their 5xx and the failed checks read from its NDJSON report.
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
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
import zlib
from collections import Counter
from pathlib import Path

import httpx
import numpy as np
import psutil

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from scenes import city, write_scene  # noqa: E402
from service_harness import ADMIN_KEY, BUNNY, fresh_postgres_database, start_service  # noqa: E402

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

    def record_status(self, phase: str, status: int | None, json_error: bool, text: str = "") -> None:
        """A request not sent with httpx (a raw socket): its status (None: no answer) and whether its
        error body was ``{detail, error}``."""
        counts = self.phases.setdefault(phase, Counter())
        counts["requests"] += 1
        if status is None:
            counts["connection_errors"] += 1
            self.note(phase, text or "no response")
            return
        counts[f"{status // 100}xx"] += 1
        if status >= 400 and not json_error:
            counts["bad_error_bodies"] += 1
            self.note(phase, f"error body not {{detail, error}}: {text[:120]}")

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


def png_bomb(width: int = 12000, height: int = 12000) -> bytes:
    """A real, valid RGB PNG of ``width`` x ``height`` black texels (12000 x 12000: about 421 KB that
    decode to 432 MB), compressed row by row so making it takes little memory."""

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    packer, row, parts = zlib.compressobj(9), b"\0" * (1 + 3 * width), []
    for _ in range(height):
        parts.append(packer.compress(row))
    parts.append(packer.flush())
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", b"".join(parts)) + chunk(b"IEND", b"")


def textured_glb(image: bytes) -> bytes:
    """One textured quad whose base colour texture is ``image`` (PNG)."""
    from gltf_files import SQUARE_UV, GltfBuilder

    b = GltfBuilder()
    index = b._add("images", {"bufferView": b.view(image), "mimeType": "image/png"})
    b.quad("q", [0, 0, 0], 1.0, b.material(texture=b.texture(index)), uv=SQUARE_UV)
    return b.glb()


def raw_exchange(url: str, data: bytes, wait: float) -> tuple[int | None, bytes, float]:
    """Send ``data`` on a raw connection and read until the server closes it or ``wait`` seconds
    pass: (status or None, what came back, seconds until the first byte or the end)."""
    host, port = url.split("//")[1].split(":")
    got, start, first = b"", time.monotonic(), None
    with socket.create_connection((host, int(port))) as s:
        s.sendall(data)
        s.settimeout(0.5)
        while time.monotonic() - start < wait:
            try:
                chunk = s.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                break
            if not chunk:
                break
            first = first or time.monotonic() - start
            got += chunk
    status = int(got.split()[1]) if got.startswith(b"HTTP/1.1 ") else None
    return status, got, first if first is not None else time.monotonic() - start


def json_error_body(raw: bytes) -> bool:
    try:
        body = json.loads(raw.split(b"\r\n\r\n", 1)[1])
        return isinstance(body.get("detail"), str) and isinstance(body.get("error"), str)
    except Exception:  # noqa: BLE001 - a verdict, not an error
        return False


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


def health_timer(url: str, stop: threading.Event, out: list[float]) -> None:
    """``GET /v1/health`` back to back until ``stop``, milliseconds per answer into ``out``."""
    with httpx.Client(base_url=url, timeout=120) as c:
        while not stop.is_set():
            start = time.perf_counter()
            try:
                c.get("/v1/health")
            except httpx.HTTPError:
                pass
            out.append(1000 * (time.perf_counter() - start))
            time.sleep(0.02)


def alive(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def rss_mib(pid: int) -> float:
    try:
        return psutil.Process(pid).memory_info().rss / 2**20
    except psutil.NoSuchProcess:
        return float("nan")


def database_url(args, home: Path) -> tuple[str, callable]:
    """A fresh database for one service: SQLite in its home, or a new database on the campaign's
    PostgreSQL server; (URL, a function that drops it)."""
    if args.postgres_admin_url:
        return fresh_postgres_database(args.postgres_admin_url)
    return f"sqlite:///{home / 'farfield.db'}", lambda: None


def new_key(url: str, tenant: str) -> str:
    db = Database(url)
    try:
        return create_key(db, tenant)[0]
    finally:
        db.engine.dispose()


def stored_scene_folders(home: Path) -> set[str]:
    return {p.parent.name for p in (home / "blobs" / "scenes").glob("*/*")}


def hardened_phases(
    tally: Tally, service, client: httpx.Client, db_url: str, valid: dict, scene_id: str, result: dict
) -> None:
    """Phases 8-14 (issue 59) on the campaign's main service."""
    home = service.home

    # 8. upload burst while /v1/health is timed
    phase = "8 upload burst"
    before = stored_scene_folders(home)
    stop, health_ms = threading.Event(), []
    timer = threading.Thread(target=health_timer, args=(service.url, stop, health_ms))
    timer.start()
    time.sleep(0.3)
    statuses: list[int] = []

    def upload(n: int) -> None:
        with service.client() as c:
            c.timeout = httpx.Timeout(300)
            response = send(tally, phase, c, "POST", "/v1/scenes", files={"file": (f"burst{n}.glb", valid["glb"])})
            if response is not None:
                statuses.append(response.status_code)
                if response.status_code == 429 and "retry-after" not in response.headers:
                    tally.note(phase, "429 without Retry-After")

    start = time.perf_counter()
    with concurrent.futures.ThreadPoolExecutor(45) as pool:
        list(pool.map(upload, range(45)))
    burst_s = time.perf_counter() - start
    stop.set()
    timer.join()
    made = Counter(statuses)
    stored = len(stored_scene_folders(home) - before)
    if stored != made.get(201, 0):
        tally.note(phase, f"LEAK: {stored} scene folders for {made.get(201, 0)} accepted uploads")
    if set(made) - {201, 429}:
        tally.note(phase, f"unexpected statuses {dict(made)}")
    result["upload_burst"] = {
        "uploads": 45, "statuses": dict(made), "seconds": round(burst_s, 2), "health_requests": len(health_ms),
        "health_p50_ms": round(percentile(health_ms, 50), 1), "health_p95_ms": round(percentile(health_ms, 95), 1),
        "health_max_ms": round(max(health_ms, default=float("nan")), 1),
    }  # fmt: skip
    if percentile(health_ms, 95) >= 200:
        tally.note(phase, f"health p95 {percentile(health_ms, 95):.0f} ms (target < 200 ms)")

    # 9. texture bomb
    phase = "9 texture bomb"
    bomb = textured_glb(png_bomb())
    before = stored_scene_folders(home)
    rss_before = rss_mib(service.api_pid())
    start = time.perf_counter()
    response = send(tally, phase, client, "POST", "/v1/scenes", files={"file": ("bomb.glb", bomb)})
    seconds = time.perf_counter() - start
    status = response.status_code if response is not None else None
    result["texture_bomb"] = {
        "glb_kb": round(len(bomb) / 1000), "status": status, "seconds": round(seconds, 3),
        "api_rss_growth_mib": round(rss_mib(service.api_pid()) - rss_before, 1),
        "detail": response.json().get("detail", "")[:160] if status is not None and status >= 400 else "",
    }  # fmt: skip
    if status != 413:
        tally.note(phase, f"bomb answered {status} (expected 413)")
    if stored_scene_folders(home) - before:
        tally.note(phase, "LEAK: the refused bomb left a scene folder")

    # 10. NUL byte in ids
    phase = "10 NUL ids"
    job = client.post(
        "/v1/jobs",
        json={
            "scene_id": scene_id,
            "resolution": 64,
            "viewcells": [{"kind": "box", "lo": [50, 1, 50], "hi": [54, 5, 54]}],
        },
    ).json()
    nul_scene, nul_job = f"{scene_id[:8]}%00{scene_id[8:]}", f"{job['id'][:8]}%00{job['id'][8:]}"
    probes = [("GET", f"/v1/scenes/{nul_scene}"), ("GET", f"/v1/scenes/{nul_scene}/objects"), ("GET", f"/v1/scenes/{nul_scene}/scene.glb"),
              ("DELETE", f"/v1/scenes/{nul_scene}"), ("GET", "/v1/scenes/%00"), ("GET", f"/v1/jobs/{nul_job}"), ("POST", f"/v1/jobs/{nul_job}/cancel"),
              ("POST", f"/v1/jobs/{nul_job}/retry"), ("GET", f"/v1/jobs/{nul_job}/cells/0"), ("GET", f"/v1/jobs/{nul_job}/cells/0/bundle.zip"),
              ("GET", f"/v1/jobs/{nul_job}/cells/0/manifest.json"), ("GET", f"/v1/jobs/{nul_job}/cells/0/impostor.glb"),
              ("GET", f"/v1/jobs/{nul_job}/cells/0/payload.bin"), ("GET", f"/v1/jobs/{nul_job}/cells/0/atlas/0.png"),
              ("GET", f"/v1/jobs/{nul_job}/index.json"), ("GET", f"/v1/jobs/{nul_job}/database.zip"), ("GET", f"/v1/jobs/{nul_job}/lookup?x=0&y=0&z=0"),
              ("GET", f"/v1/jobs/{nul_job}/clusters"), ("GET", f"/v1/jobs/{nul_job}/placement"), ("GET", f"/v1/jobs?scene_id={nul_scene}"),
              ("GET", "/v1/jobs?state=%00"), ("GET", "/v1/placement-algorithms/%00"), ("GET", "/v1/techniques/%00")]  # fmt: skip
    for method, path in probes:
        response = send(tally, phase, client, method, path)
        if response is not None and response.status_code < 400 and "?" not in path:
            tally.note(phase, f"{method} {path} answered {response.status_code}")
    for body in ({"scene_id": scene_id[:8] + "\x00" + scene_id[8:], "resolution": 64, "viewcells": [{"kind": "box", "lo": [50, 1, 50], "hi": [54, 5, 54]}]},
                 {"scene_id": "\x00", "resolution": 64, "grid": {"lo": [0, 0, 0], "hi": [1, 1, 1], "counts": [1, 1, 1]}}):  # fmt: skip
        response = send(tally, phase, client, "POST", "/v1/jobs", json=body)
        if response is not None and response.status_code < 400:
            tally.note(phase, f"a JSON scene_id with NUL answered {response.status_code}")
    wait_job(client, job["id"], 300)

    # 11. far view cells
    phase = "11 far view cells"
    far = []
    for technique in ("layered", "tdm", "envmap"):
        for cell in ({"kind": "box", "lo": [1e300, 1e300, 1e300], "hi": [1.0000001e300, 1.0000001e300, 1.0000001e300]},
                     {"kind": "box", "lo": [-1e300, 0, 0], "hi": [1e300, 1, 1]}, {"kind": "point", "at": [1e300, 0, 0]}):  # fmt: skip
            response = send(
                tally,
                phase,
                client,
                "POST",
                "/v1/jobs",
                json={"scene_id": scene_id, "technique": technique, "resolution": 64, "viewcells": [cell]},
            )
            far.append((technique, "cell", response))
        grid = {"lo": [1e300, 0, 0], "hi": [1.0000001e300, 1, 1], "counts": [1, 1, 1]}
        response = send(
            tally,
            phase,
            client,
            "POST",
            "/v1/jobs",
            json={"scene_id": scene_id, "technique": technique, "resolution": 64, "grid": grid},
        )
        far.append((technique, "grid", response))
        if send(tally, phase, client, "GET", "/v1/health") is None:
            tally.note(phase, f"{technique}: the keep-alive connection did not answer after the far cells")
    outcomes = Counter()
    for technique, kind, response in far:
        if response is None:
            continue
        if response.status_code == 201:
            # An accepted far cell must bake or fail as bad input; one that fails as an internal error
            # is retried FARFIELD_MAX_ATTEMPTS times with back-off (minutes), so it is read after 30 s,
            # named by its cells' errors and cancelled.
            ended = wait_job(client, response.json()["id"], 30)
            errors = sorted({(e.get("error") or "")[:90] for e in ended.get("errors", []) if e.get("error")})
            outcomes[
                f"{technique} {kind}: 201, job {ended['state']}" + (f" ({'; '.join(errors)})" if errors else "")
            ] += 1
            if errors and any("internal error" in e for e in errors):
                tally.note(phase, f"{technique} {kind}: an accepted far cell fails in the worker: {errors[0]}")
            if ended["state"] not in ("done", "failed", "cancelled"):
                client.post(f"/v1/jobs/{ended['id']}/cancel")
        else:
            outcomes[f"{technique} {kind}: {response.status_code}"] += 1
    result["far_cells"] = dict(outcomes)

    # 12. two Authorization headers
    phase = "12 two Authorization headers"
    other = new_key(db_url, "second-tenant")
    before = stored_scene_folders(home)
    orders = [(other, ADMIN_KEY), (ADMIN_KEY, other), ("bad", ADMIN_KEY), (ADMIN_KEY, "bad")]
    with service.client(key=None) as anonymous:
        for first, second in orders:
            headers = [("Authorization", f"Bearer {first}"), ("Authorization", f"Bearer {second}")]
            for method, path, kwargs in (("POST", "/v1/scenes", {"files": {"file": ("two.obj", valid["obj"])}}), ("GET", "/v1/scenes", {}),
                                         ("GET", f"/v1/scenes/{scene_id}", {}), ("POST", "/v1/jobs", {"json": {"scene_id": scene_id, "resolution": 64, "viewcells": [{"kind": "box", "lo": [50, 1, 50], "hi": [54, 5, 54]}]}})):  # fmt: skip
                response = send(tally, phase, anonymous, method, path, headers=headers, **kwargs)
                if response is not None and response.status_code != 401:
                    tally.note(phase, f"{method} {path} with two keys answered {response.status_code}")
    if stored_scene_folders(home) - before:
        tally.note(phase, "LEAK: an upload with two keys was stored")

    # 13. multipart parts
    phase = "13 multipart parts"
    before = stored_scene_folders(home)
    for parts in (257, 300):
        files = [("file", (f"p{i}.obj", valid["obj"][:64])) for i in range(parts)]
        response = send(tally, phase, client, "POST", "/v1/scenes", files=files)
        if response is not None and response.status_code != 400:
            tally.note(phase, f"{parts} parts answered {response.status_code} (expected 400)")
    if stored_scene_folders(home) - before:
        tally.note(phase, "LEAK: a refused multipart upload was stored")

    # 14. half-sent headers
    phase = "14 half-sent headers"
    limit = float(service.env.get("FARFIELD_HEADER_TIMEOUT_S", 10))
    status, got, seconds = raw_exchange(
        service.url, b"GET /v1/health HTTP/1.1\r\nHost: farfield\r\nX-Slow: ", limit + 20
    )
    tally.record_status(phase, status, json_error_body(got), got[:200].decode(errors="replace"))
    result["half_sent_headers"] = {"status": status, "seconds": round(seconds, 2), "limit_s": limit}
    if status != 408 or seconds > limit + 5:
        tally.note(phase, f"half-sent headers: {status} after {seconds:.1f} s (expected 408 within {limit:.0f} s)")


def guarded_phases(tally: Tally, args, result: dict, files: Path) -> None:
    """Phases 15-19 on a second service with small quotas and the default failed-auth limit."""
    import trimesh

    home = Path(tempfile.mkdtemp(prefix="farfield-campaign-guarded-"))
    db_url, drop = database_url(args, home)
    env = {
        "FARFIELD_MAX_TENANT_CELLS": "4",
        "FARFIELD_MAX_TENANT_PLACEMENTS": "1",
        "FARFIELD_AUTH_FAILURES": "20",
        "DATABASE_URL": db_url,
    }
    service = start_service(home, **env)
    second = None
    try:
        client = service.client()
        crate = trimesh.creation.box(extents=(1.0, 1.0, 1.0)).export(file_type="stl")
        scene_id = client.post("/v1/scenes", files={"file": ("crate.stl", crate)}).json()["id"]
        cell = {"kind": "box", "lo": [-4.0, -0.5, -0.5], "hi": [-3.0, 0.5, 0.5]}

        # 15. quotas
        phase = "15 quotas"

        def at_once(count: int, body: dict) -> list[httpx.Response | None]:
            barrier = threading.Barrier(count)

            def one(_: int) -> httpx.Response | None:
                with service.client() as c:
                    barrier.wait()
                    return send(tally, phase, c, "POST", "/v1/jobs", json=body)

            with concurrent.futures.ThreadPoolExecutor(count) as pool:
                return list(pool.map(one, range(count)))

        cells_jobs = at_once(8, {"scene_id": scene_id, "resolution": 256, "viewcells": [cell, cell]})
        placement = {"view_space": {"lo": [-6.0, 0.0, -6.0], "hi": [6.0, 1.0, 6.0]}, "budget": {"primitives": 100.0}}
        placement_jobs = at_once(4, {"scene_id": scene_id, "resolution": 64, "placement": placement})
        quota = {}
        for label, responses, room in (
            ("2-cell jobs, quota 4 cells", cells_jobs, 2),
            ("placement jobs, quota 1", placement_jobs, 1),
        ):
            codes = Counter(r.status_code for r in responses if r is not None)
            quota[label] = dict(codes)
            if codes.get(201, 0) > room:
                tally.note(phase, f"PAST QUOTA: {label}: {dict(codes)}")
            if any(r is not None and r.status_code == 429 and "retry-after" not in r.headers for r in responses):
                tally.note(phase, f"{label}: 429 without Retry-After")
        listed = client.get("/v1/jobs", params={"limit": 100}).json()
        accepted = sum(1 for r in cells_jobs + placement_jobs if r is not None and r.status_code == 201)
        quota["jobs stored"] = len(listed)
        if len(listed) != accepted:
            tally.note(phase, f"{len(listed)} jobs stored for {accepted} accepted")
        result["quotas"] = quota
        for job in listed:
            wait_job(client, job["id"], 600)

        # 16. dedup without disclosure
        phase = "16 dedup across tenants"
        body = {"resolution": 64, "viewcells": [cell]}
        mine = send(tally, phase, client, "POST", "/v1/jobs", json={"scene_id": scene_id, **body}).json()
        wait_job(client, mine["id"], 300)
        other_key = new_key(db_url, "other-tenant")
        with service.client(key=other_key) as stranger:
            theirs_scene = send(
                tally, phase, stranger, "POST", "/v1/scenes", files={"file": ("crate.stl", crate)}
            ).json()["id"]
            theirs = send(tally, phase, stranger, "POST", "/v1/jobs", json={"scene_id": theirs_scene, **body}).json()
            wait_job(stranger, theirs["id"], 300)
            theirs_cell = send(tally, phase, stranger, "GET", f"/v1/jobs/{theirs['id']}/cells/0").json()
        again = send(tally, phase, client, "POST", "/v1/jobs", json={"scene_id": scene_id, **body}).json()
        wait_job(client, again["id"], 300)
        mine_cell = send(tally, phase, client, "GET", f"/v1/jobs/{mine['id']}/cells/0").json()
        again_cell = send(tally, phase, client, "GET", f"/v1/jobs/{again['id']}/cells/0").json()
        baked = {"first tenant": mine_cell.get("stats", {}).get("baked"), "second tenant, same content": theirs_cell.get("stats", {}).get("baked"),
                 "first tenant again": again_cell.get("stats", {}).get("baked")}  # fmt: skip
        result["dedup"] = baked
        if baked["second tenant, same content"] is not True:
            tally.note(phase, f"DISCLOSURE: the second tenant's stats.baked is {baked['second tenant, same content']}")

        # 17. failed authentication
        phase = "17 failed authentication"
        codes, retry_after = [], set()
        with service.client(key=None) as anonymous:
            for n in range(60):
                response = send(
                    tally,
                    phase,
                    anonymous,
                    "GET",
                    "/v1/scenes",
                    headers={"Authorization": f"Bearer ff_wrong{n:03d}_{'x' * 32}"},
                )
                if response is not None:
                    codes.append(response.status_code)
                    if response.status_code == 429:
                        retry_after.add(response.headers.get("retry-after"))
            valid_meanwhile = send(tally, phase, client, "GET", "/v1/scenes")
            health = send(tally, phase, anonymous, "GET", "/v1/health")
        first_429 = codes.index(429) if 429 in codes else None
        result["auth_failures"] = {
            "statuses": dict(Counter(codes)), "first_429_at": first_429, "retry_after": sorted(str(r) for r in retry_after),
            "valid key meanwhile": valid_meanwhile.status_code if valid_meanwhile is not None else None,
            "health meanwhile": health.status_code if health is not None else None,
        }  # fmt: skip
        if first_429 is None or None in retry_after or set(codes) - {401, 429}:
            tally.note(phase, f"expected 401s then 429 with Retry-After: {dict(Counter(codes))}")

        # 18. SIGKILL of the API under farfield up
        phase = "18 API SIGKILL"
        api, redis, workers = service.api_pid(), service.redis_pid(), service.worker_mains()
        os.kill(api, signal.SIGKILL)
        start = time.monotonic()
        with service.client(key=None) as probe:
            probe.timeout = httpx.Timeout(2)
            back = None
            while time.monotonic() - start < 120:
                try:
                    if probe.get("/v1/health").status_code == 200:
                        back = time.monotonic() - start
                        break
                except httpx.HTTPError:
                    pass
                time.sleep(0.05)
        send(tally, phase, client, "GET", "/v1/health")
        job = send(
            tally, phase, client, "POST", "/v1/jobs", json={"scene_id": scene_id, "resolution": 48, "viewcells": [cell]}
        )
        ended = wait_job(client, job.json()["id"], 300)["state"] if job is not None and job.status_code == 201 else None
        result["api_kill"] = {
            "downtime_s": round(back, 2) if back is not None else None, "supervisor_alive": service.process.poll() is None,
            "redis_same": alive(redis) and service.redis_pid() == redis, "workers_same": sorted(service.worker_mains()) == sorted(workers),
            "job_after": ended,
        }  # fmt: skip
        if (
            back is None
            or back >= 10
            or not result["api_kill"]["redis_same"]
            or not result["api_kill"]["workers_same"]
            or ended != "done"
        ):
            tally.note(phase, f"API kill: {result['api_kill']}")
        client.close()

        # 19. SIGKILL of the supervisor, then a new farfield up on the same home
        phase = "19 supervisor SIGKILL"
        children = [service.api_pid(), service.redis_pid(), *service.worker_mains(), *service.worker_pool_children()]
        os.kill(service.process.pid, signal.SIGKILL)
        service.process.wait()
        time.sleep(1)
        orphans = sum(alive(pid) for pid in children)
        start = time.monotonic()
        second = start_service(home, **env)
        deadline = time.monotonic() + 10
        while any(alive(pid) for pid in children) and time.monotonic() < deadline:
            time.sleep(0.1)
        left = [pid for pid in children if alive(pid)]
        with second.client() as c:
            health = send(tally, phase, c, "GET", "/v1/health")
        result["supervisor_kill"] = {
            "children": len(children), "orphans_after_kill": orphans, "left_after_new_up": len(left),
            "new_up_seconds": round(time.monotonic() - start, 1), "health": health.json().get("status") if health is not None else None,
        }  # fmt: skip
        if left:
            tally.note(
                phase,
                f"LEFTOVERS: {len(left)} old children alive: {[psutil.Process(p).name() for p in left if alive(p)]}",
            )
    finally:
        for running in (second, service):
            if running is not None and running.process.poll() is None:
                running.stop()
        # A killed supervisor's children: the second up reaped them; make sure, by pid, if it failed to start.
        shutil.rmtree(home, ignore_errors=True)
        drop()


def run(args) -> dict:
    tally = Tally()
    home = Path(tempfile.mkdtemp(prefix="farfield-campaign-"))
    db_url, drop = database_url(args, home)
    # Attempts enough that the five kills, which may all land on one cell, do not use its attempts up
    # (a cell that keeps killing its worker is failed after FARFIELD_MAX_ATTEMPTS by design).  The
    # failed-auth limit is lifted on this service only: schemathesis's ignored_auth check and the
    # two-header probes send keys that do not authenticate, and past the limit every keyed request
    # from this address would be a 429 for a minute; phase 17 runs with the default on the second service.
    service = start_service(
        home,
        FARFIELD_MAX_UPLOAD_MB="64",
        FARFIELD_MAX_ATTEMPTS="8",
        FARFIELD_AUTH_FAILURES="1000000",
        DATABASE_URL=db_url,
    )
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
        other_key = new_key(db_url, "stranger")
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

        # 8-14: issue 59's cases
        hardened_phases(tally, service, client, db_url, valid, scene_id, result)

        # schemathesis, if asked
        if args.schemathesis or args.schemathesis_seconds:
            result["schemathesis"] = schemathesis(args, service.url, home)

        # the end: crashes and leaks
        result["crashes"] = {
            "supervisor_alive": service.process.poll() is None,
            "health": client.get("/v1/health").json(),
        }
        tmp_after = {p.name for p in Path(tempfile.gettempdir()).glob("farfield-upload-*")} | {
            p.name for p in Path(tempfile.gettempdir()).glob("farfield-ingest-*")
        }
        result["leaks"] = {"temporary_upload_files_left": len(tmp_after - tmp_before)}
        result["api_log_tracebacks"] = api_log_tracebacks(home)
    finally:
        client.close()
        service.stop()
        shutil.rmtree(home, ignore_errors=True)
        drop()
    guarded_phases(tally, args, result, home)
    result["phases"] = {phase: dict(counts) for phase, counts in tally.phases.items()}
    result["notes"] = {phase: notes[:20] for phase, notes in tally.notes.items() if notes}
    return result


def api_log_tracebacks(home: Path) -> list[str]:
    """The last lines of each traceback in the service's API log (a 5xx leaves one)."""
    log = home / "logs" / "api.log"
    if not log.exists():
        return []
    lines = log.read_text(errors="replace").splitlines()
    found = []
    for n, line in enumerate(lines):
        if line.startswith("Traceback"):
            end = next(
                (m for m in range(n + 1, len(lines)) if lines[m] and not lines[m].startswith((" ", "Traceback"))), n
            )
            found.append(" | ".join(lines[max(0, n - 2) : n + 1] + lines[end - 2 : end + 1]))
    return found[:10]


def schemathesis(args, url: str, home: Path) -> dict:
    """A schemathesis run with every check (``positive_data_acceptance``, ``not_a_server_error`` and
    the rest): its exit status, the requests it sent, their statuses and the failed checks, from its
    NDJSON report."""
    exe = shutil.which("schemathesis") or str(Path(sys.executable).parent / "schemathesis")
    report = Path(tempfile.gettempdir()) / f"farfield-campaign-schemathesis-{args.database}.ndjson"  # kept to read
    command = [exe, "run", f"{url}/openapi.json", "--header", f"Authorization: Bearer {ADMIN_KEY}",
               "--checks", "all", "--seed", "24", "--exclude-path", "/v1/scenes", "--exclude-method", "DELETE",
               "--report", "ndjson", "--report-ndjson-path", str(report), "--workers", str(args.schemathesis_workers)]  # fmt: skip
    if args.schemathesis:
        command += ["--max-examples", str(args.schemathesis)]
    if args.schemathesis_seconds:
        command += ["--max-time", str(args.schemathesis_seconds)]
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, timeout=3600, check=False)
    seconds = time.perf_counter() - start
    statuses, checks, failed = Counter(), Counter(), Counter()

    def walk(value) -> None:
        if isinstance(value, dict):
            response = value.get("response")
            if isinstance(response, dict) and isinstance(response.get("status_code"), int):
                statuses[f"{response['status_code'] // 100}xx"] += 1
            if isinstance(value.get("name"), str) and value.get("status") in (
                "success",
                "failure",
                "error",
                "SUCCESS",
                "FAILURE",
            ):
                checks[value["name"]] += 1
                if str(value["status"]).lower() != "success":
                    failed[value["name"]] += 1
            for item in value.values():
                walk(item)
        elif isinstance(value, list):
            for item in value:
                walk(item)

    if report.exists():
        for line in report.read_text().splitlines():
            try:
                walk(json.loads(line))
            except json.JSONDecodeError:
                continue
    requests = sum(statuses.values())
    report.with_suffix(".txt").write_text(done.stdout + done.stderr)  # the whole output, kept to read
    lines = done.stdout.splitlines()
    errors = next((n for n, line in enumerate(lines) if "ERRORS" in line or "FAILURES" in line), None)
    shown = (lines[errors : errors + 16] if errors is not None else []) + lines[-12:]
    return {
        "returncode": done.returncode, "seconds": round(seconds), "requests": requests,
        "requests_per_s": round(requests / seconds, 1) if seconds else None, "statuses": dict(statuses),
        "checks_run": dict(checks), "checks_failed": dict(failed), "summary": shown,
    }  # fmt: skip


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
    for key in (
        "upload_burst",
        "texture_bomb",
        "far_cells",
        "half_sent_headers",
        "quotas",
        "dedup",
        "auth_failures",
        "api_kill",
        "supervisor_kill",
        "api_log_tracebacks",
    ):
        if key in result:
            lines.append(f"- {key.replace('_', ' ')}: {result[key]}")
    lines.append(f"- crashes: {result['crashes']}; leaks: {result['leaks']}")
    if "schemathesis" in result:
        st = result["schemathesis"]
        lines.append(
            f"- schemathesis (exit {st['returncode']}): {st['requests']} requests in {st['seconds']} s ({st['requests_per_s']}/s), "
            f"statuses {st['statuses']}, checks failed {st['checks_failed']}, checks run {st['checks_run']}:\n    "
            + "\n    ".join(st["summary"])
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
    parser.add_argument(
        "--schemathesis-seconds", type=int, default=0, help="time budget of the schemathesis run (0: none)"
    )
    parser.add_argument("--schemathesis-workers", default="2", help="schemathesis workers (a number or auto)")
    parser.add_argument("--database", choices=("sqlite", "postgresql"), default="sqlite")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    if not BUNNY.exists():
        raise SystemExit(f"needs {BUNNY} (../shared/scenes)")
    args.postgres_admin_url = None
    pg_dir = None
    if args.database == "postgresql":
        # A throwaway server, as .ci/run starts one; each service gets a fresh database on it.
        pg_dir = Path(tempfile.mkdtemp(prefix="farfield-campaign-pg-"))
        started = subprocess.run(
            [str(ROOT / "scripts" / "postgres-server"), "start", str(pg_dir / "pg")],
            capture_output=True,
            text=True,
            check=False,
        )
        if started.returncode != 0:
            raise SystemExit(f"no PostgreSQL server: {started.stderr}")
        args.postgres_admin_url = started.stdout.strip().splitlines()[-1]
    try:
        result = run(args)
    finally:
        if pg_dir is not None:
            subprocess.run([str(ROOT / "scripts" / "postgres-server"), "stop", str(pg_dir / "pg")], check=False)
            shutil.rmtree(pg_dir, ignore_errors=True)
    result["database"] = args.database
    print(json.dumps(result, indent=1) if args.json else table(result))


if __name__ == "__main__":
    main()
