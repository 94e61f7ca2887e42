"""Point-based and LDI impostors with normals: what the normal channel costs and what it buys.

Usage: ``.venv/bin/python benchmarks/bench_points_ldi_lit.py [--resolution R] [--random N] [--json]``

For each scene (a smooth icosphere with exact vertex normals, the procedural house: flat façades
without vertex normals, and a procedural tree: a smooth trunk and crown) and each of ``points`` and ``ldi``,
one bake with ``channels=albedo`` and one with ``channels=albedo+normal`` of the same part and view
cell (a cubic cell a fifth of the part's size, three part sizes in front of it along -z), side by
side in one run: bake seconds, memory per channel; then the lit evaluation of the normal bake
(:mod:`farfield.core.quality.lit`, five test lights incl. a grazing one) from the cell's corners,
its reference viewpoint and ``--random`` seeded points inside: the unlit error, the worst light's
lit error, the same impostor lit as flat cards (sprites facing the viewer), the normal error and
issue 55's two ratios.  The renderer (llvmpipe or a GPU) is printed.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from farfield.core import procedural  # noqa: E402
from farfield.core.quality.lit import evaluate_lit, lit_figures  # noqa: E402
from farfield.core.render.context import renderer_info  # noqa: E402
from farfield.core.scene import Scene, SceneObject  # noqa: E402
from farfield.core.techniques.ldi import LdiOptions, bake_ldi  # noqa: E402
from farfield.core.techniques.points.technique import PointOptions, bake_points  # noqa: E402
from farfield.core.viewcells import BoxCell  # noqa: E402


def sphere() -> Scene:
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    vertices = np.asarray(mesh.vertices)
    return Scene((SceneObject("ball", vertices, np.asarray(mesh.faces), normals=vertices, base_color=(0.6, 0.5, 0.4, 1.0)),), "sphere")  # fmt: skip


def tree() -> Scene:
    """A procedural tree: a trunk (a 12-sided cylinder, smooth sides) and a crown of three smooth
    icospheres, every part with vertex normals."""
    trunk = trimesh.creation.cylinder(radius=0.3, height=4.0, sections=12)
    trunk.apply_translation([0.0, 0.0, 2.0])
    parts = [("trunk", trunk, (0.35, 0.24, 0.15, 1.0))]
    for k, (centre, radius) in enumerate((((0.0, 0.0, 5.0), 2.0), ((1.2, 0.6, 6.2), 1.3), ((-1.0, -0.5, 6.4), 1.2))):
        crown = trimesh.creation.icosphere(subdivisions=3, radius=radius)
        crown.apply_translation(centre)
        parts.append((f"crown{k}", crown, (0.2, 0.45, 0.15, 1.0)))
    objects = []
    for name, mesh, colour in parts:
        # z-up to y-up world: (x, y, z) -> (x, z, -y), a proper rotation (normals turn alike)
        turn = lambda a: np.column_stack([a[:, 0], a[:, 2], -a[:, 1]])  # noqa: E731
        objects.append(SceneObject(name, turn(np.asarray(mesh.vertices)), np.asarray(mesh.faces),
                                   normals=turn(np.asarray(mesh.vertex_normals)), base_color=colour))  # fmt: skip
    return Scene.from_objects(objects, source="tree")


SCENES = {"sphere": sphere, "house": procedural.house, "tree": tree}


def memory(impostor) -> tuple[int, int]:
    """(albedo bytes, normal bytes) as the technique's stats count them; a colour-only bake's albedo
    is its geometry and texture (points) or its pages (ldi)."""
    channels = impostor.stats.get("channel_bytes")
    if channels:
        return channels["albedo"], channels["normal"]
    stats = impostor.stats
    return stats.get("geometry_bytes", 0) + stats["texture_bytes"], 0


def run(resolution: int, random_count: int, only: tuple[str, ...] = ()) -> list[dict]:
    rows = []
    chosen = {name: make for name, make in SCENES.items() if not only or name in only}
    bakers = {
        "points": lambda scene, cell, channels, r=resolution: bake_points(scene, cell, PointOptions(resolution=r, channels=channels)),
        "ldi": lambda scene, cell, channels: bake_ldi(scene, cell, LdiOptions(resolution=resolution, channels=channels)),
    }  # fmt: skip
    for channels in ("albedo", "albedo+normal"):  # warm-up, untimed: numba's kernels, the GL's programs
        for bake in bakers.values():
            bake(sphere(), BoxCell.from_center([0.0, 0.0, -3.0], 0.4), channels)
    for name, make in chosen.items():
        scene = make()
        lo, hi = scene.bounds
        size = float(np.max(hi - lo))
        centre = 0.5 * (lo + hi)
        cell = BoxCell.from_center(centre - np.array([0.0, 0.0, 3.0 * size]), 0.2 * size)
        for technique, bake in bakers.items():
            bakes = {}
            for channels in ("albedo", "albedo+normal"):
                start = time.perf_counter()
                bakes[channels] = (bake(scene, cell, channels), time.perf_counter() - start)
            impostor = bakes["albedo+normal"][0]
            lit = evaluate_lit(scene, impostor, random_count=random_count)
            rows.append(
                {
                    "scene": name,
                    "technique": technique,
                    "elements": impostor.payload.count,
                    "bake_s_albedo": bakes["albedo"][1],
                    "bake_s_normal": bakes["albedo+normal"][1],
                    "normal_stage_s": impostor.stats["seconds"].get("normals", 0.0),
                    "kib_albedo": memory(bakes["albedo"][0])[0] / 1024,
                    "kib_normal": memory(impostor)[1] / 1024,
                    **lit_figures(lit),
                }
            )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--random", type=int, default=2)
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--scenes", nargs="*", default=(), help=f"of {', '.join(SCENES)} (default: all)")
    args = parser.parse_args()
    rows = run(args.resolution, args.random, tuple(args.scenes))
    if args.json:
        print(json.dumps(rows, indent=1))
        return
    print(f"renderer: {renderer_info()}; {args.resolution} px")
    print(
        f"{'scene':<7} {'tech':<6} {'n':>7} {'bake s':>7} {'+n s':>6} {'(norm)':>6} {'KiB':>7} {'+n KiB':>7} {'unlit':>6} "
        f"{'lit':>6} {'flat':>6} {'lit/unlit':>9} {'flat/lit':>8} {'n med':>6} {'n p95':>6} {'in med':>6} {'in p95':>6}"
    )
    for r in rows:
        print(
            f"{r['scene']:<7} {r['technique']:<6} {r['elements']:>7} {r['bake_s_albedo']:>7.2f} {r['bake_s_normal']:>6.2f} "
            f"{r['normal_stage_s']:>6.2f} {r['kib_albedo']:>7.0f} {r['kib_normal']:>7.0f} {r['unlit_mean']:>6.2f} "
            f"{r['lit_mean_worst']:>6.2f} {r['flat_mean_worst']:>6.2f} {r['lit_to_unlit_worst']:>9.2f} "
            f"{r['flat_to_lit_least']:>8.2f} {r['normal_median']:>6.1f} {r['normal_p95']:>6.1f} "
            f"{r['normal_interior_median']:>6.1f} {r['normal_interior_p95']:>6.1f}"
        )


if __name__ == "__main__":
    main()
