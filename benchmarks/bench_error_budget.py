"""The speed/accuracy knob: error budget (``max_error_px``) -> layers, memory, bake time, measured error.

Usage: ``.venv/bin/python benchmarks/bench_error_budget.py [--resolution R] [--table-4-1] [--json]``

For each technique with a guarantee (layered, tdm, points, envmap) and each budget (1, 2, 4 pixels;
layered and tdm also seed 000's ``budget=thesis``), one bake of the same part and view cell (the
procedural house of seed 000 Table 4.1's stand-in, a 10 m box cell 60 m in front of it; envmap: a
city around a 10 m cubic cell), then the evaluation from the cell's corners, its reference
viewpoint and 8 seeded points inside it: hole pixels, pixels bloated beyond one pixel and beyond
the budget, colour error, and whether the technique's promise held at its budget.  The table is
``docs/measurements/error-budget.md``.  The renderer (llvmpipe or a GPU) is printed.

``--table-4-1``: seed 000 Table 4.1's layered rows instead (a building 45 m deep, 30 wide, 20 high,
the procedural house scaled to it; a cubic 100 m cell; 512 x 512 at 45°; distances 90 to 1000 m),
baked at the thesis's budget and at the strict one: layers, quads and memory beside the thesis's.
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
from farfield.core.render.context import renderer_info  # noqa: E402
from farfield.core.scene import Scene, SceneObject  # noqa: E402
from farfield.core.techniques import get_technique  # noqa: E402
from farfield.core.viewcells import BoxCell  # noqa: E402

BUDGETS = [{"max_error_px": 1.0}, {"max_error_px": 2.0}, {"max_error_px": 4.0}]
THESIS = {"budget": "thesis"}


def _memory(impostor) -> float:
    stats = impostor.stats
    return (stats.get("texture_bytes", 0) + stats.get("geometry_bytes", 0) + stats.get("point_bytes", 0)) / 1024.0


def run(resolution: int) -> list[dict]:
    house = procedural.house()
    lo, hi = house.bounds
    centre = 0.5 * (lo + hi)
    cell = BoxCell.from_center(centre + np.array([0.0, 0.0, 60.0]), 10.0)
    city = procedural.city(100)
    city_cell = BoxCell.from_center([170.0, 5.0, 170.0], 10.0)
    rows = []
    for name in ("layered", "tdm", "points", "envmap"):
        technique = get_technique(name)
        scene, where = (city, city_cell) if technique.scope == "scene" else (house, cell)
        settings = BUDGETS + ([THESIS] if name in ("layered", "tdm") else [])
        for values in settings:
            options = technique.options(values, resolution=resolution)
            start = time.perf_counter()
            impostor = technique.bake(scene, where, options, None, None)
            seconds = time.perf_counter() - start
            result = technique.evaluate(scene, impostor, 8, 0, 0)
            totals = result.totals if hasattr(result, "totals") else result["totals"]
            promise = technique.promise
            kept = not (promise.holes and totals["hole_pixels_beyond_budget"]) and not (
                promise.bloat and totals["bloat_beyond_budget"]
            )
            rows.append(
                {
                    "technique": name,
                    "setting": ", ".join(
                        f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in values.items()
                    ),
                    "layers": impostor.stats.get("layers"),
                    "memory_kib": round(_memory(impostor), 1),
                    "bake_s": round(seconds, 2),
                    "hole_pixels": totals["hole_pixels"],
                    "bloat_beyond_1px": totals["bloat_beyond_1px"],
                    "beyond_budget": totals["hole_pixels_beyond_budget"] + totals["bloat_beyond_budget"],
                    "colour_error_mean": round(totals["colour_error_mean"], 2),
                    "promise_kept": kept,
                }
            )
            print(_line(rows[-1]), flush=True)
    return rows


# Seed 000 Table 4.1, layered impostors: distance (m) -> (layers, polygons, memory kB).
TABLE_4_1 = {90: (110, 1176, 329), 110: (81, 700, 198), 140: (56, 372, 107), 180: (34, 178, 57.4),
             250: (19, 82, 25.5), 500: (5, 16, 4.5), 1000: (1, 2, 0.67)}  # fmt: skip


def table_4_1() -> list[dict]:
    """Table 4.1's layered rows at the thesis's budget and the strict one (module docstring)."""
    house = procedural.house()
    lo, hi = house.bounds
    target = np.array([45.0, 20.0, 30.0])  # depth along +x, height, width
    cell = BoxCell.from_center([0.0, 0.0, 0.0], 100.0)
    technique = get_technique("layered")
    rows = []
    for distance, (layers, polygons, memory) in TABLE_4_1.items():
        scale = target / (hi - lo)
        offset = np.array([50.0 + distance, -10.0, -15.0]) - lo * scale
        moved = Scene.from_objects(
            [SceneObject(o.name, o.vertices * scale + offset, o.faces, base_color=o.base_color) for o in house.objects],
            "house-45m",
        )
        for budget in ("thesis", "strict"):
            start = time.perf_counter()
            impostor = technique.bake(moved, cell, technique.options({"budget": budget}, resolution=512), None, None)
            rows.append(
                {
                    "distance_m": distance,
                    "budget": budget,
                    "layers": impostor.stats["layers"],
                    "quads": impostor.stats["quads"],
                    "memory_kb": round(_memory(impostor) * 1.024, 1),
                    "bake_s": round(time.perf_counter() - start, 2),
                    "thesis": {"layers": layers, "polygons": polygons, "memory_kb": memory},
                }
            )
            r = rows[-1]
            print(
                f"{distance:>5} {budget:<7} {r['layers']:>6} {layers:>6} {r['quads']:>7} {polygons:>7} "
                f"{r['memory_kb']:>9.1f} {memory:>9.2f} {r['bake_s']:>7.2f}",
                flush=True,
            )
    return rows


HEADER = f"{'technique':<9} {'setting':<22} {'layers':>6} {'memory KiB':>10} {'bake s':>7} {'holes':>6} {'>1px':>6} {'>budget':>7} {'err mean':>8}  promise"


def _line(r: dict) -> str:
    layers = "" if r["layers"] is None else r["layers"]
    return (
        f"{r['technique']:<9} {r['setting']:<22} {layers:>6} {r['memory_kib']:>10.1f} {r['bake_s']:>7.2f} "
        f"{r['hole_pixels']:>6} {r['bloat_beyond_1px']:>6} {r['beyond_budget']:>7} {r['colour_error_mean']:>8.2f}  "
        f"{'kept' if r['promise_kept'] else 'BROKEN'}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, default=256)
    parser.add_argument("--table-4-1", action="store_true", help="seed 000 Table 4.1's layered rows instead")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    info = renderer_info()
    resolution = 512 if args.table_4_1 else args.resolution
    print(f"renderer: {info.renderer} ({info.version}); resolution {resolution}, fov 45°", flush=True)
    if args.table_4_1:
        print(
            f"{'dist':>5} {'budget':<7} {'layers':>6} {'thesis':>6} {'quads':>7} {'thesis':>7} {'memory kB':>9} {'thesis':>9} {'bake s':>7}"
        )
        rows = table_4_1()
    else:
        print(HEADER, flush=True)
        rows = run(args.resolution)
    if args.json:
        print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
