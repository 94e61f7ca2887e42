"""Layered impostors measured side by side in one run: quality, memory and speed against a lower bound.

Usage: ``.venv/bin/python benchmarks/bench_layered.py [--quick] [--only PART ...] [--json]``

1. Table (seed 000 Table 4.1 / Fig. 3.11): one object, a cubic view cell at several distances and
   output resolutions 256, 512, 1024 -> layers, quads, texture memory, hole pixels, bloat, colour
   error, generation time per stage.
2. Memory: one quad per layer vs box-grown quads vs box-grown after culling (the thesis went
   6.15 MB -> 2.1 MB -> 0.45 MB on its dragon).
3. Knobs: grid cell, fill threshold, culling, pixel model, one at a time.
4. Speed: the bake of a ~100k-triangle object at 512 (61 layers since issue 23) and at 1024, and its
   recording alone, against a lower bound measured in the same run: one full render of the part at
   the impostor resolution (the bake's own plan) plus the readback of all layer texels.

Inputs come from a seeded ``np.random.default_rng``; the renderer (llvmpipe or a GPU) is printed.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from farfield.core.layering.plan import plan_layers  # noqa: E402
from farfield.core.quality.evaluation import evaluate  # noqa: E402
from farfield.core.render.context import gl_context, renderer_info  # noqa: E402
from farfield.core.render.programs import park_framebuffer  # noqa: E402
from farfield.core.render.raster import Camera, MeshRenderer  # noqa: E402
from farfield.core.scene import Scene, SceneObject  # noqa: E402
from farfield.core.techniques.layered import BakeOptions, bake_layered  # noqa: E402
from farfield.core.viewcells import BoxCell  # noqa: E402


def dense_object(seed: int = 0) -> Scene:
    """A bumpy icosphere (81,920 triangles) fused with a smaller one (20,480): 102,400 triangles, radius ~1."""
    rng = np.random.default_rng(seed)
    big = trimesh.creation.icosphere(subdivisions=6)
    bumps = (
        1.0
        + 0.04 * np.sin(7 * big.vertices[:, :1]) * np.cos(5 * big.vertices[:, 1:2])
        + 0.01 * rng.standard_normal((len(big.vertices), 1))
    )
    small = trimesh.creation.icosphere(subdivisions=5, radius=0.5)
    small.apply_translation([0.3, 0.9, 0.4])
    colours = np.concatenate(
        [rng.integers(60, 255, (len(big.vertices), 3)), np.full((len(big.vertices), 1), 255)], axis=1
    ).astype(np.uint8)
    return Scene.from_objects(
        [
            SceneObject("body", big.vertices * bumps, big.faces, vertex_colors=colours),
            SceneObject("head", small.vertices, small.faces, base_color=(0.8, 0.5, 0.3, 1.0)),
        ],
        "dense-object",
    )


def cell_before(scene: Scene, distance: float, size: float) -> BoxCell:
    """Cubic cell of ``size`` whose near face lies ``distance`` before the part's near face along x."""
    b = scene.bounds
    centre = 0.5 * (b[0] + b[1])
    centre[0] = b[0][0] - distance - 0.5 * size
    return BoxCell.from_center(centre, size)


def table(scene: Scene, distances, resolutions, size: float, random_count: int) -> list[dict]:
    rows = []
    for distance in distances:
        for resolution in resolutions:
            cell = cell_before(scene, distance, size)
            imp = bake_layered(scene, cell, BakeOptions(resolution=resolution))
            ev = evaluate(scene, imp, cell, random_count=random_count, seed=1, samples=2)
            s = imp.stats
            rows.append(
                {
                    "distance": distance,
                    "resolution": resolution,
                    "layers": s["layers"],
                    "quads": s["quads"],
                    "texture_kib": s["texture_bytes"] / 1024,
                    "holes": ev.totals["hole_pixels"],
                    "bloat_1px": ev.totals["bloat_beyond_1px"],
                    "colour_err": ev.totals["colour_error_mean"],
                    "colour_p99": ev.totals["colour_error_p99"],
                    "ssim": ev.totals["ssim"],
                    **{f"t_{k}": v for k, v in s["seconds"].items()},
                }
            )
    return rows


def memory(scene: Scene, distance: float, size: float, resolution: int) -> dict:
    cell = cell_before(scene, distance, size)
    grown = bake_layered(scene, cell, BakeOptions(resolution=resolution, culling="off"))
    culled = bake_layered(scene, cell, BakeOptions(resolution=resolution, culling="penumbra"))
    one = grown.stats["texture_bytes_one_quad_per_layer"]
    return {
        "layers": grown.stats["layers"],
        "one_quad_per_layer_kib": one / 1024,
        "box_grown_kib": grown.stats["texture_bytes_tile_area"] / 1024,
        "box_grown_culled_kib": culled.stats["texture_bytes_tile_area"] / 1024,
        "atlas_pages_culled_kib": culled.texture_bytes / 1024,
        "ratio_one_to_grown": one / grown.stats["texture_bytes_tile_area"],
        "ratio_one_to_culled": one / culled.stats["texture_bytes_tile_area"],
    }


