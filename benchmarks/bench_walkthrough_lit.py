"""The lit walkthrough on the benchmark city: the envmap runtime's impostors lit with their normal
pages against the same cells drawn as flat cards, frame by frame along the street path, and what
the lit draw costs.

Usage: ``.venv/bin/python benchmarks/bench_walkthrough_lit.py [--side 36] [--subdivisions 3] [--resolution 256] [--layers 32] [--frames 24] [--repeats 3] [--json]``

The city, the cells and the path are ``bench_envmap.py``'s (:func:`bench_envmap.detailed_city`, a
3 x 1 x 3 grid of 10 m cells over the middle street crossing, :func:`bench_envmap.street_path`),
baked twice, with ``channels=albedo+normal`` and with ``channels=albedo`` (the four horizontal
faces), and walked twice under the five test lights (:func:`farfield.core.quality.lighting.default_lights`)
by :func:`farfield.core.quality.walkthrough.walkthrough`: per light the lit error of the whole frame
and of the far field (what the near field leaves), the flat cards' and the unlit error; the frame
times of the unlit draw, of the G-buffer draw (GL), of the GL's shading pass and of the numpy
shading of one light.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_envmap import HORIZONTAL, detailed_city, street_grid, street_path  # noqa: E402

from farfield.core.impostor.database import ImpostorDatabase, write_database  # noqa: E402
from farfield.core.quality.lighting import default_lights  # noqa: E402
from farfield.core.quality.walkthrough import walkthrough  # noqa: E402
from farfield.core.render.context import gl_context, renderer_info  # noqa: E402
from farfield.core.techniques.envmap.technique import EnvmapOptions, bake_envmap  # noqa: E402


def run(args) -> dict:
    gl_context()
    info = renderer_info()
    scene = detailed_city(args.side, args.subdivisions)
    cells = street_grid(args.side)
    positions, forwards = street_path(args.side, args.frames)
    lights = default_lights()
    report = {"renderer": info.renderer, "triangles": scene.triangle_count, "cells": len(cells), "runs": {}}
    print(
        f"renderer: {info.renderer}; city {scene.triangle_count:,} triangles, {len(cells)} cells, {args.frames} frames"
    )
    with tempfile.TemporaryDirectory() as tmp:
        for channels in ("albedo+normal", "albedo"):
            options = EnvmapOptions(resolution=args.resolution, layers=args.layers, fov_deg=90.0,
                                    directions=HORIZONTAL, channels=channels)  # fmt: skip
            start = time.perf_counter()
            baked = [(list(ijk), bake_envmap(scene, box, options)) for ijk, box in cells]
            bake_s = time.perf_counter() - start
            root = write_database(Path(tmp) / channels.replace("+", "-"), "envmap", {}, baked)
            start = time.perf_counter()
            with ImpostorDatabase(root) as db:
                result = walkthrough(scene, db, positions, forwards, repeats=args.repeats, lights=lights)
            s = result["summary"]
            report["runs"][channels] = {"bake_s": bake_s, "walk_s": time.perf_counter() - start, "summary": s}
            lit = s["lit"]
            print(f"\n{channels}: baked in {bake_s:.1f} s; {s['frames_served']} of {s['frames']} frames served")
            print(f"  unlit frame {s['impostor_ms_mean']:.2f} ms runtime vs {s['full_ms_mean']:.2f} ms full scene; "
                  f"G-buffer {lit['impostor_gbuffer_ms_mean']:.2f} ms runtime vs {lit['full_gbuffer_ms_mean']:.2f} ms full; "
                  f"shading pass (GL) {lit['shade_gl_ms_mean']:.2f} ms, numpy {lit['shade_ms_mean']:.2f} ms a light")  # fmt: skip
            print(f"  far field: {lit['far']['both_pixels']} of {lit['both_pixels']} pixels both cover")
            print(f"  {'light':<24} {'lit':>6} {'flat':>6} {'unlit':>6} | far: {'lit':>6} {'flat':>6} {'unlit':>6}")
            for source, whole, far in zip(lit["sources"], lit["lights"], lit["far"]["lights"]):
                direction = "(" + ", ".join(f"{x:+.2f}" for x in source["direction"]) + ")"
                print(f"  {direction:<24} {whole['lit_error_mean']:>6.2f} {whole['flat_error_mean']:>6.2f} "
                      f"{whole['unlit_error_mean']:>6.2f} |      {far['lit_error_mean']:>6.2f} {far['flat_error_mean']:>6.2f} "
                      f"{far['unlit_error_mean']:>6.2f}")  # fmt: skip
    return report


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--side", type=int, default=36)
    parser.add_argument("--subdivisions", type=int, default=3)
    parser.add_argument("--resolution", type=int, default=256)
    parser.add_argument("--layers", type=int, default=32)
    parser.add_argument("--frames", type=int, default=24)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    report = run(args)
    if args.json:
        print(json.dumps(report, indent=1, default=float))


if __name__ == "__main__":
    main()
