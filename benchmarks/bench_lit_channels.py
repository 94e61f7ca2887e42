"""The trade table of issue 55: channel set x resolution -> memory, bake time and lit error, for a
layered impostor of each shared scene (the helmet: normal, metallic-roughness, occlusion and
emissive maps; the pine: alpha-cut leaves; the duck; a procedural house), side by side in one run.

For each scene, one view cell (a cube a fifth of the part's size, three part sizes in front of it
along +z, as ``bench_lit.py``), each channel set (``albedo``: drawn lit as flat cards, the matte
default; ``albedo+normal``: matte; ``albedo+normal+material``: the recorded material) at each
resolution: the bake's seconds, its bytes (colour pages and every channel's), and the lit
evaluation (:func:`farfield.core.quality.lit.evaluate_lit`: five test lights, grazing ones
included) against the source shaded with its own material: the worst light's lit mean error, the
unlit mean error of the same pixels, their ratio and the normal error on smooth surfaces.

    .venv/bin/python benchmarks/bench_lit_channels.py [--resolutions 128 256] [--random 2] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_lit import scenes  # noqa: E402

from farfield.core.quality.lit import evaluate_lit, lit_figures  # noqa: E402
from farfield.core.render.context import renderer_info  # noqa: E402
from farfield.core.techniques.layered import BakeOptions, bake_layered  # noqa: E402
from farfield.core.viewcells import BoxCell  # noqa: E402

CHANNEL_SETS = ("albedo", "albedo+normal", "albedo+normal+material")


def run(resolutions: list[int], random_count: int, only: list[str] | None) -> list[dict]:
    rows = []
    for name, make in scenes().items():
        if only and name not in only:
            continue
        scene = make()
        lo, hi = scene.bounds
        size = float(np.max(hi - lo))
        cell = BoxCell.from_center(0.5 * (lo + hi) + np.array([0.0, 0.0, 3.0 * size]), 0.2 * size)
        for resolution in resolutions:
            bakes = {}
            for _ in range(2):  # best of two, alternating: a first bake also compiles its shader variants
                for channels in CHANNEL_SETS:
                    start = time.perf_counter()
                    impostor = bake_layered(scene, cell, BakeOptions(resolution=resolution, channels=channels))
                    seconds = time.perf_counter() - start
                    if channels not in bakes or seconds < bakes[channels][1]:
                        bakes[channels] = (impostor, seconds)
            for channels in CHANNEL_SETS:
                impostor, seconds = bakes[channels]
                figures = lit_figures(evaluate_lit(scene, impostor, random_count=random_count))
                extra = {k: sum(p.nbytes for p in pages) for k, pages in impostor.channels.items()}
                rows.append(
                    {
                        "scene": name,
                        "resolution": resolution,
                        "channels": channels,
                        "bake_s": seconds,
                        "kib_colour": impostor.texture_bytes / 1024,
                        "kib_channels": sum(extra.values()) / 1024,
                        "channel_kib": {k: v / 1024 for k, v in extra.items()},
                        **{
                            k: figures[k]
                            for k in (
                                "unlit_mean",
                                "lit_mean_worst",
                                "lit_to_unlit_worst",
                                "normal_smooth_median",
                                "normal_smooth_p95",
                            )
                        },
                    }
                )
                print(f"  {name} {resolution} {channels}: {seconds:.1f} s", file=sys.stderr, flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolutions", type=int, nargs="+", default=[128, 256])
    parser.add_argument("--random", type=int, default=2)
    parser.add_argument("--scenes", nargs="*", help="only these (helmet, pine, duck, house)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    rows = run(args.resolutions, args.random, args.scenes)
    if args.json:
        print(json.dumps(rows, indent=1))
        return
    print(f"renderer: {renderer_info()}; layered; lit error in sRGB levels (0-255), worst of five lights")
    print(
        f"{'scene':<7} {'px':>4} {'channels':<24} {'bake s':>7} {'KiB':>7} {'+KiB':>7} {'unlit':>6} {'lit':>6} {'lit/unlit':>9} {'n med':>6} {'n p95':>6}"
    )
    for r in rows:
        print(
            f"{r['scene']:<7} {r['resolution']:>4} {r['channels']:<24} {r['bake_s']:>7.2f} {r['kib_colour']:>7.0f} "
            f"{r['kib_channels']:>7.0f} {r['unlit_mean']:>6.2f} {r['lit_mean_worst']:>6.2f} {r['lit_to_unlit_worst']:>9.2f} "
            f"{r['normal_smooth_median']:>6.1f} {r['normal_smooth_p95']:>6.1f}"
        )


if __name__ == "__main__":
    main()
