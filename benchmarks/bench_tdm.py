"""Textured depth meshes (seed 003) and layered impostors of the same part, measured side by side.

Usage: ``.venv/bin/python benchmarks/bench_tdm.py [--quick] [--json] [--out DIR]``

1. Seed 000 Table 4.1 side by side: the building-like object of ``tests/scenes.py::house`` (the
   thesis's house model is not public), a cubic 100 m view cell, 512 x 512, 45°, distances
   90-1000 m between cell and model: layers, meshes, initial and final TDM triangles, TDM memory,
   layered quads and memory, generation time per stage of both, hole pixels and colour error of
   both (the same ``farfield.core.quality.evaluation.evaluate``: the cell's 8 corners, its centre and 4 random
   points).  Memory = texture + geometry as drawn (TDM an indexed mesh: 20 B per vertex of each
   texture chart + 12 B per triangle; layered 104 B per quad).  The TDM's texture is its atlas
   pages as stored (charts packed as masks, gaps included); the layered impostor's is counted two
   ways: its tiles alone (rectangles of kept texels, no padding: a lower bound no packer beats)
   and its atlas pages as stored (power-of-two pages); the TDM's also as its needed texels alone
   (each chart's texels, no gaps between charts: the same kind of lower bound).  Ratios are given
   like for like (lower bound against lower bound, pages against pages) and mixed (TDM pages
   against the layered lower bound).
2. The trade: the voxel enlargement factor 1.0-3.0 at 140 m against triangles, memory, generation
   time and image error, as a table and a plot (``tdm_trade.png``).
3. Which to use, part by part (seed 000 Table 4.2 tries other models): the test suite's scenes
   with cells near them (the same cells as ``tests/test_tdm.py``), both techniques evaluated alike
   and :func:`farfield.core.quality.comparison.choose` (fewest hole pixels, then least memory) naming the one to use.

The renderer (llvmpipe or a GPU) is printed.  numba kernels are compiled (and cached) by a warm-up
bake first, so their compile time is not in any row.  ``--quick`` uses 256 pixels and fewer rows.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from scenes import SHARED_SCENES, house  # noqa: E402
from test_bake import cell_in_front  # noqa: E402
from test_tdm import CASES as PARTS  # noqa: E402  (the test suite's parts and cells)

from farfield.core.quality.comparison import Candidate, choose  # noqa: E402
from farfield.core.quality.evaluation import evaluate  # noqa: E402
from farfield.core.render.context import gl_context, renderer_info  # noqa: E402
from farfield.core.techniques.layered import BakeOptions, bake_layered  # noqa: E402
from farfield.core.techniques.tdm.technique import TdmOptions, bake_tdm  # noqa: E402
from farfield.core.viewcells import BoxCell  # noqa: E402

DISTANCES = (90, 110, 140, 180, 250, 500, 1000)
FACTORS = (1.0, 1.25, 1.5, 1.75, 2.0, 2.5, 3.0)


def cell_before(scene, distance: float, size: float = 100.0) -> BoxCell:
    """A cubic cell of ``size`` centred on the part's x and y, ``distance`` in front of its z = min face."""
    lo, hi = scene.bounds
    c = 0.5 * (lo + hi)
    return BoxCell(
        np.array([c[0] - size / 2, c[1] - size / 2, lo[2] - distance - size]),
        np.array([c[0] + size / 2, c[1] + size / 2, lo[2] - distance]),
    )


def tdm_memory(stats: dict) -> int:
    """The TDM's atlas pages as stored and its geometry, bytes."""
    return int(stats["texture_bytes"] + stats["geometry_bytes"])


def measure(scene, cell, resolution: int, enlargement: float = 2.0) -> dict:
    tdm = bake_tdm(scene, cell, TdmOptions(resolution=resolution, enlargement=enlargement))
    layered = bake_layered(scene, cell, BakeOptions(resolution=resolution))
    ev_t = evaluate(scene, tdm, cell, random_count=4, seed=3).totals
    ev_l = evaluate(scene, layered, cell, random_count=4, seed=3).totals
    s, l = tdm.stats, layered.stats
    return {
        "layers": s["layers_planned"],
        "meshes": s["meshes"],
        "initial_triangles": s["initial_triangles"],
        "tdm_triangles": s["triangles"],
        "tdm_memory": tdm_memory(s),
        "tdm_texture_needed_bytes": s["texture_bytes_tile_area"],
        "tdm_memory_needed": int(s["texture_bytes_tile_area"] + s["geometry_bytes"]),
        "tdm_seconds": s["seconds"],
        "tdm_holes": ev_t["hole_pixels"],
        "tdm_colour_error": ev_t["colour_error_mean"],
        "tdm_colour_p99": ev_t["colour_error_p99"],
        "tdm_ssim": ev_t["ssim"],
        "tdm_bloat_beyond_1px": ev_t["bloat_beyond_1px"],
        "layered_quads": l["quads"],
        "layered_memory": int(l["texture_bytes_tile_area"] + l["geometry_bytes"]),
        "layered_memory_pages": int(l["texture_bytes"] + l["geometry_bytes"]),
        "layered_seconds": l["seconds"]["total"],
        "layered_holes": ev_l["hole_pixels"],
        "layered_colour_error": ev_l["colour_error_mean"],
        "layered_colour_p99": ev_l["colour_error_p99"],
        "layered_ssim": ev_l["ssim"],
        "layered_bloat_beyond_1px": ev_l["bloat_beyond_1px"],
        "geometry_pixels": ev_t["geometry_pixels"],
    }


