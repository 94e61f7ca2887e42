"""A textured depth mesh at scale (issue "Cost that grows with what the scene needs", item 2): the
stages of one large bake, the atlas packer before and after on that bake's own charts, and what a
fresh worker pays for the numba kernels.

Usage: ``.venv/bin/python benchmarks/bench_tdm_scale.py [--scene dense|scan] [--subdivisions 7]
[--before REV] [--before-limit SECONDS] [--no-warm] [--json]``, or
``.venv/bin/python benchmarks/bench_tdm_scale.py --scene scan --bake-before REV [--rounds 2]``.

Scenes: **dense** (default), ``tests/scenes.py::dense_mesh`` from the cell below; **scan**,
``tests/scenes.py::scan_mesh`` (351,682 triangles of ridged multi-octave noise down to below the
voxel, creases and 24 holes: a laser scan's character) from the *large near cell* of issue 60: a
cube of side 2 whose far face lies 1.5 units in front of it, which plans 363 layers, over a
million voxels and some 9 M initial triangles, as the issue's 346k-triangle scan did.

``--bake-before REV``: instead of 1-3, the whole bake of the scene by ``core/techniques/tdm/`` as
it is and as it was at ``REV`` (its files loaded from ``git show`` in place of the package, the rest
of the tree as it is), each in a fresh process with its numba kernels loaded first, ``--rounds``
times in turns (before, after, before, after): each stage's seconds, the triangles, charts, bytes,
the process's peak resident memory, and the holes and bloat of the job report's evaluation
(``report_part``: the reference viewpoint and three cell corners, 2 samples per pixel side).

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

from scenes import dense_mesh, scan_mesh  # noqa: E402

from farfield.core.render.context import gl_context, renderer_info  # noqa: E402
from farfield.core.techniques.tdm import technique as tdm_module  # noqa: E402
from farfield.core.techniques.tdm.technique import TdmOptions, bake_tdm  # noqa: E402
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


# Loads the tdm package of another revision (a folder in ``source``) in place of this tree's; the
# subprocess scripts below (and bench_tdm_cascade.py's) set ``source`` first.
LOAD_REVISION = """
if source:  # the tdm package of another revision, loaded in place of this tree's
    name = "farfield.core.techniques.tdm"

    class Before:
        def find_spec(self, full, path=None, target=None):
            if full == name:
                return importlib.util.spec_from_file_location(full, source + "/__init__.py", submodule_search_locations=[source])
            if full.startswith(name + "."):
                return importlib.util.spec_from_file_location(full, source + "/" + full.rsplit(".", 1)[1] + ".py")
            return None

    sys.meta_path.insert(0, Before())
"""

BAKE = (
    """
import importlib.util, json, resource, sys, time
source = sys.argv[3]
"""
    + LOAD_REVISION
    + """sys.path.insert(0, "benchmarks")
sys.path.insert(0, "tests")
from bench_tdm_scale import scene_and_cell
from farfield.core.render.context import gl_context
from farfield.core.techniques.part import report_part
from farfield.core.techniques.tdm.technique import TdmOptions, bake_tdm, warm_kernels
import farfield.core.techniques.tdm.technique as technique
from farfield.core.layering import recording
assert (not source) == (not technique.__file__.startswith(source or "?")), technique.__file__
recording.warm_kernels()  # the recording's kernels too, as a worker does (TECHNIQUE.kernels): not in the record stage
warm_kernels()
scene, cell = scene_and_cell(sys.argv[1], int(sys.argv[2]))
with gl_context():
    cpu = time.process_time()
    impostor = bake_tdm(scene, cell, TdmOptions())
    cpu = time.process_time() - cpu
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    report = report_part(scene, impostor)
s = impostor.stats
print(json.dumps({"peak_mib": peak, "cpu_seconds": cpu, "report": report, **{k: s[k] for k in (
    "layers", "voxels", "initial_triangles", "triangles", "texture_charts", "atlas_pages", "texture_bytes", "geometry_bytes", "seconds")}}))
"""
)


def scene_and_cell(name: str, subdivisions: int = 7):
    """The benchmark's scene and view cell (see the module docstring)."""
    if name == "scan":
        scene = scan_mesh()
        return scene, close_cell(scene, 2.0, 1.5)
    scene = dense_mesh(subdivisions)
    return scene, close_cell(scene)


def bake_in_process(scene: str, subdivisions: int, source: str | None) -> dict:
    """One whole bake (and its evaluation) in a fresh process, by the tdm package in the folder
    ``source`` (None: this tree's)."""
    out = subprocess.run(
        [sys.executable, "-c", BAKE, scene, str(subdivisions), source or ""],
        check=True, capture_output=True, text=True, cwd=ROOT,
    )  # fmt: skip
    return json.loads(out.stdout.strip().splitlines()[-1])