def knobs(scene: Scene, distance: float, size: float, random_count: int) -> list[dict]:
    """Each knob varied alone around the defaults: its effect on quads, memory, time and error."""
    cell = cell_before(scene, distance, size)
    variants = [("defaults", {})]
    variants += [(f"grid_cell={g}", {"grid_cell": g}) for g in (2, 4, 16, 32)]
    variants += [(f"fill_threshold={f}", {"fill_threshold": f}) for f in (0.5, 0.95)]
    variants += [(f"culling={c}", {"culling": c}) for c in ("umbra", "off")]
    variants += [("pixel_model=center", {"pixel_model": "center"})]
    rows = []
    for name, change in variants:
        imp = bake_layered(scene, cell, BakeOptions(resolution=512, **change))
        ev = evaluate(scene, imp, cell, random_count=random_count, seed=1, samples=2)
        s = imp.stats
        rows.append(
            {
                "knob": name,
                "layers": s["layers"],
                "quads": s["quads"],
                "texture_kib": s["texture_bytes"] / 1024,
                "tile_kib": s["texture_bytes_tile_area"] / 1024,
                "geometry_kib": s["geometry_bytes"] / 1024,
                "seconds": s["seconds"]["total"],
                "holes": ev.totals["hole_pixels"],
                "colour_err": ev.totals["colour_error_mean"],
                "colour_p99": ev.totals["colour_error_p99"],
                "ssim": ev.totals["ssim"],
                "bloat_1px": ev.totals["bloat_beyond_1px"],
            }
        )
    return rows


def bake_plan(scene: Scene, cell: BoxCell, resolution: int):
    """The layer plan a default bake of ``scene`` (one part) at ``resolution`` records."""
    options = BakeOptions(resolution=resolution)
    return plan_layers(
        cell,
        scene.bounds,
        math.radians(options.fov_deg),
        resolution,
        options.pixel_model,
        texel_share=options.texel_share,
    )


def lower_bound_s(scene: Scene, plan, repeats: int) -> float:
    """The recording's lower bound, best of ``repeats``: one plain render of ``scene`` from ``plan``'s
    reference viewpoint (a square as wide as the layers' longer side, the one shape the renderer's
    camera has: up to ~16 % more texels than a layer here), plus the read-back of all its layers."""
    res_x, res_y = (int(r) for r in plan.texture_resolution)
    ctx = gl_context()
    target = 0.5 * (scene.bounds[0] + scene.bounds[1])
    bounds = []
    with MeshRenderer(scene.objects) as renderer:
        camera = Camera.look_at(
            plan.reference_viewpoint,
            target,
            2 * math.atan(float(plan.frustum_half_tangents.max())),
            max(res_x, res_y),
            plan.t0 * 0.5,
            (plan.t0 + plan.depth + plan.reference_offset) * 2,
        )
        renderer.render(camera)
        texture = ctx.texture((res_x, res_y), 4)
        fbo = ctx.framebuffer([texture])
        for _ in range(repeats):
            start = time.perf_counter()
            renderer.render(camera)
            fbo.use()
            for _ in range(plan.count):
                texture.read()
            bounds.append(time.perf_counter() - start)
        park_framebuffer(ctx)
        fbo.release()
        texture.release()
    return min(bounds)


def speed(scene: Scene, distance: float, size: float, resolution: int, repeats: int) -> dict:
    cell = cell_before(scene, distance, size)
    bake_layered(scene, cell, BakeOptions(resolution=resolution))  # warm: context, shaders
    bakes = []  # (seconds, impostor): the best bake's stages are reported with its time
    for _ in range(repeats):
        start = time.perf_counter()
        made = bake_layered(scene, cell, BakeOptions(resolution=resolution))
        bakes.append((time.perf_counter() - start, made))
    plan = bake_plan(scene, cell, resolution)
    res_x, res_y = (int(r) for r in plan.texture_resolution)
    bound_s = lower_bound_s(scene, plan, repeats)
    bake_s, imp = min(bakes, key=lambda pair: pair[0])
    record_s = min(made.stats["seconds"]["record"] for _, made in bakes)  # issue 29 item 3: recording alone
    return {
        "resolution": resolution,
        "triangles": scene.triangle_count,
        "layers": imp.stats["layers_planned"],
        "texture": [res_x, res_y],
        "bake_s": bake_s,
        "stages": imp.stats["seconds"],
        "lower_bound_s": bound_s,
        "ratio": bake_s / bound_s,
        "record_s": record_s,
        "record_ratio": record_s / bound_s,
    }