def compare_part(name: str, resolution: int) -> dict:
    """Both techniques of one test part, evaluated alike, and the one :func:`choose` names."""
    factory, distance, size, lift = PARTS[name]
    scene = factory()
    diameter = float(np.max(scene.bounds[1] - scene.bounds[0]))
    cell = cell_in_front(scene, distance, size * diameter, lift=lift)
    tdm = bake_tdm(scene, cell, TdmOptions(resolution=resolution))
    layered = bake_layered(scene, cell, BakeOptions(resolution=resolution))
    candidates = [
        Candidate.of(i.technique, i, evaluate(scene, i, cell, random_count=4, seed=3)) for i in (tdm, layered)
    ]
    choice = choose(candidates)
    return {
        "triangles": scene.triangle_count, "layers": tdm.stats["layers_planned"], "candidates": [c.to_dict() for c in candidates],
        "choice": candidates[choice.index].name, "reason": choice.reason,
    }  # fmt: skip


def print_table(rows: dict) -> None:
    keys = list(rows)

    def line(label, fn):
        print(f"{label:<34}" + "".join(f"{fn(rows[k]):>11}" for k in keys))

    line("distance view cell to model (m)", lambda r: r["distance"])
    line("# layers", lambda r: r["layers"])
    line("# meshes", lambda r: r["meshes"])
    line("# triangles in initial meshes", lambda r: f"{r['initial_triangles']:,}")
    line("# triangles of TDM", lambda r: r["tdm_triangles"])
    line("memory of TDM, pages (kB)", lambda r: f"{r['tdm_memory'] / 1000:.1f}")
    line("memory of TDM, needed texels (kB)", lambda r: f"{r['tdm_memory_needed'] / 1000:.1f}")
    for stage in ("record", "mesh", "simplify", "charts", "atlas", "texture", "total"):
        line(f"TDM {stage} (s)", lambda r, st=stage: f"{r['tdm_seconds'].get(st, 0.0):.3f}")
    line("TDM hole pixels", lambda r: r["tdm_holes"])
    line("TDM colour error (mean, 0-255)", lambda r: f"{r['tdm_colour_error']:.2f}")
    line("TDM colour error (99th percentile)", lambda r: f"{r['tdm_colour_p99']:.0f}")
    line("TDM SSIM", lambda r: f"{r['tdm_ssim']:.3f}")
    line("TDM pixels bloated beyond 1 px", lambda r: r["tdm_bloat_beyond_1px"])
    line("# quads of layered impostor", lambda r: r["layered_quads"])
    line("memory of layered, tiles (kB)", lambda r: f"{r['layered_memory'] / 1000:.1f}")
    line("memory of layered, pages (kB)", lambda r: f"{r['layered_memory_pages'] / 1000:.1f}")
    line("layered generation (s)", lambda r: f"{r['layered_seconds']:.3f}")
    line("layered hole pixels", lambda r: r["layered_holes"])
    line("layered colour error", lambda r: f"{r['layered_colour_error']:.2f}")
    line("layered colour error (99th percentile)", lambda r: f"{r['layered_colour_p99']:.0f}")
    line("layered SSIM", lambda r: f"{r['layered_ssim']:.3f}")
    line("layered pixels bloated beyond 1 px", lambda r: r["layered_bloat_beyond_1px"])
    line("triangles TDM / quads layered", lambda r: f"{r['tdm_triangles'] / max(r['layered_quads'], 1):.2f}")
    line("triangles TDM / layered (2 a quad)", lambda r: f"{r['tdm_triangles'] / max(2 * r['layered_quads'], 1):.2f}")
    line("memory TDM pages / layered tiles", lambda r: f"{r['tdm_memory'] / max(r['layered_memory'], 1):.2f}")
    line("memory TDM needed / layered tiles", lambda r: f"{r['tdm_memory_needed'] / max(r['layered_memory'], 1):.2f}")
    line("memory TDM / layered pages", lambda r: f"{r['tdm_memory'] / max(r['layered_memory_pages'], 1):.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="256 pixels, three distances, three factors")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--out", default="benchmarks/out", help="folder for the plot")
    args = parser.parse_args()
    resolution = 256 if args.quick else 512
    distances = (90, 250, 1000) if args.quick else DISTANCES
    factors = (1.0, 2.0, 3.0) if args.quick else FACTORS
    gl_context()
    info = renderer_info()
    scene = house()
    if not args.json:
        print(
            f"renderer: {info.vendor} / {info.renderer}; part: {scene.triangle_count} triangles; {resolution} px, 45°, 100 m cubic cell"
        )
    bake_tdm(scene, cell_before(scene, 500.0), TdmOptions(resolution=64))  # compile the numba kernels

    table = {}
    for d in distances:
        row = measure(scene, cell_before(scene, float(d)), resolution)
        row["distance"] = d
        table[d] = row
        if not args.json:
            print(
                f"  {d} m: TDM {row['tdm_triangles']} triangles in {row['tdm_seconds']['total']:.2f} s", file=sys.stderr
            )
    trade = {}
    cell = cell_before(scene, 140.0)
    for f in factors:
        tdm = bake_tdm(scene, cell, TdmOptions(resolution=resolution, enlargement=f))
        ev = evaluate(scene, tdm, cell, random_count=4, seed=3).totals
        trade[f] = {
            "triangles": tdm.stats["triangles"], "memory": tdm_memory(tdm.stats), "seconds": tdm.stats["seconds"]["total"],
            "holes": ev["hole_pixels"], "colour_error": ev["colour_error_mean"], "bloat_beyond_1px": ev["bloat_beyond_1px"],
        }  # fmt: skip
    parts = {}
    for name in PARTS:
        if name in ("bunny", "helmet") and not SHARED_SCENES.exists():
            continue
        parts[name] = compare_part(name, resolution)
        if not args.json:
            print(f"  {name}: use {parts[name]['choice']}", file=sys.stderr)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    plot = out / "tdm_trade.png"
    write_trade_plot(trade, plot)
    if args.json:
        print(
            json.dumps(
                {"renderer": info.renderer, "resolution": resolution, "table": table, "trade": trade, "parts": parts},
                indent=2,
            )
        )
        return
    print("\nTable 4.1 side by side (seed 000), enlargement factor 2:")
    print_table(table)
    print("\nThe trade at 140 m (enlargement factor -> triangles, memory, time, image error):")
    print(
        f"{'factor':>7}{'triangles':>11}{'memory kB':>11}{'seconds':>9}{'holes':>7}{'colour err':>11}{'bloat>1px':>10}"
    )
    for f, r in trade.items():
        print(
            f"{f:>7.2f}{r['triangles']:>11}{r['memory'] / 1000:>11.1f}{r['seconds']:>9.2f}{r['holes']:>7}{r['colour_error']:>11.2f}{r['bloat_beyond_1px']:>10}"
        )
    print(f"plot: {plot}")
    print("\nWhich to use, part by part (enlargement factor 2; memory = pages as stored + geometry):")
    print(
        f"{'part':<12}{'tris':>9}{'layers':>7}{'technique':>10}{'triangles':>10}{'memory kB':>11}{'holes':>6}{'>1px':>6}{'colour err':>11}{'bake s':>8}  use"
    )
    for name, part in parts.items():
        for c in part["candidates"]:
            use = part["choice"] if c["name"] == "tdm" else ""
            print(f"{name:<12}{part['triangles']:>9,}{part['layers']:>7}{c['name']:>10}{c['triangles']:>10,}{c['memory_bytes'] / 1000:>11.1f}{c['hole_pixels']:>6}"
                  f"{c['bloat_beyond_1px']:>6}{c['colour_error_mean']:>11.2f}{c['bake_seconds']:>8.2f}  {use}")  # fmt: skip


def write_trade_plot(trade: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    factors = list(trade)
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    axes[0].plot(factors, [trade[f]["triangles"] for f in factors], "o-")
    axes[0].set_ylabel("TDM triangles")
    axes[1].plot(factors, [trade[f]["memory"] / 1000 for f in factors], "o-", color="tab:green")
    axes[1].set_ylabel("memory (kB)")
    axes[2].plot(factors, [trade[f]["colour_error"] for f in factors], "o-", color="tab:red", label="mean colour error")
    axes[2].plot(
        factors,
        [trade[f]["bloat_beyond_1px"] / 100 for f in factors],
        "s--",
        color="tab:purple",
        label="bloat > 1 px / 100",
    )
    axes[2].legend()
    for ax in axes:
        ax.set_xlabel("voxel enlargement factor")
        ax.grid(alpha=0.3)
    fig.suptitle("Textured depth mesh: the enlargement factor trade (house at 140 m, 100 m cell)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)


if __name__ == "__main__":
    main()
