"""Write a benchmark scene of ``bench_visibility.py`` / ``bench_placement.py`` as a GLB, and print what to plan it with.

Usage: ``.venv/bin/python benchmarks/write_benchmark_scene.py street|downtown|city|dense OUT.glb [--resolution 128]
[--cpv-divisions 8] [--sides both|one] [--json]``

The scene is ``bench_visibility.scene_of(NAME)`` (``street``: the 400-building procedural city of
``farfield.core.procedural.city(400, seed=0, detail=16)`` with the view space 1.5..2.5 m over its
ground; ``downtown``: the sparse suburb with 16 towers, 30..40 m up; ``city``: the 400-building city,
above the roofs; ``dense``: 49 buildings of detail 64), written one node per object with its base
colour (``bench_placement_service.write_glb``; ``--sides both``, the default, keeps the objects'
double-sidedness in the materials, so the service plans the scene the in-process benchmarks plan).  Printed, as shell assignments (or JSON with
``--json``): the view space ``X0,Y0,Z0,X1,Y1,Z1`` for ``farfield submit --view-space``, t_max =
half the worst view's estimate with no impostor by the builtin llvmpipe cost model at
``--resolution`` (``bench_placement._worst_view``: CPVs of side / 8, 11.25°, 45° fov; the
benchmarks' reference budget) for ``--frame-ms``, and the CPV size (the view space's longest side /
``--cpv-divisions``) for ``--cpv-size``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_placement import LLVMPIPE_MODEL, _worst_view  # noqa: E402
from bench_placement_service import write_glb  # noqa: E402
from bench_visibility import scene_of  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("name", choices=("street", "downtown", "city", "dense"))
    parser.add_argument("out", help="the GLB to write")
    parser.add_argument("--resolution", type=int, default=128, help="output pixels a side (t_max's model)")
    parser.add_argument("--cpv-divisions", type=int, default=8, help="CPV size = the view space's longest side / this")
    parser.add_argument(
        "--sides",
        choices=("both", "one"),
        default="both",
        help="both: each material doubleSided as the built scene's objects are (the in-process benchmarks' scene); "
        "one: every material one-sided (glTF's default; what bench_placement_service.py writes)",
    )
    parser.add_argument("--json", action="store_true", help="print JSON instead of shell assignments")
    args = parser.parse_args()

    scene, lo, hi = scene_of(args.name)
    worst = _worst_view(scene, lo, hi, LLVMPIPE_MODEL, args.resolution)
    glb = write_glb(scene, Path(args.out), sides=args.sides == "both")
    figures = {
        "glb": str(glb),
        "sides": args.sides,
        "objects": scene.object_count,
        "triangles": scene.triangle_count,
        "view_space": ",".join(f"{x:.6g}" for x in (*lo, *hi)),
        "worst_ms": round(worst, 6),
        "t_max_ms": round(0.5 * worst, 6),
        "cpv_size": round(float(np.max(hi - lo)) / args.cpv_divisions, 6),
    }
    if args.json:
        print(json.dumps(figures))
    else:
        for key, value in figures.items():
            print(f"{key.upper()}={value}")


if __name__ == "__main__":
    main()
