"""Placement for a frame-time budget (seed 000 ch. 5): the shape of Table 5.1 on two seeded scenes, measured in one run.

Usage: ``.venv/bin/python benchmarks/bench_placement.py [--scene city|helmets|both] [--quick] [--json OUT]``

For each scene the reference placement and its variations run side by side, with the same cost
model (the builtin one ``farfield calibrate`` measured on this machine's llvmpipe, unless
``--cost-model FILE``) and the layered technique:

* t_max varied (Table 5.1 tests 2-6): memory should grow faster than linearly as t_max falls;
* CPV size x2 and x1/2 (tests 9-10);
* fewer candidates (apex angles 22.5/90°, directions every 22.5°, 6 distances) and more
  (directions every 5.625°) (tests 11-12);
* box view cells only, shafts only (test 13 and its converse);
* one impostor per leaf box cell and node (test 14, "per rectangular view cell");
* a grid of layered environment maps over the same view space (test 15), **estimated** from the
  envmap layer plans (not baked): per leaf region a cubic cell, its near field the smallest radius
  whose geometry (every element within it, all directions) fits t_max, its layers from
  :func:`core.envmap_layers.layers_for_near_field`, and its memory the cost model's memory law
  applied to each of the six faces' layers.

Columns: # CPV, # candidates, # impostors, estimated memory (MiB), CPVs left unsolved/unsolvable,
and the seconds of each step.  Memory is the cost model's estimate (layers x texels law); nothing
is baked.  Everything runs on CPU; rendering is not involved (the cost model stands for it).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from farfield.core import procedural  # noqa: E402
from farfield.core.envmap_layers import layers_for_near_field  # noqa: E402
from farfield.core.errors import FarfieldError  # noqa: E402
from farfield.core.exchange import load_scene  # noqa: E402
from farfield.core.pixel_angles import pixel_angle  # noqa: E402
from farfield.core.placement.cost_model import LLVMPIPE_MODEL, CostModel, primitive_model  # noqa: E402
from farfield.core.placement.hierarchy import Elements  # noqa: E402
from farfield.core.placement.planner import PlacementSettings, place  # noqa: E402
from farfield.core.placement.view_space import element_pixels  # noqa: E402
from farfield.core.scene import Scene, SceneObject  # noqa: E402

SHARED = Path(__file__).resolve().parents[2] / "shared" / "scenes"
RESOLUTION = 256


def city_scene(quick: bool, size: int | None = None) -> tuple[Scene, np.ndarray, np.ndarray]:
    """A seeded city of detailed box buildings; the view space a box above the roofs of its centre,
    a quarter of the city's side across."""
    scene = procedural.city(size or (400 if quick else 1600), seed=0, detail=16)
    c = 0.5 * (scene.bounds[0] + scene.bounds[1])
    top = float(scene.bounds[1][1])
    half = 0.1875 * float(scene.extents[0])
    return scene, np.array([c[0] - half, top + 10.0, c[2] - half]), np.array([c[0] + half, top + 20.0, c[2] + half])


def helmet_scene(quick: bool, size: int | None = None) -> tuple[Scene, np.ndarray, np.ndarray]:
    """Copies of the Damaged Helmet (``../shared/scenes``), 4 m tall, on a seeded terrain; the view
    space a box just above the terrain at the centre."""
    helmet = load_scene(str(SHARED / "damaged_helmet" / "DamagedHelmet.glb"))
    rng = np.random.default_rng(7)
    side = size or (6 if quick else 12)
    spacing = 12.0
    objects = []
    size = float(np.max(helmet.extents))
    for i in range(side):
        for j in range(side):
            scale = 4.0 / size * rng.uniform(0.7, 1.3)
            offset = np.array([i * spacing + rng.uniform(-2, 2), 0.0, j * spacing + rng.uniform(-2, 2)])
            for obj in helmet.objects:
                v = (obj.vertices - helmet.bounds[0]) * scale + offset
                objects.append(SceneObject(f"helmet_{i}_{j}_{obj.name}", v, obj.faces, base_color=obj.base_color))
    n = side * 4
    g = np.linspace(-spacing, side * spacing, n + 1)
    x, z = np.meshgrid(g, g, indexing="ij")
    y = -1.0 + 0.8 * np.sin(x / 17.0) * np.cos(z / 23.0) + rng.uniform(-0.2, 0.2, x.shape)
    verts = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    k = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]
    k = k.ravel()
    faces = np.concatenate([np.stack([k, k + 1, k + n + 2], 1), np.stack([k, k + n + 2, k + n + 1], 1)])
    objects.append(SceneObject("terrain", verts, faces, base_color=(0.35, 0.45, 0.25, 1.0)))
    scene = Scene.from_objects(objects, "helmets")
    c = 0.5 * (scene.bounds[0] + scene.bounds[1])
    half = 2.0 * spacing
    return scene, np.array([c[0] - half, 6.0, c[2] - half]), np.array([c[0] + half, 10.0, c[2] + half])


