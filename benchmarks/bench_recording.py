"""Layer recording (issue 29 item 3) before and after, measured side by side in one run.

Usage: ``.venv/bin/python benchmarks/bench_recording.py [--before REV] [--rounds N] [--no-envmap] [--json]``

Each case is timed in a fresh process with this tree's ``farfield`` and with the ``core/`` of git
revision ``--before`` (from ``git archive``, first on the import path; the benchmark code, scenes,
plans and bound are this tree's), alternating, ``--rounds`` times each; a process warms up once,
then keeps the best of 3 (of 2 for the envmap cell).  The table gives the best of all rounds per
tree, and whether the two trees recorded the same bytes.

- ``dense 512`` and ``dense 1024``: :func:`farfield.core.layering.recording.record_layers` of ``bench_layered.py``'s
  102,400-triangle object (vertex colours and a plain colour) from its speed cell, the plan a
  default bake records; beside it the lower bound of issue 29 item 3, one plain render of the
  object at the plan's texels plus the read-back of every layer (``bench_layered.lower_bound_s``).
- ``helmet 512`` (textured) and ``pine 512`` (alpha-cut foliage): the third-party scenes of
  ``../shared/scenes``, a 0.3-diameter cell 1.6 diameters away.
- ``envmap cell``: ``bake_envmap`` of ``bench_envmap.py``'s middle cell in its million-triangle
  city, 512 x 512 faces, 64 layers, six directions: total and record stage, and a hash of the
  pages and quads.

The renderer (llvmpipe or a GPU) is printed.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

SHARED_SCENES = ROOT.parent / "shared" / "scenes"
THIRD_PARTY = {"helmet": "damaged_helmet/DamagedHelmet.glb", "pine": "scrub_pine/scrubPine.obj"}


def _best(run, repeats: int = 3) -> tuple[float, object]:
    """Warm up once, then the best of ``repeats`` calls of ``run``: (seconds, its last result)."""
    result = run()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        result = run()
        times.append(time.perf_counter() - start)
    return min(times), result


def _digest(*arrays: np.ndarray) -> str:
    digest = hashlib.sha1()
    for a in arrays:
        digest.update(np.ascontiguousarray(a).tobytes())
    return digest.hexdigest()[:12]


def measure(envmap: bool) -> dict:
    """Every case in this process, with whichever ``farfield`` the import path gives."""
    from bench_layered import bake_plan, cell_before, dense_object, lower_bound_s

    from farfield.core.exchange import load_scene
    from farfield.core.layering.recording import record_layers
    from farfield.core.render.context import renderer_info

    cases = {"renderer": renderer_info().renderer}
    dense = dense_object()
    diameter = float(np.max(dense.bounds[1] - dense.bounds[0]))
    parts = [
        (f"dense {r}", dense, bake_plan(dense, cell_before(dense, 1.6 * diameter, 0.3 * diameter), r))
        for r in (512, 1024)
    ]
    for name, path in THIRD_PARTY.items():
        scene = load_scene(SHARED_SCENES / path)
        d = float(np.max(scene.bounds[1] - scene.bounds[0]))
        parts.append((f"{name} 512", scene, bake_plan(scene, cell_before(scene, 1.6 * d, 0.3 * d), 512)))
    for name, scene, plan in parts:
        seconds, recorded = _best(lambda scene=scene, plan=plan: record_layers(scene, plan))
        cases[name] = {
            "seconds": seconds,
            "layers": int(plan.count),
            "texels": [int(r) for r in plan.texture_resolution],
            "pairs": int(recorded.drawn_triangles.sum()),
            "digest": _digest(recorded.rgba),
        }
        if name.startswith("dense"):
            cases[name]["lower_bound_s"] = lower_bound_s(scene, plan, 3)
    if envmap:
        from bench_envmap import detailed_city, street_grid

        from farfield.core.techniques.envmap.technique import EnvmapOptions, bake_envmap

        city = detailed_city(36, 3)
        cells = street_grid(36)
        middle = cells[len(cells) // 2][1]
        options = EnvmapOptions(
            resolution=512, fov_deg=90.0, layers=64, directions=("+x", "-x", "+y", "-y", "+z", "-z")
        )
        bakes = []
        for _ in range(3):  # the first warms up
            start = time.perf_counter()
            imp = bake_envmap(city, middle, options)
            bakes.append((time.perf_counter() - start, imp))
        seconds, imp = min(bakes[1:], key=lambda pair: pair[0])
        cases["envmap cell"] = {
            "seconds": seconds,
            "record_s": min(b.stats["seconds"]["record"] for _, b in bakes[1:]),
            "layers": int(imp.stats["layers"]),
            "digest": _digest(*imp.pages, imp.payload.corners, imp.payload.uv),
        }
    return cases


def run_tree(revision: str | None, envmap: bool, work: Path) -> dict:
    """:func:`measure` in a fresh process: this tree's ``farfield``, or the ``core/`` of ``revision``."""
    env = dict(os.environ)
    if revision is not None:
        root = work / f"rev-{revision}"
        package = root / "farfield"
        if not package.exists():
            package.mkdir(parents=True)
            archive = subprocess.run(
                ["git", "archive", revision, "core"], check=True, capture_output=True, cwd=ROOT
            ).stdout
            with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
                tar.extractall(package, filter="data")
            (package / "__init__.py").write_text("")
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(root), env.get("PYTHONPATH", "")) if p)
        env["NUMBA_CACHE_DIR"] = str(root / "numba-cache")
    command = [sys.executable, str(Path(__file__).resolve()), "--measure"] + ([] if envmap else ["--no-envmap"])
    result = subprocess.run(command, capture_output=True, text=True, env=env, cwd=ROOT)
    if result.returncode != 0:
        sys.exit(f"bench_recording: the {revision or 'this tree'} process failed:\n{result.stderr[-3000:]}")
    return json.loads(result.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--before",
        default="db81940",
        help="git revision recorded beside this tree (default: db81940, before the slab.frag variants)",
    )
    parser.add_argument("--rounds", type=int, default=2, help="fresh processes per tree, alternating (default 2)")
    parser.add_argument(
        "--no-envmap", action="store_true", help="leave out the envmap cell (its city takes a while to build)"
    )
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--measure", action="store_true", help=argparse.SUPPRESS)  # internal: one tree, JSON out
    args = parser.parse_args()
    if args.measure:
        print(json.dumps(measure(not args.no_envmap)))
        return
    runs: dict[str, list[dict]] = {"before": [], "after": []}
    with tempfile.TemporaryDirectory() as work:
        for r in range(args.rounds):
            for tree, revision in (("before", args.before), ("after", None)):
                print(f"round {r + 1}/{args.rounds}: {tree} ...", file=sys.stderr, flush=True)
                runs[tree].append(run_tree(revision, not args.no_envmap, Path(work)))
    best = {
        tree: {
            name: min((run[name] for run in results), key=lambda case: case["seconds"])
            for name in results[0]
            if name != "renderer"
        }
        for tree, results in runs.items()
    }
    report = {"renderer": runs["after"][0]["renderer"], "before": args.before, "rounds": args.rounds, **best}
    if args.json:
        print(json.dumps(report, indent=1))
        return
    print(
        f"renderer: {report['renderer']}   before: {args.before}   best of {args.rounds} processes x 3 per tree (envmap: x 2)"
    )
    print(
        f"{'case':<12} {'layers':>6} {'texels':>10} {'pairs':>8} {'before s':>9} {'after s':>8} {'speed-up':>8} {'same bytes':>10} {'bound s':>8} {'before/bound':>12} {'after/bound':>11}"
    )
    for name, after in best["after"].items():
        before = best["before"][name]
        texels = "x".join(str(t) for t in after["texels"]) if "texels" in after else ""
        row = f"{name:<12} {after['layers']:>6} {texels:>10} {after.get('pairs', ''):>8} {before['seconds']:>9.3f} {after['seconds']:>8.3f} {before['seconds'] / after['seconds']:>7.2f}x {str(before['digest'] == after['digest']):>10}"
        if "lower_bound_s" in after:
            bound = min(before["lower_bound_s"], after["lower_bound_s"])
            row += f" {bound:>8.3f} {before['seconds'] / bound:>11.1f}x {after['seconds'] / bound:>10.1f}x"
        print(row)
        if "record_s" in after:
            print(
                f"{'':<12} record stage: before {before['record_s']:.3f} s, after {after['record_s']:.3f} s ({before['record_s'] / after['record_s']:.2f}x)"
            )


if __name__ == "__main__":
    main()
