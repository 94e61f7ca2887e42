"""Whole bakes per stage, bundle writing included, and the PNG encoding of pages, side by side in one run (issue 60 item 2).

Usage: ``.venv/bin/python benchmarks/bench_bundle.py [--only gil|encoding|bakes|cpu ...] [--against REV] [--repeat 2] [--bakes NAME ...] [--json]``

1. **gil**: does Pillow's PNG encoder release the GIL?  A thread spins in pure Python while the main
   thread encodes one 1024 x 1024 page; the spinner's own CPU seconds (``time.thread_time``) show
   whether it could run.  The control is one long C call that holds the GIL (``sum(range(...))``).
2. **encoding**: the pages of a few bakes (the LDI and a layered impostor of the Damaged Helmet at
   512 px, the benchmark object's layered impostor at 512 and 1024 px, the envmap cell of
   ``bench_envmap.py``) encoded with each zlib level and strategy: CPU seconds (best of 2) and bytes,
   as ratios to the level-6 default strategy; and the strategy :data:`farfield.core.impostor.png_pages.PNG_STRATEGY`.
3. **bakes**: each bake's stages (``stats["seconds"]``) and its bundle written
   (:func:`farfield.core.impostor.bundle.write_bundle`: PNG pages, GLB, fsync), wall and CPU
   seconds (``getrusage``, every thread), each stage's share of the whole; the LDI cells beside the
   nine plain renders of their construction images (``bench_ldi.py``'s (a) and (b), alternately,
   best of 3), as wall seconds and as CPU seconds of the process (every thread: llvmpipe renders
   on its own threads), the least of each.  Bakes: ``layered-512`` and ``layered-1024`` (``bench_layered.py``'s speed object
   and cell), ``envmap`` (``bench_envmap.py``'s middle cell, 512 px, 64 layers, six directions),
   ``ldi-256`` and ``ldi-512`` (the helmet cell of ``bench_ldi.py``).  Each bake runs in a fresh
   process after a warm-up bake; with ``--against REV`` the same bake also runs with the ``core/``
   of git revision ``REV`` (``git archive``, first on the import path), the two alternating,
   ``--repeat`` times each, the fastest whole (bake + bundle) of each kept.  ``content`` hashes the
   page and payload arrays: equal where the two codes bake the same impostor.

4. **cpu**: the same bakes' stages in CPU seconds of the baking thread (the stage clock read with
   ``time.process_time`` in that process), without the bundle: one warm-up bake and one measured,
   in fresh processes, this tree and ``--against`` alternately, ``--repeat`` times each.

The renderer is printed, and the load average beside each row: on this project's shared 2-core
machine compare CPU seconds and ratios measured in the same run, not wall seconds across runs.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import os
import resource
import subprocess
import sys
import tempfile
import threading
import time
import zlib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

BAKES = ("layered-512", "layered-1024", "envmap", "ldi-256", "ldi-512")
STRATEGIES = [(6, -1), (1, -1), (3, -1), (4, -1), (5, -1), (9, -1), (6, zlib.Z_FILTERED), (6, zlib.Z_RLE)]


def cpu_s() -> float:
    """CPU seconds of this process, every thread."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def gil() -> list[dict]:
    """Part 1: the spinner's CPU seconds beside a PNG encode and beside a call that holds the GIL."""
    from PIL import Image

    page = (np.random.default_rng(0).integers(0, 4, (1024, 1024, 4)) * 60).astype(np.uint8)

    def encode():
        Image.fromarray(page, "RGBA").save(io.BytesIO(), "PNG", compress_level=6)

    def hold():
        sum(range(6 * 10**7))

    rows = []
    for label, work in (("PNG encode", encode), ("GIL held (sum of a range)", hold)):
        stop, spun = threading.Event(), {}

        def spin():
            start = time.thread_time()
            while not stop.is_set():
                pass
            spun["cpu"] = time.thread_time() - start

        spinner = threading.Thread(target=spin)
        wall = time.perf_counter()
        spinner.start()
        start = time.thread_time()
        work()
        worked = time.thread_time() - start
        stop.set()
        spinner.join()
        rows.append({"work": label, "wall": time.perf_counter() - wall, "work_cpu": worked, "spinner_cpu": spun["cpu"],
                     "load": os.getloadavg()[0]})  # fmt: skip
    return rows