def envmap_grid_memory(scene: Scene, lo, hi, cell: float, t_max: float, model: CostModel) -> dict:
    """Estimated memory of a grid of layered environment maps (seed 002) over the view space with
    cubic cells of side ``cell``: per cell, the near field is the smallest radius from the cell's
    centre whose elements (all directions, no culling) fit t_max by the model; its layers follow
    from the envmap layer plan; memory is the model's law per face (see the module docstring)."""
    elements = Elements.of(scene)
    centre_b = 0.5 * (elements.bounds[:, 0] + elements.bounds[:, 1])
    counts = np.maximum(1, np.ceil((hi - lo) / cell - 1e-9)).astype(int)
    alpha = pixel_angle(math.pi / 2, RESOLUTION, "min")
    total, cells, layers_all, near_all = 0.0, 0, [], []
    for idx in np.ndindex(*counts):
        c_lo = lo + np.array(idx) * cell
        c_hi = np.minimum(c_lo + cell, np.maximum(hi, c_lo + 1e-9))
        centre = 0.5 * (c_lo + c_hi)
        pixels = element_pixels(elements, c_lo, c_hi, math.radians(45.0), RESOLUTION)
        cost = model.geometry_time(elements.draw_calls, elements.triangles, pixels)
        dist = np.linalg.norm(centre_b - centre, axis=1)
        order = np.argsort(dist)
        within = model.frame_time + np.cumsum(cost[order])
        fits = np.searchsorted(within, t_max, side="right")  # elements that fit, nearest first
        near = float(dist[order[fits]]) if fits < order.size else math.inf
        near = max(near, 0.51 * math.sqrt(3) * cell)
        if math.isinf(near):
            continue
        layers = layers_for_near_field(cell, RESOLUTION, near, alpha, 3)
        total += 6.0 * float(model.memory_bytes(layers, RESOLUTION * RESOLUTION))
        cells += 1
        layers_all.append(layers), near_all.append(near)
    return {"cells": cells, "memory_bytes": total, "layers_median": float(np.median(layers_all)) if layers_all else 0.0,
            "near_field_median": float(np.median(near_all)) if near_all else 0.0}  # fmt: skip


def run(name: str, scene: Scene, lo, hi, model: CostModel, quick: bool, only: list[str] | None = None) -> list[dict]:
    # The reference budget: half the worst view's time without impostors.
    worst = _worst_view(scene, lo, hi, model)
    t_ref = 0.5 * worst
    cpv = float(np.max(hi - lo)) / 8.0
    base = {"t_max": t_ref, "model": model, "options": {"resolution": RESOLUTION}, "cpv_size": cpv, "cells": "both"}
    rows = [
        ("1", f"reference (t_max {t_ref:.4g} {model.unit})", {}),
        ("2", "t_max x 1.5", {"t_max": 1.5 * t_ref}),
        ("3", "t_max x 1.25", {"t_max": 1.25 * t_ref}),
        ("5", "t_max x 0.8", {"t_max": 0.8 * t_ref}),
        ("6", "t_max x 0.65", {"t_max": 0.65 * t_ref}),
        ("9", "CPV size x 2", {"cpv_size": 2 * cpv}),
        ("10", "CPV size x 1/2", {"cpv_size": 0.5 * cpv}),
        ("11", "fewer candidates", {"apex_angles_deg": (22.5, 90.0), "direction_step_deg": 22.5, "distance_steps": 6}),
        ("12", "more candidates", {"direction_step_deg": 5.625}),
        ("13", "box view cells only", {"cells": "boxes"}),
        ("13s", "shaft view cells only", {"cells": "shafts"}),
        ("14", "per leaf box cell", {"cells": "leaf-boxes"}),
    ]
    if quick:
        rows = [r for r in rows if r[0] in ("1", "2", "6", "13", "13s", "14")]
    if only:
        rows = [r for r in rows if r[0] in only]
    out = []
    for test, label, change in rows:
        settings = PlacementSettings(**{**base, **change})
        started = time.perf_counter()
        result = place(scene, lo, hi, settings)
        s = result.summary
        out.append({
            "scene": name, "test": test, "parameter": label, "t_max": settings.t_max, "cpvs": s["cpvs"], "candidates": s["candidates"],
            "impostors": s["impostors"], "memory_mib": s["memory_bytes"] / 2**20, "unsolved": s["cpvs_unsolved"],
            "unsolvable": s["cpvs_unsolvable"], "worst_before": s["worst_before"], "worst_after": s["worst_after"],
            "seconds": {k: round(v, 2) for k, v in result.seconds.items()}, "wall": time.perf_counter() - started,
        })  # fmt: skip
        print(_line(out[-1]), flush=True)
    if only and "15" not in only:
        return out
    env = envmap_grid_memory(scene, lo, hi, cpv, t_ref, model)
    out.append({
        "scene": name, "test": "15", "parameter": f"envmap grid, {env['cells']} cells of {cpv:.3g} (estimated)", "t_max": t_ref,
        "cpvs": None, "candidates": None, "impostors": env["cells"], "memory_mib": env["memory_bytes"] / 2**20, "unsolved": None,
        "unsolvable": None, "worst_before": None, "worst_after": None, "seconds": {}, "wall": 0.0, "envmap": env,
    })  # fmt: skip
    print(_line(out[-1]), flush=True)
    return out


