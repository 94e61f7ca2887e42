"""A textured depth mesh at scale (issue "Cost that grows with what the scene needs", item 2): the
stages of one large bake, the atlas packer before and after on that bake's own charts, and what a
fresh worker pays for the numba kernels.

Usage: ``.venv/bin/python benchmarks/bench_tdm_scale.py [--subdivisions 7] [--before REV]
[--before-limit SECONDS] [--no-warm] [--json]``

1. **The bake**: ``tests/scenes.py::dense_mesh`` (a bumpy icosphere of radius 1, 327,680
   triangles at 7 subdivisions: the size of the 346k-triangle scan the issue measured) from a
   cubic cell of side 1 whose far face lies 2 units in front of it, 512 px, 45°, f = 2: its layers,
   voxels, charts, triangles, memory and the seconds of each stage (``Impostor.stats``).
2. **The packer, before and after**: the bake's chart masks packed by ``core/techniques/tdm/mask_atlas.py`` as it
   is and as it was at git revision ``--before`` (loaded from ``git show``), each in a fresh
   process, the old one stopped after ``--before-limit`` seconds.  Both must give the same layout;
   the table says whether they did.
3. **A fresh worker's first cell** (unless ``--no-warm``): ``warm_kernels`` in a process with an
   empty numba cache (what the first worker of a new install pays at its start), then with the cache
   it filled (what every later worker pays), then a tiny TDM bake in a process that warmed first and
   one that did not.

Every figure comes from this run; the renderer (llvmpipe or a GPU) is printed.  The numba kernels
are compiled (or loaded) before the bake, outside its stages.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from scenes import dense_mesh  # noqa: E402

from farfield.core.render.context import gl_context, renderer_info  # noqa: E402
from farfield.core.techniques import tdm as tdm_module  # noqa: E402
from farfield.core.techniques.tdm.technique import TdmOptions, bake_tdm, warm_kernels  # noqa: E402
from farfield.core.viewcells import BoxCell  # noqa: E402

PACK = """
import importlib.util, pickle, sys, time
masks, padding, max_page, source = pickle.load(open(sys.argv[1], "rb"))
if source is None:
    from farfield.core.techniques.tdm.mask_atlas import pack_masks
else:
    spec = importlib.util.spec_from_file_location("mask_atlas_before", source)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    pack_masks = module.pack_masks
pack_masks(masks[:50], padding, max_page)  # compile (or load) its kernels outside the timing
start = time.perf_counter()
layout = pack_masks(masks, padding, max_page)
seconds = time.perf_counter() - start
pickle.dump((seconds, layout.page.tolist(), layout.x.tolist(), layout.y.tolist(), layout.page_sizes.tolist()), open(sys.argv[2], "wb"))
"""

FIRST_CELL = """
import sys, time
import numpy as np
from farfield.core.procedural import city
from farfield.core.render.context import gl_context
from farfield.core.techniques.tdm.technique import TdmOptions, bake_tdm, warm_kernels
warm = warm_kernels() if sys.argv[1] == "warm" else 0.0
scene = city(4)
lo, hi = scene.bounds
from farfield.core.viewcells import BoxCell
with gl_context():
    start = time.perf_counter()
    bake_tdm(scene, BoxCell(np.array([lo[0] - 60, lo[1], lo[2]]), np.array([lo[0] - 40, lo[1] + 20, lo[2] + 20])), TdmOptions(resolution=64))
    print(warm, time.perf_counter() - start)