PARTS = ("table", "memory", "knobs", "speed")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer distances and resolutions")
    parser.add_argument(
        "--only", action="append", choices=PARTS, help="run only this part (repeatable; default: all four)"
    )
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    parts = args.only or PARTS
    info = renderer_info()
    scene = dense_object()
    diameter = float(np.max(scene.bounds[1] - scene.bounds[0]))
    size = 0.3 * diameter
    distances = (
        [1.0 * diameter, 3.0 * diameter]
        if args.quick
        else [0.5 * diameter, 1.0 * diameter, 2.0 * diameter, 4.0 * diameter, 8.0 * diameter]
    )
    resolutions = [256, 512] if args.quick else [256, 512, 1024]
    random_count = 4 if args.quick else 8
    result = {"renderer": info.renderer, "object_triangles": scene.triangle_count}
    if "table" in parts:
        result["table"] = table(scene, distances, resolutions, size, random_count)
    if "memory" in parts:
        result["memory"] = memory(scene, 0.5 * diameter, size, 512)
    if "knobs" in parts:
        result["knobs"] = knobs(scene, 1.0 * diameter, size, random_count)
    if "speed" in parts:
        result["speed"] = [speed(scene, 1.6 * diameter, size, r, repeats=2 if args.quick else 3) for r in (512, 1024)]
    if args.json:
        print(json.dumps(result, indent=2))
        return
    print(
        f"renderer: {info.renderer} ({info.vendor}, {info.version})   object: {scene.triangle_count} triangles, diameter {diameter:.3g}, cubic cell {size:.3g}"
    )
    report(result)


def report(result: dict) -> None:
    if "table" in result:
        _print_table(result["table"])
    if "memory" in result:
        _print_memory(result["memory"])
    if "knobs" in result:
        _print_knobs(result["knobs"])
    for s in result.get("speed", []):
        stages = "  ".join(f"{k} {v:.3f}" for k, v in s["stages"].items())
        print(
            f"\n4. speed at {s['resolution']}: {s['triangles']} triangles, {s['layers']} layers, texture {s['texture'][0]}x{s['texture'][1]}: bake {s['bake_s']:.3f} s "
            f"vs lower bound {s['lower_bound_s']:.3f} s = {s['ratio']:.1f}x\n   stages: {stages}\n"
            f"   recording (best of the bakes) {s['record_s']:.3f} s = {s['record_ratio']:.1f}x the lower bound"
        )


def _print_table(rows: list[dict]) -> None:
    print("\n1. quality, memory and time by distance (near face to near face) and output resolution")
    head = f"{'dist':>6} {'res':>5} {'layers':>6} {'quads':>6} {'tex KiB':>9} {'holes':>6} {'bloat>1':>8} {'col err':>8} {'p99':>5} {'SSIM':>5} {'record':>7} {'cull':>6} {'quads':>6} {'atlas':>6} {'total s':>8}"
    print(head)
    for r in rows:
        print(
            f"{r['distance']:>6.2f} {r['resolution']:>5} {r['layers']:>6} {r['quads']:>6} {r['texture_kib']:>9.1f} {r['holes']:>6} {r['bloat_1px']:>8} {r['colour_err']:>8.2f} {r['colour_p99']:>5.0f} {r['ssim']:>5.3f} "
            f"{r['t_record']:>7.3f} {r['t_cull']:>6.3f} {r['t_quads']:>6.3f} {r['t_atlas']:>6.3f} {r['t_total']:>8.3f}"
        )


def _print_memory(m: dict) -> None:
    print(
        f"\n2. texture memory at 512, {m['layers']} layers: one quad per layer {m['one_quad_per_layer_kib']:.0f} KiB -> box-grown "
        f"{m['box_grown_kib']:.0f} KiB -> box-grown after culling {m['box_grown_culled_kib']:.0f} KiB "
        f"(ratios {m['ratio_one_to_grown']:.1f}x, {m['ratio_one_to_culled']:.1f}x; thesis 2.9x, 13.7x); atlas pages {m['atlas_pages_culled_kib']:.0f} KiB"
    )


def _print_knobs(rows: list[dict]) -> None:
    print("\n3. knobs at 512, one at a time (distance 1 diameter)")
    print(
        f"{'knob':<22} {'layers':>6} {'quads':>6} {'atlas KiB':>10} {'tiles KiB':>10} {'geom KiB':>9} {'seconds':>8} {'holes':>6} {'bloat>1':>8} {'col err':>8} {'p99':>5} {'SSIM':>5}"
    )
    for r in rows:
        print(
            f"{r['knob']:<22} {r['layers']:>6} {r['quads']:>6} {r['texture_kib']:>10.1f} {r['tile_kib']:>10.1f} {r['geometry_kib']:>9.1f} "
            f"{r['seconds']:>8.3f} {r['holes']:>6} {r['bloat_1px']:>8} {r['colour_err']:>8.2f} {r['colour_p99']:>5.0f} {r['ssim']:>5.3f}"
        )


if __name__ == "__main__":
    main()
