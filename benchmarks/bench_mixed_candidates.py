"""Layered-only against mixed (layered + simplified geometry) placement on a statue park (issue 57, item 3).

Usage: ``.venv/bin/python benchmarks/bench_mixed_candidates.py [--statues 4] [--subdivisions 7]
[--spacing 14] [--half 5 | --street X0,Z0,X1,Z1] [--resolution 256] [--fov 60] [--cpv-size 2.5] [--vdi-deg 22.5]
[--budget-share 0.3] [--cluster-triangles N] [--leaf-size 1] [--views 40] [--json OUT]``

The scene is :func:`farfield.core.procedural.statue_park` (``--statues`` bumpy statues of
``20 * 4**subdivisions`` triangles each, ``--spacing`` m apart on a grid around the origin); the view
space is the street-level square ``[-half, half]`` at 1.7 m between them (or ``--street``'s x-z
rectangle at 1.7 m).  The budget is
``--budget-share`` of the plain frame (the worst problem view's geometry by the builtin llvmpipe
model, found by planning at a vanishing budget).  Two placements with the same knobs: layered
candidates alone, and layered beside levels of detail (``PlacementSettings.lod``,
:mod:`farfield.core.placement.lod`).  Columns: planning seconds, CPVs (solved / unsolved), what was
chosen of each kind, estimated memory, and the share of ``--views`` random views (position in the view
space, direction on the sphere) within t_max by the placement's estimate (the lookup's CPV time).

Each placement's drawn impostors are listed, largest first (technique, elements, level of detail
and its triangles, memory, CPVs drawn in): where the memory goes.

Levels of detail need no bake: a placement with at most ``--max-bakes`` layered impostors has them
baked here, its database written and walked through the same views with the reference runtime
(:func:`farfield.core.quality.walkthrough.placement_walkthrough`): measured frames against t_max, the
plain geometry and the full scene (hole pixels, colour error).  A placement with more is not walked
(its bake is the time this benchmark cannot spend): its row has estimates only.  Everything runs on
this machine (CPU, Mesa llvmpipe); times are this machine's and its load's.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from farfield.core.impostor.database import ImpostorDatabase
from farfield.core.placement.cost_model import LLVMPIPE_MODEL
from farfield.core.placement.database import PlacementLookup, bake_placement, placement_index, write_placement_database
from farfield.core.placement.lod import LOD_TECHNIQUE
from farfield.core.placement.planner import PlacementSettings, place
from farfield.core.procedural import statue_park
from farfield.core.quality.walkthrough import placement_walkthrough, random_views


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--statues", type=int, default=4)
    ap.add_argument("--subdivisions", type=int, default=7)
    ap.add_argument("--spacing", type=float, default=14.0)
    ap.add_argument("--half", type=float, default=5.0)
    ap.add_argument(
        "--street",
        default=None,
        metavar="X0,Z0,X1,Z1",
        help="the view space's x-z rectangle instead of --half's square",
    )
    ap.add_argument("--resolution", type=int, default=256)
    ap.add_argument("--fov", type=float, default=60.0)
    ap.add_argument("--cpv-size", type=float, default=2.5)
    ap.add_argument("--vdi-deg", type=float, default=22.5)
    ap.add_argument("--budget-share", type=float, default=0.3)
    ap.add_argument("--cluster-triangles", type=int, default=None, help="default: a statue is one element")
    ap.add_argument("--leaf-size", type=int, default=1)
    ap.add_argument("--views", type=int, default=40)
    ap.add_argument(
        "--max-bakes",
        type=int,
        default=4,
        help="walk a placement if it has at most this many layered impostors to bake",
    )
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)

    scene = statue_park(args.statues, args.subdivisions, args.spacing)
    per_statue = scene.triangle_count // args.statues
    cluster = per_statue if args.cluster_triangles is None else args.cluster_triangles
    lo, hi = np.array([-args.half, 1.7, -args.half]), np.array([args.half, 1.7, args.half])
    if args.street:
        x0, z0, x1, z1 = (float(v) for v in args.street.split(","))
        lo, hi = np.array([x0, 1.7, z0]), np.array([x1, 1.7, z1])

    def settings(t_max: float, lod: bool) -> PlacementSettings:
        return PlacementSettings(t_max, LLVMPIPE_MODEL, options={"resolution": args.resolution, "fov_deg": args.fov},
                                 cpv_size=args.cpv_size, vdi_deg=args.vdi_deg, leaf_size=args.leaf_size,
                                 cluster_triangles=cluster, lod=lod)  # fmt: skip

    plain = place(scene, lo, hi, settings(1e-6, False)).summary["worst_before"]
    t_max = args.budget_share * plain
    print(f"statue park: {args.statues} statues x {per_statue:,} triangles = {scene.triangle_count:,}; elements of "
          f"<= {cluster:,} triangles; view space {lo.tolist()} .. {hi.tolist()}; {args.resolution} px, {args.fov:g} deg; "
          f"plain worst {plain:.3f} ms, t_max {t_max:.3f} ms ({args.budget_share:g} of it)", flush=True)  # fmt: skip
    positions, forwards = random_views(lo, hi, args.views, seed=7)
    rows, placements = [], {}
    for name, lod in (("layered", False), ("layered + lod", True)):
        start = time.perf_counter()
        result = place(scene, lo, hi, settings(t_max, lod))
        seconds = time.perf_counter() - start
        s = result.summary
        lookup = PlacementLookup(
            placement_index(result, [{"index": imp["id"], "state": "done", "bundle": None} for imp in result.impostors])
        )
        estimates = np.array([lookup.find(p, d).get("time_estimated") or 0.0 for p, d in zip(positions, forwards)])
        kinds = s.get("by_technique") or {
            result.parameters["technique"]: {"impostors": s["impostors"], "memory_bytes": s["memory_bytes"]}
        }
        row = {
            "placement": name, "plan_s": round(seconds, 1), "cpvs": s["cpvs"], "solved": s["cpvs_solved"], "unsolved": s["cpvs_unsolved"],
            "unsolvable": s["cpvs_unsolvable"], "candidates": s["candidates"], "memory_bytes": s["memory_bytes"],
            "by_kind": {k: {"count": v["impostors"], "memory_bytes": v["memory_bytes"]} for k, v in kinds.items()},
            "views_within_t_max_estimated": float(np.mean(estimates <= t_max * (1 + 1e-9))),
            "lod_nodes_simplified": s.get("lod_nodes_simplified", 0), "seconds": result.seconds,
        }  # fmt: skip
        rows.append(row)
        placements[name] = result
        print(json.dumps(row), flush=True)

    for name, result in placements.items():  # what each placement draws: where its memory goes
        drawn = sorted((imp for imp in result.impostors if imp["cpvs"]), key=lambda imp: -imp["memory_bytes"])
        print(f"{name}: {len(drawn)} drawn, largest first (technique, elements, level, triangles, MiB, CPVs)")
        for imp in drawn:
            print(f"  {imp['technique']} {','.join(imp['objects'])} {imp.get('level', '-')} {imp.get('triangles', '-')} "
                  f"{imp['memory_bytes'] / 2**20:.3f} {imp['cpvs']}")  # fmt: skip

    walks = {}
    for name, result in placements.items():
        layered_drawn = [imp for imp in result.impostors if imp["cpvs"] and imp["technique"] != LOD_TECHNIQUE]
        if len(layered_drawn) > args.max_bakes:
            print(f"{name}: {len(layered_drawn)} layered impostors to bake (> --max-bakes): not walked")
            continue
        start = time.perf_counter()
        baked = bake_placement(scene, result)  # its layered impostors (levels of detail need no bake)
        print(f"{name}: baked {len(baked)} layered impostors in {time.perf_counter() - start:.1f} s", flush=True)
        with tempfile.TemporaryDirectory() as tmp:
            root = write_placement_database(Path(tmp) / "db", result, baked)
            with ImpostorDatabase(root) as db:
                walks[name] = placement_walkthrough(scene, db, positions, forwards, repeats=3)["summary"]
        w = walks[name]
        print(
            json.dumps({f"{name} walkthrough": {k: v for k, v in w.items() if k != "over_t_max"}}, default=str),
            flush=True,
        )

    layered, both = rows
    print()
    print(
        "| placement | plan s | CPVs solved / unsolved | chosen | memory (est.) | views within t_max: est. / measured |"
    )
    print("|---|---|---|---|---|---|")
    for r in rows:
        chosen = ", ".join(f"{k} {v['count']}" for k, v in r["by_kind"].items())
        w = walks.get(r["placement"])
        measured = "not walked" if w is None else f"{100 * w['share_within_t_max']:.1f} %"
        print(f"| {r['placement']} | {r['plan_s']:.1f} | {r['solved']:,} / {r['unsolved']:,} | {chosen} | "
              f"{r['memory_bytes'] / 2**20:.3f} MiB | {100 * r['views_within_t_max_estimated']:.1f} % / {measured} |")  # fmt: skip
    if both["memory_bytes"] > 0:
        print(f"\nmemory layered-only / mixed: {layered['memory_bytes'] / both['memory_bytes']:.1f}x")
    if args.json:
        Path(args.json).write_text(
            json.dumps({"rows": rows, "walkthroughs": walks, "t_max": t_max, "plain": plain}, indent=1, default=str)
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
