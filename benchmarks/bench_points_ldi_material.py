"""Point-based and LDI impostors with their material: the lit error kept against matte.

Usage: ``.venv/bin/python benchmarks/bench_points_ldi_material.py [--resolution R] [--random N] [--json]``

For each scene (a smooth icosphere of metallic 0.7 and roughness 0.35, and the shared DamagedHelmet
with its metallic-roughness, occlusion and emissive maps) and each of ``points`` and ``ldi``, one
bake with ``channels=albedo+normal`` and one with ``channels=albedo+normal+material`` of the same
part and view cell (a cube a fifth of the part's size, three part sizes in front of it along +z,
as ``bench_lit_channels.py``); then the lit evaluation of each (:mod:`farfield.core.quality.lit`,
five test lights) from the cell's corners, its reference viewpoint and ``--random`` seeded points
inside, the source shaded with its own material: the impostor shaded with its kept material or
matte, the worst light's lit error and the mean material errors.  The renderer is printed.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from farfield.core.exchange import load_scene  # noqa: E402
from farfield.core.quality.lit import evaluate_lit  # noqa: E402
from farfield.core.render.context import renderer_info  # noqa: E402
from farfield.core.scene import Scene, SceneObject  # noqa: E402
from farfield.core.techniques.ldi import LdiOptions, bake_ldi  # noqa: E402
from farfield.core.techniques.points.technique import PointOptions, bake_points  # noqa: E402
from farfield.core.viewcells import BoxCell  # noqa: E402

SHARED = Path(__file__).resolve().parents[2] / "shared" / "scenes"


def metal_sphere() -> Scene:
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    vertices = np.asarray(mesh.vertices)
    ball = SceneObject("ball", vertices, np.asarray(mesh.faces), normals=vertices, base_color=(0.8, 0.5, 0.2, 1.0))
    return Scene((replace(ball, metallic_factor=0.7, roughness_factor=0.35),), "metal sphere")


SCENES = {"sphere": metal_sphere, "helmet": lambda: load_scene(SHARED / "damaged_helmet" / "DamagedHelmet.glb")}


def run(resolution: int, random_count: int, only: tuple[str, ...] = ()) -> list[dict]:
    bakers = {
        "points": lambda scene, cell, channels: bake_points(scene, cell, PointOptions(resolution=resolution, channels=channels)),
        "ldi": lambda scene, cell, channels: bake_ldi(scene, cell, LdiOptions(resolution=resolution, channels=channels)),
    }  # fmt: skip
    rows = []
    for name, make in SCENES.items():
        if only and name not in only:
            continue
        scene = make()
        lo, hi = scene.bounds
        size = float(np.max(hi - lo))
        cell = BoxCell.from_center(0.5 * (lo + hi) + np.array([0.0, 0.0, 3.0 * size]), 0.2 * size)
        for technique, bake in bakers.items():
            for channels in ("albedo+normal", "albedo+normal+material"):
                impostor = bake(scene, cell, channels)
                t = evaluate_lit(scene, impostor, random_count=random_count).totals
                rows.append(
                    {
                        "scene": name,
                        "technique": technique,
                        "channels": channels,
                        "impostor_material": t.get("impostor_material"),
                        "lit_mean_worst": max(row["lit_error_mean"] for row in t["lights"]),
                        "unlit_mean": t["lights"][0]["unlit_error_mean"],
                        **{k: t.get(k) for k in ("roughness_error_mean", "metallic_error_mean",
                                                 "occlusion_error_mean", "emissive_error_mean")},
                    }
                )  # fmt: skip
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, default=96)
    parser.add_argument("--random", type=int, default=0)
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--scenes", nargs="*", default=(), help=f"of {', '.join(SCENES)} (default: all)")
    args = parser.parse_args()
    rows = run(args.resolution, args.random, tuple(args.scenes))
    if args.json:
        print(json.dumps(rows, indent=1))
        return
    print(f"renderer: {renderer_info()}; {args.resolution} px")
    print(
        f"{'scene':<7} {'tech':<6} {'material':<8} {'unlit':>6} {'lit':>6} {'rough':>6} {'metal':>6} {'occl':>6} {'emis':>6}"
    )
    for r in rows:
        print(
            f"{r['scene']:<7} {r['technique']:<6} {r['impostor_material']:<8} {r['unlit_mean']:>6.2f} "
            f"{r['lit_mean_worst']:>6.2f} {r['roughness_error_mean']:>6.3f} {r['metallic_error_mean']:>6.3f} "
            f"{r['occlusion_error_mean']:>6.3f} {r['emissive_error_mean']:>6.3f}"
        )


if __name__ == "__main__":
    main()
