"""Lit environment-map impostors: the normal channel's cost and what it buys on the procedural city.

Usage: ``.venv/bin/python benchmarks/bench_envmap_lit.py [--buildings N] [--cells K] [--resolution R] [--layers L] [--random N] [--json]``

For each of ``--cells`` cubic street cells (``--cell-size`` units, in the free square of a street
crossing: no building reaches into it, so no viewpoint sees a wall from inside its box) of :func:`farfield.core.procedural.city` (flat
façades, no vertex normals: the recorded normals are face normals), one envmap bake with
``channels=albedo`` and one with ``channels=albedo+normal`` of the same cell, side by side in one run
(bake seconds and the record stage's, memory per channel set: macrotexture bytes and PNG bytes of
each page set); then the lit evaluation of the normal bake
(:func:`farfield.core.techniques.envmap.lit.evaluate_envmap_lit`: the far field beyond the near
field, five test lights incl. a grazing one) from the cell's corners, centre and ``--random`` seeded
points, along every face axis and the diagonals: unlit, lit and flat-card colour errors per light,
the two ratios of issue 55's targets (lit / unlit <= 1.5 under every light; flat / lit >= 2) and
the normal error.  The renderer (llvmpipe or a GPU) is printed.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from farfield.core import procedural  # noqa: E402
from farfield.core.impostor.glb import page_png  # noqa: E402
from farfield.core.quality.lit import lit_figures  # noqa: E402
from farfield.core.render.context import renderer_info  # noqa: E402
from farfield.core.techniques.envmap.lit import evaluate_envmap_lit  # noqa: E402
from farfield.core.techniques.envmap.technique import EnvmapOptions, bake_envmap  # noqa: E402
from farfield.core.viewcells import BoxCell  # noqa: E402

# Street crossings of the city's 20-unit lot grid: buildings are at most 16 wide, so a square of
# 4 around each crossing is free.  Cells float half a unit above the ground.
CROSSINGS = ((170.0, 170.0), (130.0, 150.0), (90.0, 110.0), (210.0, 130.0))


def run(buildings: int, cells: int, size: float, resolution: int, layers: int, random_count: int) -> list[dict]:
    scene = procedural.city(buildings)
    for channels in ("albedo", "albedo+normal"):  # warm-up: kernels, shader variants, the GL context
        bake_envmap(scene, BoxCell.from_center((170.0, 2.5, 170.0), 4.0), EnvmapOptions(resolution=16, layers=4,
                                                                                          channels=channels))  # fmt: skip
    rows = []
    for x, z in CROSSINGS[:cells]:
        centre = (x, 0.5 + 0.5 * size, z)
        cell = BoxCell.from_center(centre, size)
        for obj in scene.objects[1:]:  # the buildings: none may reach into the cell
            lo, hi = obj.bounds
            if np.all(lo < cell.hi) and np.all(hi > cell.lo):
                raise SystemExit(f"cell {centre} of size {size} reaches into {obj.name}: give a smaller --cell-size")
        bakes = {}
        for channels in ("albedo", "albedo+normal"):
            start = time.perf_counter()
            impostor = bake_envmap(scene, cell, EnvmapOptions(resolution=resolution, layers=layers, channels=channels))
            bakes[channels] = (impostor, time.perf_counter() - start)
        plain, lit = bakes["albedo"][0], bakes["albedo+normal"][0]
        normal_pages = lit.channels["normal"]
        result = evaluate_envmap_lit(scene, lit, random_count=random_count)
        t = result.totals
        rows.append(
            {
                "cell": list(centre),
                "triangles": scene.triangle_count,
                "quads": lit.stats["quads"],
                "near_field": lit.stats["near_field"],
                "bake_s_albedo": bakes["albedo"][1],
                "bake_s_normal": bakes["albedo+normal"][1],
                "record_s_albedo": plain.stats["seconds"]["record"],
                "record_s_normal": lit.stats["seconds"]["record"],
                "kib_albedo": plain.texture_bytes / 1024,
                "kib_normal": sum(p.nbytes for p in normal_pages) / 1024,
                "png_kib_albedo": plain.stats["png_bytes"] / 1024,
                "png_kib_normal": sum(len(page_png(p)) for p in normal_pages) / 1024,
                "same_colour": all(np.array_equal(a, b) for a, b in zip(plain.pages, lit.pages, strict=True)),
                "views": t["viewpoints"],
                **lit_figures(result),
            }
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--buildings", type=int, default=300)
    parser.add_argument("--cells", type=int, default=3, choices=range(1, len(CROSSINGS) + 1))
    parser.add_argument("--cell-size", type=float, default=4.0)
    parser.add_argument("--resolution", type=int, default=256)
    parser.add_argument("--layers", type=int, default=32)
    parser.add_argument("--random", type=int, default=0)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    rows = run(args.buildings, args.cells, args.cell_size, args.resolution, args.layers, args.random)
    if args.json:
        print(json.dumps(rows, indent=1))
        return
    print(f"renderer: {renderer_info()}; city of {args.buildings} buildings ({rows[0]['triangles']} triangles), "
          f"envmap {args.resolution} px, {args.layers} layers, 6 faces, cells of {args.cell_size:g}")  # fmt: skip
    print(f"{'cell':<16} {'quads':>6} {'bake s':>7} {'+n s':>6} {'rec s':>6} {'+n rec':>6} {'KiB':>6} {'+n KiB':>7} "
          f"{'PNG KiB':>8} {'+n PNG':>7} {'same rgb':>8}")  # fmt: skip
    for r in rows:
        cell = ",".join(f"{c:g}" for c in r["cell"])
        print(f"{cell:<16} {r['quads']:>6} {r['bake_s_albedo']:>7.2f} {r['bake_s_normal']:>6.2f} {r['record_s_albedo']:>6.2f} "
              f"{r['record_s_normal']:>6.2f} {r['kib_albedo']:>6.0f} {r['kib_normal']:>7.0f} {r['png_kib_albedo']:>8.0f} "
              f"{r['png_kib_normal']:>7.0f} {'yes' if r['same_colour'] else 'NO':>8}")  # fmt: skip
    print(f"\n{'cell':<16} {'views':>5} {'unlit':>6} {'lit':>6} {'flat':>6} {'lit/unlit':>9} {'flat/lit':>8} "
          f"{'n med':>6} {'n p95':>6} {'in med':>6} {'in p95':>6} {'flat n':>6} {'eval s':>7}")  # fmt: skip
    for r in rows:
        cell = ",".join(f"{c:g}" for c in r["cell"])
        worst = max(r["lights"], key=lambda row: row["lit_error_mean"])
        print(f"{cell:<16} {r['views']:>5} {worst['unlit_error_mean']:>6.2f} {worst['lit_error_mean']:>6.2f} "
              f"{max(x['flat_error_mean'] for x in r['lights']):>6.2f} {r['lit_to_unlit_worst']:>9.2f} "
              f"{r['flat_to_lit_least']:>8.2f} {r['normal_median']:>6.1f} {r['normal_p95']:>6.1f} "
              f"{r['normal_interior_median']:>6.1f} {r['normal_interior_p95']:>6.1f} {r['flat_normal_median']:>6.1f} "
              f"{r['eval_s']:>7.1f}")  # fmt: skip
    print("\nper light, pooled over cells (mean levels 0-255 where both cover): lit / flat / unlit")
    for k in range(len(rows[0]["lights"])):
        lit = np.mean([r["lights"][k]["lit_error_mean"] for r in rows])
        flat = np.mean([r["lights"][k]["flat_error_mean"] for r in rows])
        unlit = np.mean([r["lights"][k]["unlit_error_mean"] for r in rows])
        print(f"  light {k}: {lit:6.2f} {flat:6.2f} {unlit:6.2f}")


if __name__ == "__main__":
    main()
