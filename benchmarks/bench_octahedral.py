"""Octahedral impostors: hole and bloat pixels against distance, beside the computed accuracy distance.

A small procedural tree (trunk, crown, branch; 2.2 units tall, bounding radius 1.48) is baked with
grids of N x N frames (32 texels each) and drawn at RESOLUTION px, 45°, from seeded viewpoints at
fractions of the bake's accuracy distance (the outside-sphere cell's top-down, grazing, 45° and
from-below corners and random directions), against the real geometry (farfield.core.quality.evaluation,
2 x 2 samples per pixel).  Prints one row per grid, channel set and distance.

    python benchmarks/bench_octahedral.py [--grids 8,12,16] [--resolution 64]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from farfield.core.procedural import box_object
from farfield.core.quality.evaluation import evaluate_at
from farfield.core.scene import Scene
from farfield.core.techniques import get_technique
from farfield.core.viewcells import SphereOutsideCell

FACTORS = (0.05, 0.1, 0.2, 0.35, 0.5, 1.0, 1.5)


def tree() -> Scene:
    return Scene.from_objects(
        [
            box_object("trunk", [-0.15, -0.15, 0.0], [0.15, 0.15, 1.0], (0.45, 0.3, 0.15, 1.0)),
            box_object("crown", [-0.7, -0.5, 1.0], [0.7, 0.5, 2.2], (0.1, 0.6, 0.2, 1.0)),
            box_object("branch", [0.3, -0.1, 0.2], [1.0, 0.1, 0.5], (0.8, 0.2, 0.2, 1.0)),
        ],
        "tree",
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grids", default="8,12,16")
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--frame-resolution", type=int, default=32)
    args = parser.parse_args()
    scene = tree()
    technique = get_technique("octahedral")
    centre = 0.5 * (scene.bounds[0] + scene.bounds[1])
    print(f"{'N':>3} {'channels':<20} {'D_acc':>7} {'radii':>6} {'factor':>6} {'distance':>8} {'px wide':>7} "
          f"{'holes':>6} {'bloat>1':>7} {'err mean':>8}")  # fmt: skip
    for n in (int(g) for g in args.grids.split(",")):
        for channels in ("albedo", "albedo+normal+depth"):
            options = technique.options(
                {"grid": n, "frame_resolution": args.frame_resolution, "channels": channels}, args.resolution
            )
            impostor = technique.bake(scene, SphereOutsideCell(centre, 3.0), options, None, None)
            d_acc, radius = impostor.stats["accuracy_distance"], impostor.payload.radius
            pixel = impostor.stats["accuracy"]["pixel_angle"]
            for k, factor in enumerate(FACTORS):
                cell = SphereOutsideCell(centre, factor * d_acc)
                points = np.concatenate([cell.corners(), cell.sample_random(5, 100 + k, depth=0.0)])
                start = time.perf_counter()
                t = evaluate_at(scene, impostor, points, ["random"] * len(points), samples=2, confirm_windows=16).totals
                wide = 2 * radius / (factor * d_acc * pixel)
                print(f"{n:>3} {channels:<20} {d_acc:>7.1f} {d_acc / radius:>6.1f} {factor:>6.2f} {factor * d_acc:>8.2f} "
                      f"{wide:>7.1f} {t['hole_pixels']:>6} {t['bloat_beyond_1px']:>7} {t['colour_error_mean']:>8.2f}"
                      f"  ({time.perf_counter() - start:.1f} s)", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