def _worst_view(scene, lo, hi, model) -> float:
    """The worst view's time with no impostor: the worst CPV of the reference CPV size and
    view-direction intervals for a budget nothing meets."""
    from farfield.core.placement.hierarchy import Hierarchy
    from farfield.core.placement.view_space import problem_view_space

    elements = Elements.of(scene)
    h = Hierarchy.build(elements)
    pv = problem_view_space(elements, h, lo, hi, model, 1e-9, math.radians(45.0), RESOLUTION, float(np.max(hi - lo)) / 8.0, 11.25)
    return float(pv.time.max())


def _line(r: dict) -> str:
    steps = " ".join(f"{k[:4]} {v:.1f}" for k, v in r["seconds"].items() if k != "total")
    num = lambda x: "-" if x is None else str(x)  # noqa: E731
    return (f"{r['scene']:<8} {r['test']:>4} {r['parameter']:<44} {num(r['cpvs']):>7} {num(r['candidates']):>9} {num(r['impostors']):>7} "
            f"{r['memory_mib']:>10.2f} {num(r['unsolved']):>6}/{num(r['unsolvable']):<6} {steps}")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", choices=["city", "helmets", "both"], default="both")
    parser.add_argument("--quick", action="store_true", help="smaller scenes, fewer rows")
    parser.add_argument("--cost-model", default="llvmpipe", help="'llvmpipe' (the builtin model measured here), 'primitives' (t = triangles, seed 000 §5.8.3) or a model JSON")
    parser.add_argument("--rows", default=None, help="comma-separated test numbers to run (default: all)")
    parser.add_argument("--size", type=int, default=None, help="city buildings / helmets per side (default: 1600 / 12; --quick 400 / 6)")
    parser.add_argument("--json", default=None, help="write the rows here")
    args = parser.parse_args()
    model = {"llvmpipe": LLVMPIPE_MODEL, "primitives": primitive_model()}.get(args.cost_model) or CostModel.load(args.cost_model)
    print(f"cost model: {model.renderer} ({model.source}); layered impostors at {RESOLUTION} px, 45°; CPU only (no rendering)")
    print(f"{'scene':<8} {'test':>4} {'parameter':<44} {'# CPV':>7} {'# cand.':>9} {'# imp.':>7} {'MiB':>10} {'unsolved/unsolvable':<13} seconds per step")
    rows = []
    builders = {"city": city_scene, "helmets": helmet_scene}
    for name in (["city", "helmets"] if args.scene == "both" else [args.scene]):
        try:
            scene, lo, hi = builders[name](args.quick, args.size)
        except FarfieldError as error:
            print(f"{name}: cannot build the scene: {error}")
            continue
        print(f"# {name}: {scene.object_count} objects, {scene.triangle_count:,} triangles; view space {lo.round(2).tolist()} .. {hi.round(2).tolist()}")
        rows += run(name, scene, lo, hi, model, args.quick, args.rows.split(",") if args.rows else None)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
