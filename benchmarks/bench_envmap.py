"""Layered environment-map impostors (seed 002) measured side by side in one run.

Usage: ``.venv/bin/python benchmarks/bench_envmap.py [--quick] [--json] [--out DIR]``

1. Generation per cell at 512 x 512 faces with 64 layers, 4 and 6 directions (the paper: 2.5 min
   per cell on a GeForce 3), with the time of every stage.
2. Memory per cell at each compression step (seed 002 Table 2: 256 MB -> 6 MB -> 288 KB).
3. Walkthrough: a loop through a 3 x 1 x 3 grid of 10 m cells in a procedural city of about a
   million triangles; frame time of the full scene vs near field + impostors (same renderer, same
   run), hole pixels and colour error per frame, and a plot (``walkthrough.png``).
4. The trade: number of layers (near-field distance) and resolution against memory, generation
   time, frame time and image error, as a table and a plot (``trade.png``).

The city comes from a seeded ``np.random.default_rng``; the renderer (llvmpipe or a GPU) is printed.
``--quick`` shrinks the city and the settings for a smoke run.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from farfield.core.envmap_runtime import EnvmapCellRenderer, camera_at, depth_range_for, evaluate_envmap  # noqa: E402
from farfield.core.impostor_database import ImpostorDatabase, write_database  # noqa: E402
from farfield.core.render.context import gl_context, renderer_info  # noqa: E402
from farfield.core.render.raster import MeshRenderer  # noqa: E402
from farfield.core.scene import Scene, SceneObject  # noqa: E402
from farfield.core.techniques.envmap import EnvmapOptions, bake_envmap  # noqa: E402
from farfield.core.viewcells import BoxCell, grid_boxes  # noqa: E402
from farfield.core.walkthrough import generate_path, walkthrough, write_plot  # noqa: E402

HORIZONTAL = ("+x", "-x", "+z", "-z")


def detailed_city(side: int = 36, subdivisions: int = 3, seed: int = 0) -> Scene:
    """``side`` x ``side`` buildings 20 units apart (y up), each a box subdivided ``subdivisions``
    times (12 x 4^s triangles: 768 at 3), merged into one object per 6 x 6 block, plus a ground.
    36 x 36 at 3 subdivisions is 995,330 triangles."""
    rng = np.random.default_rng(seed)
    unit = trimesh.creation.box(bounds=[[0, 0, 0], [1, 1, 1]])
    for _ in range(subdivisions):
        unit = unit.subdivide()
    uv, uf = np.asarray(unit.vertices), np.asarray(unit.faces)
    blocks: dict[tuple[int, int], list] = {}
    for i in range(side):
        for j in range(side):
            w, d = rng.uniform(6.0, 16.0, 2)
            h = rng.lognormal(math.log(15.0), 0.6)
            low = np.array([i * 20.0 - w / 2, 0.0, j * 20.0 - d / 2])
            grey = rng.uniform(0.3, 0.9)
            # Storeys as colour bands, so the images have detail to get wrong.
            band = (np.floor(uv[:, 1] * h / 3.0) % 2)[:, None]
            colour = np.concatenate([np.clip(255 * (grey - 0.15 * band) * np.array([1.0, 0.97, 0.9]), 0, 255), np.full((len(uv), 1), 255)], axis=1)
            blocks.setdefault((i // 6, j // 6), []).append((low + uv * [w, h, d], uf, colour.astype(np.uint8)))
    objects = []
    for (bi, bj), parts in sorted(blocks.items()):
        offsets = np.cumsum([0] + [len(p[0]) for p in parts[:-1]])
        objects.append(
            SceneObject(
                f"block_{bi}_{bj}",
                np.concatenate([p[0] for p in parts]),
                np.concatenate([p[1] + o for p, o in zip(parts, offsets)]),
                vertex_colors=np.concatenate([p[2] for p in parts]),
            )
        )
    extent = side * 20.0
    ground = SceneObject(
        "ground",
        np.array([[-20.0, 0.0, -20.0], [-20.0, 0.0, extent], [extent, 0.0, extent], [extent, 0.0, -20.0]]),
        np.array([[0, 1, 2], [0, 2, 3]]),
        base_color=(0.3, 0.5, 0.25, 1.0),
    )
    return Scene.from_objects([ground, *objects], source=f"detailed-city-{side}-{subdivisions}")


def street_grid(side: int, counts=(3, 1, 3), size: float = 10.0) -> list:
    """Cubic cells of ``size`` over the street crossing nearest the city's middle, eye height 0.5..size+0.5."""
    middle = (side // 2) * 20.0 - 10.0  # a street between lots
    lo = np.array([middle - counts[0] * size / 2, 0.5, middle - counts[2] * size / 2])
    hi = lo + np.array(counts) * size
    return grid_boxes(lo, hi, counts)


def runtime_frame_ms(scene: Scene, impostor, directions, repeats: int = 3) -> tuple[float, float]:
    """Mean frame time (ms) over the cell's corners and centre looking along ``directions``:
    (full scene, near field + impostors), same renderer."""
    cell = BoxCell(np.asarray(impostor.viewcell["lo"]), np.asarray(impostor.viewcell["hi"]))
    axes = {"+x": (1, 0, 0), "-x": (-1, 0, 0), "+z": (0, 0, 1), "-z": (0, 0, -1), "+y": (0, 1, 0), "-y": (0, -1, 0)}
    points = np.concatenate([cell.corners(), cell.center[None]])
    runtime = EnvmapCellRenderer(scene, impostor)
    full_ms, fast_ms = [], []
    try:
        with MeshRenderer(scene.objects) as full:
            for p in points:
                near, far = depth_range_for(scene, cell, p, runtime.reach)
                for d in directions:
                    camera = camera_at(p, axes[d], impostor.fov_deg, impostor.resolution, near, far)
                    full_ms.append(1e3 * np.median([full.frame_seconds(camera) for _ in range(repeats)]))
                    fast_ms.append(1e3 * np.median([runtime.renderer.frame_seconds(camera) for _ in range(repeats)]))
    finally:
        runtime.release()
    return float(np.mean(full_ms)), float(np.mean(fast_ms))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small city and settings (smoke run)")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--out", default="benchmarks/out", help="folder for the plots")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    side, subdiv = (12, 1) if args.quick else (36, 3)
    res, layers, frames = (128, 16, 12) if args.quick else (512, 64, 60)
    gl_context()
    info = renderer_info()
    print(f"renderer: {info.renderer} ({info.vendor}, {info.version})")
    t = time.perf_counter()
    scene = detailed_city(side, subdiv)
    print(f"city: {scene.triangle_count:,} triangles in {scene.object_count} objects (built in {time.perf_counter() - t:.1f} s)")
    cells = street_grid(side)
    report: dict = {"renderer": info.renderer, "triangles": scene.triangle_count}

    # 1 + 2: generation and memory per cell, 4 and 6 directions, on the middle cell.
    middle = cells[len(cells) // 2][1]
    print(f"\n1-2. one cell ({middle.size[0]:.0f} m cube at {middle.center.tolist()}), {res} x {res} faces, {layers} layers")
    print(f"{'dirs':>4} {'near field':>10} {'layers':>6} {'quads':>6} {'raw MB':>8} {'macro MB':>9} {'PNG KB':>8} {'raw/macro':>9} {'macro/PNG':>9} {'total s':>8}  stages (s)")
    rows = []
    for directions in (HORIZONTAL, ("+x", "-x", "+y", "-y", "+z", "-z")):
        imp = bake_envmap(scene, middle, EnvmapOptions(resolution=res, fov_deg=90.0, layers=layers, directions=directions))
        s = imp.stats
        row = {"directions": len(directions), **{k: s[k] for k in ("near_field", "layers", "quads", "raw_layer_bytes", "texture_bytes", "png_bytes")}, "seconds": s["seconds"]}
        rows.append(row)
        stages = " ".join(f"{k} {v:.2f}" for k, v in s["seconds"].items() if k != "total")
        print(
            f"{len(directions):>4} {s['near_field']:>10.1f} {s['layers']:>6} {s['quads']:>6} {s['raw_layer_bytes'] / 1e6:>8.1f} "
            f"{s['texture_bytes'] / 1e6:>9.2f} {s['png_bytes'] / 1e3:>8.1f} {s['raw_layer_bytes'] / s['texture_bytes']:>9.1f} "
            f"{s['texture_bytes'] / s['png_bytes']:>9.1f} {s['seconds']['total']:>8.2f}  {stages}"
        )
    print("   seed 002 Table 2 (4 directions, 512, 64 layers): 256 MB -> 6.0 MB -> 0.288 MB, ratios 42.5 and 20.9")
    report["cell"] = rows

    # 3: walkthrough through a 3 x 1 x 3 grid.
    print(f"\n3. walkthrough: {len(cells)} cells, 6 directions, {frames} frames")
    options = EnvmapOptions(resolution=res, fov_deg=90.0, layers=layers)
    t = time.perf_counter()
    baked = [(list(ijk), bake_envmap(scene, box, options)) for ijk, box in cells]
    bake_s = time.perf_counter() - t
    print(f"   baked in {bake_s:.1f} s ({bake_s / len(cells):.2f} s per cell)")
    with tempfile.TemporaryDirectory() as tmp:
        write_database(Path(tmp) / "db", "envmap", {}, baked)
        with ImpostorDatabase(Path(tmp) / "db") as db:
            positions, forwards = generate_path(db, frames)
            walk = walkthrough(scene, db, positions, forwards, repeats=3)
    write_plot(walk, out / "walkthrough.png", title=f"{scene.triangle_count:,}-triangle city, {res}x{res}, {layers} layers ({info.renderer})")
    s = walk["summary"]
    print(
        f"   full scene {s['full_ms_mean']:.1f} ms/frame, near field + impostors {s['impostor_ms_mean']:.1f} ms/frame "
        f"(max {s['impostor_ms_max']:.1f}): speed-up {s['speedup_mean']:.1f}x; {s['cell_switches']} cell switches; "
        f"hole pixels {s['hole_pixels']} (max {s['max_hole_pixels']} a frame), colour error mean {s['colour_error_mean']:.3f}, max {s['colour_error_max']}"
    )
    print(f"   plot: {out / 'walkthrough.png'}")
    report["walkthrough"] = {"summary": s, "bake_seconds_per_cell": bake_s / len(cells)}

    # 4: the trade, on the middle cell, horizontal directions.
    print("\n4. trade (middle cell, 4 directions; frame times and errors over its 8 corners and centre)")
    print(f"{'res':>5} {'layers':>6} {'near field':>10} {'quads':>6} {'macro MB':>9} {'PNG KB':>8} {'gen s':>7} {'full ms':>8} {'imp ms':>7} {'holes':>6} {'err mean':>8}")
    trade = []
    settings = [(128, 8), (128, 16)] if args.quick else [(256, 16), (256, 32), (256, 64), (512, 16), (512, 32), (512, 64)]
    for r, k in settings:
        t = time.perf_counter()
        imp = bake_envmap(scene, middle, EnvmapOptions(resolution=r, fov_deg=90.0, layers=k, directions=HORIZONTAL))
        gen = time.perf_counter() - t
        full_ms, fast_ms = runtime_frame_ms(scene, imp, HORIZONTAL, repeats=2)
        axes = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 0, 1.0], [0, 0, -1.0]])
        ev = evaluate_envmap(scene, imp, random_count=0, samples=1, directions=axes)["totals"]
        row = {"resolution": r, "layers": k, "near_field": imp.stats["near_field"], "quads": imp.stats["quads"], "texture_bytes": imp.stats["texture_bytes"],
               "png_bytes": imp.stats["png_bytes"], "generation_s": gen, "full_ms": full_ms, "impostor_ms": fast_ms,
               "hole_pixels": ev["hole_pixels"], "colour_error_mean": ev["colour_error_mean"]}  # fmt: skip
        trade.append(row)
        print(
            f"{r:>5} {k:>6} {row['near_field']:>10.1f} {row['quads']:>6} {row['texture_bytes'] / 1e6:>9.2f} {row['png_bytes'] / 1e3:>8.1f} "
            f"{gen:>7.2f} {full_ms:>8.1f} {fast_ms:>7.2f} {row['hole_pixels']:>6} {row['colour_error_mean']:>8.3f}"
        )
    report["trade"] = trade
    _trade_plot(trade, out / "trade.png", info.renderer)
    print(f"   plot: {out / 'trade.png'}")
    if args.json:
        print(json.dumps(report, indent=1, default=float))


def _trade_plot(trade: list[dict], path: Path, renderer: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 4, figsize=(15, 3.8))
    for r in sorted({row["resolution"] for row in trade}):
        rows = [row for row in trade if row["resolution"] == r]
        k = [row["layers"] for row in rows]
        axes[0].plot(k, [row["near_field"] for row in rows], marker="o", label=f"{r}")
        axes[1].plot(k, [row["texture_bytes"] / 1e6 for row in rows], marker="o", label=f"{r}")
        axes[2].plot(k, [row["generation_s"] for row in rows], marker="o", label=f"{r}")
        axes[3].plot(k, [row["impostor_ms"] for row in rows], marker="o", label=f"{r} impostors")
        axes[3].plot(k, [row["full_ms"] for row in rows], linestyle=":", color="grey")
    for ax, title in zip(axes, ("near-field distance (m)", "macrotextures (MB)", "generation (s)", "frame time (ms; dotted: full scene)")):
        ax.set_xlabel("layers")
        ax.set_title(title)
        ax.legend(title="resolution")
    fig.suptitle(f"envmap trade, one 10 m cell, 4 directions ({renderer})")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    main()