def bakes_before_after(args) -> None:
    """``--bake-before``: whole bakes by the tdm package of ``args.bake_before`` and of this tree."""
    folder = Path(tempfile.gettempdir()) / f"farfield_tdm_{args.bake_before}"  # kept: numba caches there
    folder.mkdir(exist_ok=True)
    names = subprocess.run(
        ["git", "ls-tree", "--name-only", args.bake_before, "core/techniques/tdm/"],
        check=True, capture_output=True, text=True, cwd=ROOT,
    ).stdout.split()  # fmt: skip
    for path in names:
        text = subprocess.run(["git", "show", f"{args.bake_before}:{path}"], check=True, capture_output=True, text=True, cwd=ROOT).stdout  # fmt: skip
        target = folder / Path(path).name
        if not target.exists() or target.read_text() != text:
            target.write_text(text)
    runs = {"before": [], "after": []}
    for _ in range(args.rounds):
        runs["before"].append(bake_in_process(args.scene, args.subdivisions, str(folder)))
        runs["after"].append(bake_in_process(args.scene, args.subdivisions, None))
    if args.json:
        print(json.dumps(runs, indent=2))
        return
    print(f"renderer: {renderer_info().renderer}; load average at the end {os.getloadavg()[0]:.2f}")
    print(f"\n## Whole bakes of the {args.scene} scene: before = {args.bake_before}, after = this tree, in turns")
    columns = [(f"{args.bake_before} #{i + 1}", r) for i, r in enumerate(runs["before"])] + [
        (f"this tree #{i + 1}", r) for i, r in enumerate(runs["after"])
    ]
    print("| | " + " | ".join(c for c, _ in columns) + " |\n|---|" + "---:|" * len(columns))
    stages = [k for k in dict.fromkeys(k for _, r in columns for k in r["seconds"]) if k != "total"]
    for stage in stages:
        print(f"| {stage} s | " + " | ".join(f"{r['seconds'].get(stage, 0.0):.1f}" for _, r in columns) + " |")
    print("| total s | " + " | ".join(f"**{r['seconds']['total']:.1f}**" for _, r in columns) + " |")
    print("| CPU s of the bake (all threads) | " + " | ".join(f"{r['cpu_seconds']:.1f}" for _, r in columns) + " |")
    rows = [("layers", lambda r: r["layers"]), ("voxels", lambda r: r["voxels"]),
            ("initial triangles", lambda r: r["initial_triangles"]), ("triangles kept", lambda r: r["triangles"]),
            ("charts", lambda r: r["texture_charts"]), ("pages", lambda r: r["atlas_pages"]),
            ("texture MiB", lambda r: f"{r['texture_bytes'] / 2**20:.1f}"), ("geometry MiB", lambda r: f"{r['geometry_bytes'] / 2**20:.1f}"),
            ("peak resident MiB", lambda r: f"{r['peak_mib']:,.0f}"),
            ("hole pixels (4 views)", lambda r: r["report"]["hole_pixels"]), ("bloat beyond 1 px", lambda r: r["report"]["bloat_beyond_1px"]),
            ("colour error mean", lambda r: f"{r['report']['colour_error_mean']:.2f}"), ("ssim", lambda r: f"{r['report']['ssim']:.3f}")]  # fmt: skip
    for label, value in rows:
        print(
            f"| {label} | "
            + " | ".join(f"{value(r):,}" if isinstance(value(r), int) else str(value(r)) for _, r in columns)
            + " |"
        )


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
    parser.add_argument("--scene", choices=("dense", "scan"), default="dense", help="the mesh and cell (see above)")
    parser.add_argument("--subdivisions", type=int, default=7, help="icosphere subdivisions (7: 327,680 triangles)")
    parser.add_argument("--bake-before", default=None, help="git revision: whole bakes before and after instead")
    parser.add_argument("--rounds", type=int, default=1, help="rounds of --bake-before's bakes, in turns")
    parser.add_argument("--before", default="85137ad", help="git revision of the packer to compare against")
    parser.add_argument("--before-limit", type=float, default=900.0, help="seconds the old packer may take")
    parser.add_argument(
        "--no-warm", action="store_true", help="skip the fresh-worker measurement (it compiles for ~40 s)"
    )
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    if args.bake_before:
        bakes_before_after(args)
        return

    info = renderer_info()
    for warm in tdm_module.TECHNIQUE.kernels:  # numba compiles (or loads) its kernels here, not in a stage of the bake
        warm()
    scene, cell = scene_and_cell(args.scene, args.subdivisions)
    options = TdmOptions()
    impostor, masks = bake_with_masks(scene, cell, options)
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
        f"\n## The bake: {'scan_mesh(), 2-unit cell 1.5 units' if args.scene == 'scan' else f'dense_mesh({args.subdivisions}), 1-unit cell 2 units'} in front, {report['triangles_in']:,} triangles, 512 px, f = 2"
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