def _scene_and_bake(name: str):
    """(scene, a function that bakes it) for one of :data:`BAKES`."""
    if name.startswith("layered"):
        import bench_layered as bl

        from farfield.core.techniques.layered import BakeOptions, bake_layered

        scene = bl.dense_object()
        diameter = float(np.max(scene.bounds[1] - scene.bounds[0]))
        cell = bl.cell_before(scene, 1.6 * diameter, 0.3 * diameter)
        resolution = int(name.split("-")[1])
        return scene, cell, lambda: bake_layered(scene, cell, BakeOptions(resolution=resolution))
    if name == "envmap":
        import bench_envmap as be

        from farfield.core.techniques.envmap.technique import EnvmapOptions, bake_envmap

        scene = be.detailed_city(36, 3)
        cells = be.street_grid(36)
        middle = cells[len(cells) // 2][1]
        options = EnvmapOptions(
            resolution=512, fov_deg=90.0, layers=64, directions=("+x", "-x", "+y", "-y", "+z", "-z")
        )
        return scene, middle, lambda: bake_envmap(scene, middle, options)
    import bench_ldi as bldi

    from farfield.core.techniques.ldi import LdiOptions, bake_ldi

    class Args:
        buildings, detail = 4, 2

    _, scene, cell = next(s for s in bldi.scenes(Args()) if "Helmet" in s[0])
    resolution = int(name.split("-")[1])
    return scene, cell, lambda: bake_ldi(scene, cell, LdiOptions(resolution=resolution, channels="albedo"))


def encoding(names) -> list[dict]:
    """Part 2: every (level, strategy) over the pages of each bake."""
    from PIL import Image

    def encode(page, level, strategy):
        buffer = io.BytesIO()
        Image.fromarray(np.ascontiguousarray(page), "RGBA").save(
            buffer, "PNG", optimize=False, compress_level=level, compress_type=strategy
        )
        return len(buffer.getvalue())

    rows = []
    for name in names:
        _, _, bake = _scene_and_bake(name)
        impostor = bake()
        pages = list(impostor.pages) + [p for pages in impostor.channels.values() for p in pages]
        base = None
        for level, strategy in STRATEGIES:
            best = float("inf")
            for _ in range(2):
                start = time.process_time()
                size = sum(encode(p, level, strategy) for p in pages)
                best = min(best, time.process_time() - start)
            base = base or (best, size)
            rows.append({"pages_of": name, "pages": len(pages), "raw_mib": sum(p.nbytes for p in pages) / 2**20,
                         "level": level, "strategy": strategy, "cpu_s": best, "bytes": size,
                         "cpu_ratio": best / base[0], "bytes_ratio": size / base[1]})  # fmt: skip
    return rows


def one_bake(name: str, repeat: int) -> dict:
    """Part 3 in this process: the fastest of ``repeat`` (bake + bundle) after a warm-up, by stage."""
    from farfield.core.impostor.bundle import write_bundle

    scene, cell, bake = _scene_and_bake(name)
    bake()  # warm: context, shaders, numba
    ldi = name.startswith("ldi")
    if ldi:
        import bench_ldi as bldi

        from farfield.core.sidedness import seen_from_cell

        drawn = list(seen_from_cell(scene.objects, cell))
        cameras = bldi.construction_cameras(scene, cell, int(name.split("-")[1]))
    best, nine, run_cpu = None, [], []
    for _ in range(repeat):
        if ldi:
            cpu = cpu_s()
            nine.append((bldi.nine_images(drawn, cameras)["total"], cpu_s() - cpu))
        wall, cpu = time.perf_counter(), cpu_s()
        impostor = bake()
        baked_wall, baked_cpu = time.perf_counter(), cpu_s()
        with tempfile.TemporaryDirectory() as folder:
            write_bundle(impostor, Path(folder) / "bundle")
        end_wall, end_cpu = time.perf_counter(), cpu_s()
        run = {"stages": {k: v for k, v in impostor.stats["seconds"].items() if k != "total"},
               "bake_s": baked_wall - wall, "bake_cpu_s": baked_cpu - cpu,
               "bundle_s": end_wall - baked_wall, "bundle_cpu_s": end_cpu - baked_cpu,
               "total_s": end_wall - wall, "total_cpu_s": end_cpu - cpu, "load": os.getloadavg()[0],
               "pages": len(impostor.pages) + sum(len(p) for p in impostor.channels.values()),
               "content": _content_digest(impostor)}  # fmt: skip
        run_cpu.append(run["total_cpu_s"])
        if best is None or run["total_s"] < best["total_s"]:
            best = run
    if ldi:  # wall: the fastest of each; CPU (every thread, llvmpipe's too): the least of each
        best["nine_images_s"] = min(wall for wall, _ in nine)
        best["nine_images_cpu_s"] = min(cpu for _, cpu in nine)
        best["ratio"] = best["total_s"] / best["nine_images_s"]
        best["ratio_cpu"] = min(run_cpu) / best["nine_images_cpu_s"]
    return best


def _content_digest(impostor) -> str:
    """SHA-256 (16 hex digits) of the impostor's page arrays and payload arrays: equal for two codes
    that bake the same impostor, whatever their PNG encoding."""
    digest = hashlib.sha256()
    for page in (*impostor.pages, *(p for _, pages in sorted(impostor.channels.items()) for p in pages)):
        digest.update(np.ascontiguousarray(page).tobytes())
    for name, _, _ in impostor.payload.stored_arrays():
        digest.update(np.ascontiguousarray(getattr(impostor.payload, name)).tobytes())
    return digest.hexdigest()[:16]


def cpu_stages(name: str) -> dict:
    """Part 4 in this process: one bake's stages in CPU seconds of this thread, after a warm-up."""
    time.perf_counter = time.process_time  # the stage clock's timer; this process does nothing else
    _, _, bake = _scene_and_bake(name)
    bake()
    return bake().stats["seconds"]


def archived(revision: str, folder: Path) -> Path:
    """``bench_envmap.archived``: a folder whose ``farfield`` package is the ``core/`` of ``revision``."""
    import bench_envmap

    return bench_envmap.archived(revision, folder)


def bake_in_process(name: str, root: Path | None, flag: str = "--bake") -> dict:
    """:func:`one_bake` (``flag`` ``--cpu``: :func:`cpu_stages`) in a fresh process, with this
    tree's ``farfield`` or ``root``'s."""
    env = dict(os.environ)
    if root is not None:
        env["PYTHONPATH"] = os.pathsep.join([str(root), env.get("PYTHONPATH", "")])
    command = [sys.executable, str(Path(__file__).resolve()), flag, name]
    result = subprocess.run(command, check=True, capture_output=True, text=True, env=env, cwd=ROOT)
    return json.loads(result.stdout.strip().splitlines()[-1])


def cpu_table(names, against: str | None, repeat: int) -> list[dict]:
    """Part 4: each bake's CPU seconds per stage, this tree and (with ``against``) that revision alternately."""
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        codes = [("this tree", None)] + ([(against, archived(against, Path(folder)))] if against else [])
        for name in names:
            for run in range(repeat):
                for label, root in reversed(codes):
                    stages = bake_in_process(name, root, "--cpu")
                    rows.append({"bake": name, "code": label, "run": run, "stages": stages, "load": os.getloadavg()[0]})
                    shown = "  ".join(f"{k} {v:.3f}" for k, v in stages.items())
                    print(f"{name:<13} {label:<10} CPU s: {shown}   load {rows[-1]['load']:.1f}")
    return rows


def bakes(names, against: str | None, repeat: int) -> list[dict]:
    """Part 3: each bake in fresh processes, this tree and (with ``against``) that revision alternately."""
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        codes = [("this tree", None)] + ([(against, archived(against, Path(folder)))] if against else [])
        for name in names:
            runs: dict[str, list[dict]] = {label: [] for label, _ in codes}
            for _ in range(repeat):
                for label, root in reversed(codes):  # the revision first, then this tree
                    runs[label].append(bake_in_process(name, root))
            for label, _ in codes:
                rows.append({"bake": name, "code": label, **min(runs[label], key=lambda r: r["total_s"])})
                print_bake(rows[-1])
    return rows


def print_bake(row: dict) -> None:
    total = row["total_s"]
    parts = {**row["stages"], "bundle": row["bundle_s"]}
    shares = "  ".join(f"{k} {v:.3f} ({100 * v / total:.0f} %)" for k, v in parts.items() if k != "plan" or v > 0.0005)
    ratio = (
        f"   LDI cell / nine images: wall {row['ratio']:.2f} (nine {row['nine_images_s']:.3f} s), "
        f"CPU {row['ratio_cpu']:.2f} (nine {row['nine_images_cpu_s']:.3f} s)"
        if "ratio" in row
        else ""
    )
    print(
        f"{row['bake']:<13} {row['code']:<10} total {total:.3f} s (CPU {row['total_cpu_s']:.3f})  bundle {row['bundle_s']:.3f} s "
        f"(CPU {row['bundle_cpu_s']:.3f}, {row['pages']} pages, content {row['content']})  load {row['load']:.1f}{ratio}\n    {shares}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", action="append", choices=("gil", "encoding", "bakes", "cpu"))
    parser.add_argument("--against", help="git revision whose core/ bakes beside this tree's (part 3)")
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--bakes", nargs="+", choices=BAKES, default=list(BAKES))
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--bake", help=argparse.SUPPRESS)  # internal: one bake, JSON out
    parser.add_argument("--cpu", help=argparse.SUPPRESS)  # internal: one bake's CPU stages, JSON out
    args = parser.parse_args()
    if args.cpu:
        print(json.dumps(cpu_stages(args.cpu)))
        return
    if args.bake:
        print(json.dumps(one_bake(args.bake, 3 if args.bake.startswith("ldi") else 1)))
        return
    from farfield.core.impostor.png_pages import PNG_COMPRESS_LEVEL, PNG_STRATEGY
    from farfield.core.render.context import renderer_info

    info = renderer_info()
    print(
        f"renderer: {info.renderer} ({info.version}); pages encoded at level {PNG_COMPRESS_LEVEL}, strategy {PNG_STRATEGY}"
    )
    parts = args.only or ("gil", "encoding", "bakes", "cpu")
    report = {"renderer": info.renderer}
    if "gil" in parts:
        report["gil"] = gil()
        print("\n1. the GIL during a PNG encode: a pure-Python spinner's CPU seconds beside the work")
        for r in report["gil"]:
            print(
                f"   {r['work']:<26} wall {r['wall']:.3f} s  work CPU {r['work_cpu']:.3f} s  spinner CPU {r['spinner_cpu']:.3f} s  load {r['load']:.1f}"
            )
    if "encoding" in parts:
        print(
            "\n2. PNG encoding by zlib level and strategy (-1 Pillow's default, 1 Z_FILTERED, 3 Z_RLE): CPU s and bytes"
        )
        report["encoding"] = encoding(args.bakes)
        for r in report["encoding"]:
            print(f"   {r['pages_of']:<13} {r['pages']:>3} pages {r['raw_mib']:6.1f} MiB  level {r['level']} strategy {r['strategy']:>2}: "
                  f"CPU {r['cpu_s']:.3f} s ({r['cpu_ratio']:.2f}x)  {r['bytes'] / 1024:8.0f} KiB ({r['bytes_ratio']:.2f}x)")  # fmt: skip
    if "bakes" in parts:
        print(f"\n3. whole bakes by stage, bundle included (best of {args.repeat}, fresh processes)")
        report["bakes"] = bakes(args.bakes, args.against, args.repeat)
    if "cpu" in parts:
        print("\n4. each bake's stages in CPU seconds of the baking thread (fresh processes, alternately)")
        report["cpu"] = cpu_table(args.bakes, args.against, args.repeat)
    if args.json:
        print(json.dumps(report, indent=1, default=float))


if __name__ == "__main__":
    main()
