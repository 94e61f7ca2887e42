"""Lit textured depth meshes: the normal channel's cost and what it buys, per scene.

Usage: ``.venv/bin/python benchmarks/bench_tdm_lit.py [--resolution R] [--random N] [--scenes duck,house]``

As :mod:`bench_lit` (same scenes, same cell: a cube a fifth of the part's size, three part sizes in
front of it along +z) for the ``tdm`` technique: one bake with ``channels=albedo`` and one with
``channels=albedo+normal``, side by side in one run (bake seconds, texture memory per channel, the
GLB's bytes and vertices unlit and lit: the lit GLB's vertices carry NORMAL and TANGENT and are split
per handedness), then the lit evaluation of the normal bake: unlit colour error, lit error under
the worst light, flat cards, the ratios of issue 55's targets and the normal angle error.  The
renderer (llvmpipe or a GPU) is printed.
"""

from __future__ import annotations

import argparse
import json
import struct
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_lit import scenes  # noqa: E402

from farfield.core.impostor.glb import impostor_glb  # noqa: E402
from farfield.core.quality.lit import evaluate_lit, lit_figures  # noqa: E402
from farfield.core.render.context import renderer_info  # noqa: E402
from farfield.core.techniques.tdm.technique import TdmOptions, bake_tdm  # noqa: E402
from farfield.core.viewcells import BoxCell  # noqa: E402


def glb_vertices(data: bytes) -> int:
    """Vertices of a GLB's primitives (their POSITION accessors' counts)."""
    document = json.loads(data[20 : 20 + struct.unpack_from("<I", data, 12)[0]])
    accessors = document["accessors"]
    return sum(accessors[p["attributes"]["POSITION"]]["count"] for p in document["meshes"][0]["primitives"])


def run(resolution: int, random_count: int, names: list[str] | None) -> list[dict]:
    rows = []
    for name, make in scenes().items():
        if names and name not in names:
            continue
        scene = make()
        lo, hi = scene.bounds
        size = float(np.max(hi - lo))
        cell = BoxCell.from_center(0.5 * (lo + hi) + np.array([0.0, 0.0, 3.0 * size]), 0.2 * size)
        bakes = {}
        for channels in ("albedo", "albedo+normal"):
            bake_tdm(scene, cell, TdmOptions(resolution=32, channels=channels))  # numba kernels warm
            start = time.perf_counter()
            impostor = bake_tdm(scene, cell, TdmOptions(resolution=resolution, channels=channels))
            seconds = time.perf_counter() - start
            start = time.perf_counter()
            glb = impostor_glb(impostor)
            bakes[channels] = (impostor, seconds, glb, time.perf_counter() - start)
        impostor = bakes["albedo+normal"][0]
        lit = evaluate_lit(scene, impostor, random_count=random_count)
        rows.append(
            {
                "scene": name,
                "triangles": scene.triangle_count,
                "tdm_triangles": impostor.triangle_count,
                "has_normals": all(o.normals is not None for o in scene.objects),
                "bake_s_albedo": bakes["albedo"][1],
                "bake_s_normal": bakes["albedo+normal"][1],
                "glb_s_albedo": bakes["albedo"][3],
                "glb_s_normal": bakes["albedo+normal"][3],
                "channel_bytes": impostor.stats["channel_bytes"],
                "glb_kib_albedo": len(bakes["albedo"][2]) / 1024,
                "glb_kib_normal": len(bakes["albedo+normal"][2]) / 1024,
                "glb_vertices_albedo": glb_vertices(bakes["albedo"][2]),
                "glb_vertices_normal": glb_vertices(bakes["albedo+normal"][2]),
                **lit_figures(lit),
            }
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, default=256)
    parser.add_argument("--random", type=int, default=2)
    parser.add_argument("--scenes", default="")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    rows = run(args.resolution, args.random, [s for s in args.scenes.split(",") if s])
    if args.json:
        print(json.dumps(rows, indent=1))
        return
    print(f"renderer: {renderer_info()}; tdm at {args.resolution} px")
    for r in rows:
        print(json.dumps({k: v for k, v in r.items() if k != "lights"}))
        for row in r["lights"]:
            print("   ", {k: round(v, 2) if isinstance(v, float) else v for k, v in row.items()})


if __name__ == "__main__":
    main()
