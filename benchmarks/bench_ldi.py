"""An LDI cell against rendering its nine construction images, side by side in one run (issue 60 item 5).

Usage: ``.venv/bin/python benchmarks/bench_ldi.py [--resolutions 256 512] [--buildings 144] [--detail 400] [--repeat 2] [--json]``

For each scene and resolution, after a warm-up bake (EGL context, shaders, numba kernels):

(a) **nine images**: the part's objects (as the bake draws them: the side the cell sees) uploaded
    once to a :class:`~farfield.core.render.raster.MeshRenderer` and drawn from the nine
    construction cameras (:func:`farfield.core.ldi.construction.construction_cops`, each the
    square window around the part from its centre of projection) at the LDI's resolution, each
    image read back: what "a few renders of the scene" costs with the project's plain renderer.
(b) **the LDI cell**: :func:`farfield.core.techniques.ldi.bake_ldi` of the same part and cell
    (``channels=albedo``, as a primitive-budget job bakes its images), by stage (its
    ``stats["seconds"]``), then its bundle written (:func:`farfield.core.impostor.bundle.write_bundle`:
    the PNG pages and the GLB).  With ``channels=albedo+normal`` a second bake gives the
    ``normals`` stage (normals, and materials where the part has them).

Each of (a) and (b) is run ``--repeat`` times, alternately, and the fastest run kept.  The ratio is
(b) / (a).  Scenes: a procedural city (``procedural.city(buildings, detail=...)``; 144 and 400 give
about 1.76 M triangles), its LDI taken from a 10 m cell 160 m in front of it, the whole city the
part; and the shared Damaged Helmet (textured, 15,452 triangles) from a cell three model sizes
away.  The renderer is printed: on this project's 2-core machine that is Mesa llvmpipe, shared
with other jobs, so the absolute seconds vary from run to run; the ratio, measured side by side,
varies less.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from farfield.core import procedural  # noqa: E402
from farfield.core.exchange import load_scene  # noqa: E402
from farfield.core.impostor.bundle import write_bundle  # noqa: E402
from farfield.core.ldi.construction import _window, construction_cops, ldi_camera, view_frame  # noqa: E402
from farfield.core.render.context import renderer_info  # noqa: E402
from farfield.core.render.raster import MeshRenderer  # noqa: E402
from farfield.core.sidedness import seen_from_cell  # noqa: E402
from farfield.core.techniques.ldi import LdiOptions, bake_ldi, ldi_view  # noqa: E402
from farfield.core.viewcells import BoxCell  # noqa: E402

# ../shared/scenes beside the checkout (or beside the folder of worktrees)
SHARED = next(
    (p / "shared" / "scenes" for p in Path(__file__).resolve().parents[2:4] if (p / "shared" / "scenes").is_dir()),
    Path(),
)
SHARED = Path(os.environ.get("FARFIELD_SHARED_SCENES", SHARED))
HELMET = SHARED / "damaged_helmet" / "DamagedHelmet.glb"


def construction_cameras(scene, cell, resolution: int) -> list:
    """The nine construction cameras of the bake of ``scene`` for ``cell`` (as construct_ldi makes them)."""
    view = ldi_view(cell, scene.bounds)
    vertices = np.concatenate([o.vertices[np.unique(o.faces)] for o in scene.objects])
    far = float(((vertices - view.eye) @ view_frame(view.direction)[2]).max()) * (1 + 1e-6)
    camera = ldi_camera(view.eye, view.direction, view.quad, view.depth, far, resolution)
    return [
        camera if np.array_equal(cop, view.eye) else _window(vertices, cop, view.direction, resolution)
        for cop in construction_cops(view.eye, view.quad)
    ]


def nine_images(objects, cameras) -> dict:
    """Seconds to upload ``objects`` once and draw and read back the nine images."""
    start = time.perf_counter()
    with MeshRenderer(objects) as renderer:
        uploaded = time.perf_counter()
        for camera in cameras:
            renderer.render(camera)
        drawn = time.perf_counter()
    return {"upload": uploaded - start, "render": drawn - uploaded, "total": drawn - start}


def ldi_cell(scene, cell, resolution: int, channels: str = "albedo") -> tuple[dict, dict]:
    """(seconds by stage with ``bundle`` and ``total``, the bake's statistics) of one LDI cell."""
    start = time.perf_counter()
    impostor = bake_ldi(scene, cell, LdiOptions(resolution=resolution, channels=channels))
    baked = time.perf_counter()
    with tempfile.TemporaryDirectory() as folder:
        write_bundle(impostor, Path(folder) / "ldi")
    end = time.perf_counter()
    stages = {k: v for k, v in impostor.stats["seconds"].items() if k != "total"}
    stages["other"] = max(0.0, (baked - start) - sum(stages.values()))
    stages["bundle"] = end - baked
    stages["total"] = end - start
    return stages, impostor.stats


def scenes(args) -> list[tuple[str, object, BoxCell]]:
    city = procedural.city(args.buildings, seed=0, detail=args.detail)
    lo, hi = city.bounds
    centre = np.array([0.5 * (lo[0] + hi[0]), 30.0, lo[2] - 150.0])
    out = [(f"city({args.buildings}, detail={args.detail})", city, BoxCell.from_center(centre, 10.0))]
    if HELMET.exists():
        helmet = load_scene(HELMET)
        lo, hi = helmet.bounds
        size = float(np.linalg.norm(hi - lo))
        centre = 0.5 * (lo + hi) + np.array([0.3, 0.2, 1.0]) * 3.0 * size
        out.append(("Damaged Helmet", helmet, BoxCell.from_center(centre, 0.2 * size)))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolutions", type=int, nargs="+", default=[256, 512])
    parser.add_argument("--buildings", type=int, default=144)
    parser.add_argument("--detail", type=int, default=400)
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    info = renderer_info()
    print(f"renderer: {info.renderer} ({info.version})")
    warm = procedural.city(4, seed=0, detail=2)
    warm_cell = BoxCell.from_center(np.array([20.0, 5.0, -60.0]), 2.0)
    ldi_cell(warm, warm_cell, 32, "albedo+normal")
    nine_images(list(warm.objects), construction_cameras(warm, warm_cell, 32))
    rows = []
    for name, scene, cell in scenes(args):
        drawn = list(seen_from_cell(scene.objects, cell))
        for resolution in args.resolutions:
            cameras = construction_cameras(scene, cell, resolution)
            images, bakes = [], []
            for _ in range(args.repeat):
                images.append(nine_images(drawn, cameras))
                bakes.append(ldi_cell(scene, cell, resolution))
            a = min(images, key=lambda r: r["total"])
            b, stats = min(bakes, key=lambda r: r[0]["total"])
            normals, _ = ldi_cell(scene, cell, resolution, "albedo+normal")
            rows.append({"scene": name, "triangles": scene.triangle_count, "resolution": resolution, "nine_images": a, "ldi": b,
                         "ratio": b["total"] / a["total"], "normals_s": normals.get("normals", 0.0), "normal_bake_s": normals["total"],
                         "samples": stats["samples"], "layers": stats["layers"]})  # fmt: skip
            print_row(rows[-1])
    if args.json:
        print(json.dumps({"renderer": info.renderer, "rows": rows}, indent=1))


def print_row(row: dict) -> None:
    a, b = row["nine_images"], row["ldi"]
    print(
        f"\n{row['scene']}: {row['triangles']:,} triangles, {row['resolution']} px, {row['samples']:,} samples in {row['layers']} layers"
    )
    print(f"  (a) nine images: upload {a['upload']:.3f} s + 9 renders {a['render']:.3f} s = {a['total']:.3f} s")
    total = b["total"]
    stages = "  ".join(f"{k} {v:.3f} ({100 * v / total:.0f} %)" for k, v in b.items() if k != "total")
    print(f"  (b) LDI cell {total:.3f} s: {stages}")
    print(
        f"  ratio (b)/(a) = {row['ratio']:.2f}   [albedo+normal bake {row['normal_bake_s']:.3f} s, of it normals {row['normals_s']:.3f} s]"
    )


if __name__ == "__main__":
    main()
