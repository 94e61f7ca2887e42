"""A frame-time placement of a procedural forest with octahedral candidates allowed and not (issue 56, Measure).

Usage: ``.venv/bin/python benchmarks/bench_forest_placement.py [--trees 10000] [--prototypes 5] [--size 1000]
[--detail 8] [--frame-ms 6 | --primitives SHARE] [--altitude 2] [--octahedral grid=9,frame_resolution=16,padding=2]
[--walkthrough FRAMES] [--skip-plain] [--json OUT]``

The scene is :func:`farfield.core.procedural.tree_forest` (``--trees`` instances of ``--prototypes``
tree meshes on a ``--size`` m terrain plane; every tree an instance of its prototype).  The view
space is the forest's square inset by ``--inset`` of its side, flat at ``--altitude`` m (2: walking
through it; higher: flying over it).  Two placements with the builtin llvmpipe cost model, the same
knobs (``--resolution``, ``--fov``, ``--cpv-size``, ``--vdi-deg``, ``--cells``): layered candidates
alone; layered beside octahedral ones (``PlacementSettings.also``) on the forest with its
instancing dropped (every tree its own object: one atlas per octahedral impostor); and the same on
the instanced forest (every instance of a prototype shares its atlas: counted once).  Columns: planning seconds,
CPVs (solved / unsolved / unsolvable), impostors of each technique, estimated memory, candidates.

Whether the two placements chose the same impostors (technique, elements, view cell) is printed;
when they did, in the same problem views, the walkthrough is measured once and stands for both.

``--walkthrough FRAMES`` also walks a closed loop of FRAMES views through the view space
(:func:`farfield.core.quality.walkthrough.loop_path`): the impostors the path's CPVs draw are baked in
this process (the others are listed without a bundle), the placement database written, and
:func:`farfield.core.quality.walkthrough.placement_walkthrough` measures each frame against the plain
geometry and the full scene: the share of frames within t_max, hole pixels, baked memory of what the
path drew.  Everything runs on this machine (CPU, Mesa llvmpipe); times are this machine's.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from farfield.core.impostor.database import ImpostorDatabase
from farfield.core.options import parse_option_text
from farfield.core.placement.candidates import OUTSIDE_SPHERE
from farfield.core.placement.cost_model import LLVMPIPE_MODEL, primitive_model
from farfield.core.placement.database import (
    PlacementLookup,
    bake_impostor,
    placement_cells,
    placement_index,
    write_placement_database,
)
from farfield.core.placement.greedy import Greedy
from farfield.core.placement.planner import PlacementSettings, place
from farfield.core.procedural import tree_forest
from farfield.core.quality.walkthrough import loop_path, placement_walkthrough
from farfield.core.scene import Scene
from farfield.core.techniques import get_technique


def _octahedral(text: str) -> dict:
    options = get_technique("octahedral").Options
    values = {}
    for pair in filter(None, text.split(",")):
        name, _, value = pair.partition("=")
        values[name] = parse_option_text(options, name, value)
    return values


def walk(scene, placement, lo, hi, frames: int) -> dict:
    """Bake what the path draws, write the database, walk the path (module docstring)."""
    positions, forwards = loop_path(lo, hi, frames)
    doc = placement.to_dict()
    lookup = PlacementLookup(
        placement_index(doc, [{"index": imp["id"], "state": "done", "bundle": None} for imp in doc["impostors"]])
    )
    needed = sorted({int(i) for p, f in zip(positions, forwards) for i in lookup.find(p, f)["impostors"]})
    cluster = int(placement.elements["cluster_triangles"])
    start, baked = time.perf_counter(), {}
    for cell in placement_cells(placement):
        if cell["index"] in needed:
            baked[cell["index"]] = bake_impostor(scene, cell, cluster)
    bake_seconds = time.perf_counter() - start
    with tempfile.TemporaryDirectory() as folder:
        root = write_placement_database(Path(folder) / "db", placement, baked)
        with ImpostorDatabase(root) as db:
            result = placement_walkthrough(scene, db, positions, forwards, repeats=3)
    s = result["summary"]
    kinds = {}
    for impostor in baked.values():
        kinds[impostor.technique] = kinds.get(impostor.technique, 0) + 1
    return {
        "frames": frames, "baked": len(baked), "baked_by_technique": kinds, "bake_seconds": bake_seconds,
        "baked_bytes": int(sum(imp.texture_bytes for imp in baked.values())),
        "share_within_t_max": s["share_within_t_max"], "share_estimate_within_t_max": s["share_estimate_within_t_max"],
        "runtime_ms_p50": s["runtime_ms_p50"], "runtime_ms_max": s["runtime_ms_max"], "plain_ms_p50": s["plain_ms_p50"],
        "hole_pixels": int(sum(f.get("hole_pixels", 0) for f in result["frames"])),
        "geometry_pixels": int(sum(f.get("geometry_pixels", 0) for f in result["frames"])),
        "colour_error_mean": float(np.mean([f.get("colour_error_mean", 0.0) for f in result["frames"]])),
    }  # fmt: skip


def start_scores(state) -> dict:
    """Scores (saved ms per byte) before anything is chosen: the best shared atlas's as a group, the
    best octahedral candidate's alone (what the myopic rule ranked it by), and how many layered
    candidates score above the best group (scores only fall: a group below the candidates the greedy
    needs is never reached)."""
    greedy = Greedy(state.hierarchy, state.pv, state.cand, state.greedy.t_max)
    scores, _ = greedy.initial_ranks()
    layered = scores[state.cand.kind != OUTSIDE_SPHERE]
    alone = Greedy(state.hierarchy, state.pv, state.cand, state.greedy.t_max, groups=False).initial_ranks()[0]
    group = max((greedy.group_rank(int(a))[0] for a in greedy.atlases()), default=0.0)
    return {
        "best_group": float(group), "best_octahedral_alone": float(np.max(alone[state.cand.kind == OUTSIDE_SPHERE], initial=0.0)),
        "best_layered": float(np.max(layered, initial=0.0)), "layered_above_best_group": int(np.sum(layered > group)),
        "layered_positive": int(np.sum(layered > 0.0)),
    }  # fmt: skip


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trees", type=int, default=10_000)
    parser.add_argument("--prototypes", type=int, default=5)
    parser.add_argument("--size", type=float, default=1000.0)
    parser.add_argument("--detail", type=int, default=8)
    parser.add_argument("--seed", type=int, default=2)
    parser.add_argument("--altitude", type=float, default=2.0)
    parser.add_argument("--inset", type=float, default=0.2)
    parser.add_argument("--frame-ms", type=float, default=6.0)
    parser.add_argument(
        "--primitives",
        type=float,
        default=None,
        metavar="SHARE",
        help="bound every view's triangles by SHARE of the forest's instead of --frame-ms (the primitive model)",
    )
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--fov", type=float, default=60.0)
    parser.add_argument("--cpv-size", type=float, default=None, help="default: the view space's side / 4")
    parser.add_argument("--vdi-deg", type=float, default=22.5)
    parser.add_argument("--cells", default="both")
    parser.add_argument(
        "--leaf-size", type=int, default=4, help="elements per leaf of the object hierarchy (1: a node per tree)"
    )
    parser.add_argument("--octahedral", default="grid=9,frame_resolution=16,padding=2")
    parser.add_argument("--walkthrough", type=int, default=0, metavar="FRAMES")
    parser.add_argument(
        "--skip-plain", action="store_true", help="leave out the placement of the forest with its instancing dropped"
    )
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)

    scene = tree_forest(args.trees, args.prototypes, args.size, args.seed, args.detail)
    inset = args.inset * args.size
    lo = np.array([inset, args.altitude, inset])
    hi = np.array([args.size - inset, args.altitude, args.size - inset])
    cpv = args.cpv_size or float(hi[0] - lo[0]) / 4.0
    print(f"forest: {args.trees} trees of {args.prototypes} prototypes, {scene.triangle_count:,} triangles, {args.size:g} m; "
          f"view space {lo.tolist()} .. {hi.tolist()}; t_max {args.frame_ms} ms (builtin llvmpipe model) or primitives {args.primitives}; {args.resolution} px at "
          f"{args.fov:g} deg; CPVs {cpv:g} m x {args.vdi_deg:g} deg; cells {args.cells}; leaf size {args.leaf_size}; octahedral {args.octahedral}", flush=True)  # fmt: skip
    rows, first, first_solved = [], None, []
    if args.primitives is None:
        budget, model = args.frame_ms, LLVMPIPE_MODEL
    else:
        budget, model = args.primitives * scene.triangle_count, primitive_model()
    octahedral = {"octahedral": _octahedral(args.octahedral)}
    plain = Scene.from_objects(
        [replace(o, prototype=None, instance_matrix=None, local=None) for o in scene.objects], scene.source
    )
    for label, also, where in (
        ("layered", None, scene),
        ("layered + octahedral, no instancing", octahedral, plain),
        ("layered + octahedral, shared atlases", octahedral, scene),
    ):
        if args.skip_plain and where is plain:
            continue
        settings = PlacementSettings(t_max=budget, model=model, options={"resolution": args.resolution, "fov_deg": args.fov},
                                     also=also, cpv_size=cpv, vdi_deg=args.vdi_deg, cells=args.cells, leaf_size=args.leaf_size)  # fmt: skip
        start = time.perf_counter()
        placement = place(where, lo, hi, settings, keep_state=True)
        seconds = time.perf_counter() - start
        s = placement.summary
        by = s.get("by_technique") or {"layered": {"impostors": s["impostors"], "memory_bytes": s["memory_bytes"]}}
        row = {
            "placement": label, "plan_seconds": seconds, "steps": placement.seconds, "cpvs": s["cpvs"], "solved": s["cpvs_solved"],
            "unsolved": s["cpvs_unsolved"], "unsolvable": s["cpvs_unsolvable"], "candidates": s["candidates"],
            "impostors": s["impostors"], "memory_bytes": s["memory_bytes"],
            "by_technique": {k: {"impostors": v["impostors"], "memory_bytes": v["memory_bytes"]} for k, v in by.items()},
            "shared_atlases": len(s.get("shared_atlases", [])),
            "octahedral_candidates": int(np.sum(placement.state.cand.kind == OUTSIDE_SPHERE)),
            "start_scores": start_scores(placement.state),
            "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,  # the process's so far
        }  # fmt: skip
        chosen = json.dumps(
            sorted(
                json.dumps([imp["technique"], imp["objects"], imp["cell"]], sort_keys=True)
                for imp in placement.impostors
                if imp["cpvs"]
            ),
            sort_keys=True,
        )
        row["same_as_layered"] = bool(rows) and chosen == rows[0]["chosen"]
        solved = [c["status"] == "solved" for c in placement.cpvs]
        # CPVs layered-only solves and this placement leaves unsolved (the same problem views: the same geometry)
        row["lost"] = sum(a and not b for a, b in zip(first_solved, solved)) if rows else 0
        first_solved = solved if not rows else first_solved
        if args.walkthrough:  # the same impostors drawn in the same CPVs walk the same: measured once
            same = row["same_as_layered"] and placement.cpvs == first.cpvs
            row["walkthrough"] = rows[0]["walkthrough"] if same else walk(where, placement, lo, hi, args.walkthrough)
        first = first if rows else placement
        row["chosen"] = chosen
        rows.append(row)
        print(json.dumps({k: v for k, v in row.items() if k != "chosen"}), flush=True)

    print(
        "\n| placement | plan s | CPVs solved / unsolved / unsolvable | solved by layered, not here | candidates | octahedral candidates | impostors (layered / octahedral) | atlases shared | memory MiB (octahedral) | peak RSS MiB (process, so far) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        oc = r["by_technique"].get("octahedral", {"impostors": 0, "memory_bytes": 0.0})
        la = r["by_technique"].get("layered", {"impostors": 0})
        print(f"| {r['placement']} | {r['plan_seconds']:.1f} | {r['solved']} / {r['unsolved']} / {r['unsolvable']} | {r['lost']} | {r['candidates']:,} | {r['octahedral_candidates']} | "
              f"{la['impostors']} / {oc['impostors']} | {r['shared_atlases']} | {r['memory_bytes'] / 2**20:.2f} ({oc['memory_bytes'] / 2**20:.2f}) | {r['peak_rss_mib']:.0f} |")  # fmt: skip
    if args.walkthrough:
        print(
            "\n| placement | frames within t_max | by the estimate | runtime ms p50 / max | plain ms p50 | hole pixels / geometry pixels | baked (octahedral) | baked MiB |"
        )
        print("|---|---|---|---|---|---|---|---|")
        for r in rows:
            w = r["walkthrough"]
            print(f"| {r['placement']} | {100 * w['share_within_t_max']:.0f} % | {100 * w['share_estimate_within_t_max']:.0f} % | "
                  f"{w['runtime_ms_p50']:.2f} / {w['runtime_ms_max']:.2f} | {w['plain_ms_p50']:.2f} | {w['hole_pixels']} / {w['geometry_pixels']} | "
                  f"{w['baked']} ({w['baked_by_technique'].get('octahedral', 0)}) | {w['baked_bytes'] / 2**20:.2f} |")  # fmt: skip
    print(
        f"\nthe same impostors chosen with octahedral candidates as without: {[r['same_as_layered'] for r in rows[1:]]}"
    )
    for r in rows[1:]:
        print(f"scores at the start, {r['placement']}: {r['start_scores']}")
    if args.json:
        rows = [{k: v for k, v in r.items() if k != "chosen"} for r in rows]
        args.json.write_text(json.dumps({"arguments": vars(args) | {"json": str(args.json)}, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