"""


def close_cell(scene, size: float = 1.0, distance: float = 2.0) -> BoxCell:
    lo, hi = scene.bounds
    c = 0.5 * (lo + hi)
    return BoxCell(
        np.array([c[0] - size / 2, c[1] - size / 2, lo[2] - distance - size]),
        np.array([c[0] + size / 2, c[1] + size / 2, lo[2] - distance]),
    )


def bake_with_masks(scene, cell, options: TdmOptions):
    """The bake, and the chart masks it packed (caught on their way to the packer)."""
    caught = {}
    real = tdm_module.pack_masks

    def catch(masks, padding, max_page):
        caught["masks"] = [np.asarray(m, dtype=bool) for m in masks]
        return real(masks, padding, max_page)

    tdm_module.pack_masks = catch
    try:
        with gl_context():
            impostor = bake_tdm(scene, cell, options)
    finally:
        tdm_module.pack_masks = real
    return impostor, caught["masks"]


def pack_in_process(masks, options: TdmOptions, source: str | None, limit: float) -> dict:
    """Pack ``masks`` in a fresh process with the packer of ``source`` (None: the current one)."""
    with tempfile.TemporaryDirectory() as tmp:
        given, result = Path(tmp) / "in.pkl", Path(tmp) / "out.pkl"
        if source is not None:
            (Path(tmp) / "mask_atlas_before.py").write_text(source)
        given.write_bytes(
            pickle.dumps(
                (
                    masks,
                    options.padding,
                    options.max_page,
                    None if source is None else str(Path(tmp) / "mask_atlas_before.py"),
                )
            )
        )
        try:
            subprocess.run([sys.executable, "-c", PACK, str(given), str(result)], check=True, timeout=limit, cwd=ROOT)
        except subprocess.TimeoutExpired:
            return {"seconds": None, "limit": limit}
        seconds, page, x, y, sizes = pickle.loads(result.read_bytes())
    return {"seconds": seconds, "layout": (page, x, y, sizes), "page_area": int(sum(w * h for w, h in sizes))}


def first_cell(mode: str, env: dict) -> tuple[float, float]:
    out = subprocess.run(
        [sys.executable, "-c", FIRST_CELL, mode], check=True, capture_output=True, text=True, env=env, cwd=ROOT
    )
    warm, bake = (float(v) for v in out.stdout.split()[-2:])
    return warm, bake


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subdivisions", type=int, default=7, help="icosphere subdivisions (7: 327,680 triangles)")
    parser.add_argument("--before", default="85137ad", help="git revision of the packer to compare against")
    parser.add_argument("--before-limit", type=float, default=900.0, help="seconds the old packer may take")
    parser.add_argument(
        "--no-warm", action="store_true", help="skip the fresh-worker measurement (it compiles for ~40 s)"
    )
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()

    info = renderer_info()
    warm_kernels()  # numba compiles (or loads) its kernels here, not in a stage of the bake
    scene = dense_mesh(args.subdivisions)
    options = TdmOptions()
    impostor, masks = bake_with_masks(scene, close_cell(scene), options)
    s = impostor.stats
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # MiB (Linux reports KiB)
    report = {"renderer": info.renderer, "peak_mib": peak, "triangles_in": int(sum(len(o.faces) for o in scene.objects)), "stats": {k: s[k] for k in (
        "layers_planned", "layers", "voxels", "initial_triangles", "triangles", "texture_charts", "atlas_pages", "texture_bytes", "geometry_bytes", "texture_resolution", "seconds")}}  # fmt: skip

    before_source = subprocess.run(
        ["git", "show", f"{args.before}:core/techniques/tdm/mask_atlas.py"],
        check=True,
        capture_output=True,
        text=True,
        cwd=ROOT,
    ).stdout
    after = pack_in_process(masks, options, None, 3600.0)
    before = pack_in_process(masks, options, before_source, args.before_limit)
    report["packer"] = {
        "charts": len(masks), "texels": int(sum(int(m.sum()) for m in masks)),
        "after_seconds": after["seconds"], "after_page_area": after["page_area"],
        "before_seconds": before["seconds"], "before_limit": args.before_limit, "before_page_area": before.get("page_area"),
        "same_layout": None if before["seconds"] is None else before["layout"] == after["layout"],
    }  # fmt: skip

    if not args.no_warm:
        with tempfile.TemporaryDirectory() as cache:
            env = {**os.environ, "NUMBA_CACHE_DIR": cache}
            cold = first_cell("cold", env)
            warm_cold_cache = first_cell("warm", {**os.environ, "NUMBA_CACHE_DIR": tempfile.mkdtemp(dir=cache)})
            cached = first_cell("cold", env)
            warmed = first_cell("warm", env)
        report["first_cell"] = {
            "empty cache, no warm-up: first bake": cold[1],
            "empty cache, warm-up at start": warm_cold_cache[0], "empty cache, then first bake": warm_cold_cache[1],
            "filled cache, no warm-up: first bake": cached[1],
            "filled cache, warm-up at start": warmed[0], "filled cache, then first bake": warmed[1],
        }  # fmt: skip

    if args.json:
        print(json.dumps(report, indent=2))
        return
    print(f"renderer: {info.renderer}")
    print(
        f"\n## The bake: dense_mesh({args.subdivisions}), {report['triangles_in']:,} triangles, 1-unit cell 2 units in front, 512 px, f = 2"
    )
    st = report["stats"]
    print(f"layers {st['layers']} (planned {st['layers_planned']}), texture {st['texture_resolution'][0]} x {st['texture_resolution'][1]}, voxels {st['voxels']:,}, "
          f"initial triangles {st['initial_triangles']:,}, kept {st['triangles']:,}, charts {st['texture_charts']:,}, pages {st['atlas_pages']}, "
          f"texture {st['texture_bytes'] / 2**20:.1f} MiB, geometry {st['geometry_bytes'] / 2**20:.1f} MiB; "
          f"peak resident memory of the process after the bake {report['peak_mib']:,.0f} MiB")  # fmt: skip
    print("| stage | seconds |\n|---|---:|")
    for stage, seconds in st["seconds"].items():
        print(f"| {stage} | {seconds:.1f} |")
    pk = report["packer"]
    old = f"{pk['before_seconds']:.1f}" if pk["before_seconds"] is not None else f"> {pk['before_limit']:.0f} (stopped)"
    print(f"\n## The packer on those {pk['charts']:,} charts ({pk['texels']:,} texels), each in a fresh process")
    print("| packer | seconds | page texels | same layout |\n|---|---:|---:|---|")
    print(
        f"| before ({args.before}) | {old} | {pk['before_page_area'] if pk['before_page_area'] is not None else '-'} | |"
    )
    print(
        f"| after | {pk['after_seconds']:.1f} | {pk['after_page_area']} | {pk['same_layout'] if pk['same_layout'] is not None else 'not known'} |"
    )
    if pk["before_seconds"] is not None:
        print(f"speed-up: {pk['before_seconds'] / pk['after_seconds']:.1f}x")
    if "first_cell" in report:
        print("\n## A fresh process's first TDM cell (city(4), 64 px), seconds")
        print("| case | seconds |\n|---|---:|")
        for case, seconds in report["first_cell"].items():
            print(f"| {case} | {seconds:.2f} |")


if __name__ == "__main__":
    main()
