"""The TDM simplification cascade alone on the scan-like surface (issue 60, item 4), before and after.

Usage: ``.venv/bin/python benchmarks/bench_tdm_cascade.py [--before REV] [--rounds 2] [--field PATH]``

The cascade (``technique.py::simplify_mesh``: every factor's passes to f = 2 in the strips, then
f = 2's on the whole mesh) is the largest stage of the scan's bake (``bench_tdm_scale.py --scene scan``), and a
whole bake (90 s or more) swings with this machine's load by more than a change to the cascade
saves.  So this runs the cascade only, on the scan's own initial mesh: the voxel field of
``bench_tdm_scale.py --scene scan``'s cell is recorded once (GL) and kept in ``--field`` (a pickle;
recorded again when missing), then each process builds ``initial_mesh`` from it and times
``simplify_mesh`` at f = 2, by ``core/techniques/tdm/`` as it was at ``--before`` (its files loaded
from ``git show`` in place of the package, as ``bench_tdm_scale.py --bake-before`` does) and as it
is, in fresh processes, in turns (before, after, before, after), with the numba kernels loaded
first.  Printed per process: CPU seconds of the cascade (``time.process_time``, all threads), wall
seconds, triangles kept, a hash of the output (triangles, voxel offsets, voxels: equal hashes, the
same mesh), the contraction outcomes and the load average.  Read the CPU seconds: at a load of
5-10 from other sessions the wall seconds follow the load.
"""

from __future__ import annotations

import argparse
import json
import pickle
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_tdm_scale import LOAD_REVISION  # noqa: E402  (the other revision's tdm package, in the subprocess)

RECORD = """
import math, pickle, sys
sys.path.insert(0, "benchmarks")
sys.path.insert(0, "tests")
from bench_tdm_scale import scene_and_cell
from farfield.core.layering.plan import plan_layers
from farfield.core.render.context import gl_context
from farfield.core.sidedness import seen_from_cell
from farfield.core.stage_clock import StageClock
from farfield.core.techniques.part import layer_budget
from farfield.core.techniques.tdm.technique import TdmOptions
from farfield.core.techniques.tdm.voxel_field import record_voxel_field
scene, cell = scene_and_cell("scan")
options = TdmOptions()
plan = plan_layers(cell, scene.bounds, math.radians(options.fov_deg), options.resolution, **layer_budget(options))
with gl_context():
    field = record_voxel_field(seen_from_cell(scene.objects, cell), plan, options.culling, StageClock(()), False, False)
pickle.dump(field, open(sys.argv[1], "wb"))
"""

CASCADE = (
    """
import hashlib, importlib.util, json, os, pickle, sys, time
source = sys.argv[2]
"""
    + LOAD_REVISION
    + """from farfield.core.techniques.tdm.mesh import initial_mesh
import farfield.core.techniques.tdm.technique as technique
assert (not source) == (not technique.__file__.startswith(source or "?")), technique.__file__
technique.warm_kernels()
field = pickle.load(open(sys.argv[1], "rb"))
mesh = initial_mesh(field)
silhouette = field.silhouette
cpu, wall = time.process_time(), time.perf_counter()
triangles, offsets, voxels, outcomes = technique.simplify_mesh(mesh, field, 2.0, silhouette)
cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
digest = hashlib.sha1(triangles.tobytes() + offsets.tobytes() + voxels.tobytes()).hexdigest()[:10]
print(json.dumps({"cpu": cpu, "wall": wall, "initial": int(mesh.triangles.shape[0]), "kept": int(triangles.shape[0]),
                  "hash": digest, "outcomes": outcomes, "load": os.getloadavg()[0]}))
"""
)


def package_at(revision: str) -> Path:
    """The files of ``core/techniques/tdm/`` at ``revision``, in a folder of their own (kept: numba
    caches its kernels beside them)."""
    folder = Path(tempfile.gettempdir()) / f"farfield_tdm_{revision}"
    folder.mkdir(exist_ok=True)
    listed = subprocess.run(
        ["git", "ls-tree", "--name-only", revision, "core/techniques/tdm/"],
        check=False, capture_output=True, text=True, cwd=ROOT,
    )  # fmt: skip
    names = listed.stdout.split() if listed.returncode == 0 else []
    if not names:
        sys.exit(f"bench_tdm_cascade: revision {revision!r} has no core/techniques/tdm/")
    for path in names:
        text = subprocess.run(["git", "show", f"{revision}:{path}"], check=True, capture_output=True, text=True, cwd=ROOT).stdout  # fmt: skip
        target = folder / Path(path).name
        if not target.exists() or target.read_text() != text:
            target.write_text(text)
    return folder


def cascade_in_process(field: Path, source: Path | None) -> dict:
    out = subprocess.run(
        [sys.executable, "-c", CASCADE, str(field), str(source or "")],
        check=True, capture_output=True, text=True, cwd=ROOT,
    )  # fmt: skip
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", default="HEAD", help="git revision of core/techniques/tdm/ to compare against")
    parser.add_argument("--rounds", type=int, default=2, help="rounds of (before, after), in turns")
    parser.add_argument("--field", type=Path, default=Path(tempfile.gettempdir()) / "farfield_tdm_scan_field.pkl")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    if args.rounds < 1:
        sys.exit("bench_tdm_cascade: --rounds must be at least 1")
    if not args.field.exists():
        subprocess.run([sys.executable, "-c", RECORD, str(args.field)], check=True, cwd=ROOT)
    with open(args.field, "rb") as f:
        voxels = pickle.load(f).count
    before = package_at(args.before)
    runs = []
    for _ in range(args.rounds):
        runs.append((args.before, cascade_in_process(args.field, before)))
        runs.append(("this tree", cascade_in_process(args.field, None)))
    if args.json:
        print(json.dumps([{"code": code, **run} for code, run in runs], indent=2))
        return
    print(
        f"## The cascade at f = 2 on the scan's initial mesh ({runs[0][1]['initial']:,} triangles, {voxels:,} voxels)"
    )
    print(
        "| code | CPU s | wall s | load | kept | hash | attempts | ok | uncovered |\n|---|---:|---:|---:|---:|---|---:|---:|---:|"
    )
    for code, r in runs:
        o = r["outcomes"]
        print(f"| {code} | {r['cpu']:.1f} | {r['wall']:.1f} | {r['load']:.1f} | {r['kept']:,} | {r['hash']} | "
              f"{sum(o.values()):,} | {o['ok']:,} | {o['uncovered']:,} |")  # fmt: skip


if __name__ == "__main__":
    main()
