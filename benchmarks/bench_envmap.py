"""Layered environment-map impostors (seed 002) measured side by side in one run.

Usage: ``.venv/bin/python benchmarks/bench_envmap.py [--quick] [--only walkthrough|grid] [--path streets|loop|both] [--before REV] [--grid-cells 8,4,2] [--json] [--out DIR]``

1. Generation per cell at 512 x 512 faces with 64 layers, 4 and 6 directions (the paper: 2.5 min
   per cell on a GeForce 3), with the time of every stage.
2. Memory per cell at each compression step (seed 002 Table 2: 256 MB -> 6 MB -> 288 KB).
3. Walkthrough: a path through a 3 x 1 x 3 grid of 10 m cells in a procedural city of about a
   million triangles; frame time of the full scene vs near field + impostors (same renderer, same
   run), hole pixels and colour error per frame, and a plot (``walkthrough-<path>.png``).  The same
   database and path are walked by the runtime as it is and as it was at git revision ``--before``
   (its ``core/`` from ``git archive``, imported in a fresh process), one after the other in this
   run, so the before/after speed-ups share the machine, the cells and the frames.  The path
   (``--path``) keeps to the two streets of the crossing (``streets``, the default) or is the
   ellipse through the grid's bounding box that ``farfield walkthrough`` generates (``loop``),
   which passes through buildings (27 of its 60 frames in the full run); ``both`` walks each.  Then where
   the runtime's frame goes, on the same path: the near field alone, the layers alone, and one
   quad filling the frame (the renderer's cost per covered pixel).
4. The trade: number of layers (near-field distance) and resolution against memory, generation
   time, frame time and image error, as a table and a plot (``trade.png``).
5. The microtexture grid (``--only grid``): the walkthrough's nine cells baked at each of
   ``--grid-cells`` in turn and walked along the same path by this tree's runtime (each walk in a
   fresh process): quads, texture, bake time, frame times, speed-up, holes and colour error.

The city comes from a seeded ``np.random.default_rng``; the renderer (llvmpipe or a GPU) is printed.
``--quick`` shrinks the city and the settings for a smoke run.
"""

from __future__ import annotations

import argparse
import io
import json
import math
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from farfield.core.impostor.database import ImpostorDatabase, write_database  # noqa: E402
from farfield.core.quality.walkthrough import generate_path, walkthrough, write_plot  # noqa: E402
from farfield.core.render.context import gl_context, renderer_info  # noqa: E402
from farfield.core.render.raster import MeshRenderer  # noqa: E402
from farfield.core.scene import Scene, SceneObject  # noqa: E402
from farfield.core.techniques.envmap.runtime import EnvmapCellRenderer, camera_at, depth_range_for, evaluate_envmap  # noqa: E402
from farfield.core.techniques.envmap.technique import EnvmapOptions, bake_envmap  # noqa: E402
from farfield.core.viewcells import BoxCell, grid_boxes  # noqa: E402

HORIZONTAL = ("+x", "-x", "+z", "-z")


def detailed_city(side: int = 36, subdivisions: int = 3, seed: int = 0) -> Scene:
    """``side`` x ``side`` buildings 20 units apart (y up), each a box subdivided ``subdivisions``
    times (12 x 4^s triangles: 768 at 3), merged into one object per 6 x 6 block, plus a ground.
    36 x 36 at 3 subdivisions is 995,330 triangles."""
    rng = np.random.default_rng(seed)
    unit = trimesh.creation.box(bounds=[[0, 0, 0], [1, 1, 1]])
    for _ in range(subdivisions):
        unit = unit.subdivide()
    uv, uf = np.asarray(unit.vertices), np.asarray(unit.faces)
    blocks: dict[tuple[int, int], list] = {}
    for i in range(side):
        for j in range(side):
            w, d = rng.uniform(6.0, 16.0, 2)
            h = rng.lognormal(math.log(15.0), 0.6)
            low = np.array([i * 20.0 - w / 2, 0.0, j * 20.0 - d / 2])
            grey = rng.uniform(0.3, 0.9)
            # Storeys as colour bands, so the images have detail to get wrong.
            band = (np.floor(uv[:, 1] * h / 3.0) % 2)[:, None]
            colour = np.concatenate(
                [np.clip(255 * (grey - 0.15 * band) * np.array([1.0, 0.97, 0.9]), 0, 255), np.full((len(uv), 1), 255)],
                axis=1,
            )
            blocks.setdefault((i // 6, j // 6), []).append((low + uv * [w, h, d], uf, colour.astype(np.uint8)))
    objects = []
    for (bi, bj), parts in sorted(blocks.items()):
        offsets = np.cumsum([0] + [len(p[0]) for p in parts[:-1]])
        objects.append(
            SceneObject(
                f"block_{bi}_{bj}",
                np.concatenate([p[0] for p in parts]),
                np.concatenate([p[1] + o for p, o in zip(parts, offsets)]),
                vertex_colors=np.concatenate([p[2] for p in parts]),
            )
        )
    extent = side * 20.0
    ground = SceneObject(
        "ground",
        np.array([[-20.0, 0.0, -20.0], [-20.0, 0.0, extent], [extent, 0.0, extent], [extent, 0.0, -20.0]]),
        np.array([[0, 1, 2], [0, 2, 3]]),
        base_color=(0.3, 0.5, 0.25, 1.0),
    )
    return Scene.from_objects([ground, *objects], source=f"detailed-city-{side}-{subdivisions}")


def crossing(side: int) -> float:
    """x (and z) of the street crossing nearest the middle of :func:`detailed_city`: a street
    between lots, whose centres are 20 m apart."""
    return (side // 2) * 20.0 - 10.0


def street_grid(side: int, counts=(3, 1, 3), size: float = 10.0) -> list:
    """Cubic cells of ``size`` over the street crossing nearest the city's middle, eye height 0.5..size+0.5."""
    middle = crossing(side)
    lo = np.array([middle - counts[0] * size / 2, 0.5, middle - counts[2] * size / 2])
    hi = lo + np.array(counts) * size
    return grid_boxes(lo, hi, counts)


def street_path(side: int, frames: int, counts=(3, 1, 3), size: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    """(positions (n, 3), forwards (n, 3)) along the two streets of :func:`street_grid`'s crossing,
    at the cells' middle height, looking along the way: along +x on one street, -z on the other,
    then back along -x and +z over the same ground, each leg starting 5 % inside the cells'
    border and advancing evenly (``frames`` over the four legs).

    Lots are 20 m apart and footprints at most 16 m, so a street's centre line is 2 m or more
    from any building: no frame looks from inside one.

    >>> p, f = street_path(36, 4)
    >>> p.tolist()
    [[335.75, 5.5, 350.0], [350.0, 5.5, 364.25], [364.25, 5.5, 350.0], [350.0, 5.5, 335.75]]
    >>> f.tolist()
    [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    """
    if isinstance(frames, bool) or int(frames) != frames or frames < 1:
        raise ValueError(f"frames must be an integer >= 1, got {frames!r}")
    middle = crossing(side)
    height = 0.5 + counts[1] * size / 2
    reach = 0.95 * min(counts[0], counts[2]) * size / 2
    legs = [((-1, 0), (1, 0)), ((0, 1), (0, -1)), ((1, 0), (-1, 0)), ((0, -1), (0, 1))]  # (start, heading) in (x, z)
    positions, forwards = [], []
    for k in range(int(frames)):
        leg, step = divmod(k * len(legs), int(frames))
        (sx, sz), (hx, hz) = legs[leg]
        t = step / int(frames)  # 0..1 along the leg
        along = -reach + 2.0 * reach * t
        positions.append(
            [middle + sx * reach + hx * (along + reach), height, middle + sz * reach + hz * (along + reach)]
        )
        forwards.append([float(hx), 0.0, float(hz)])
    return np.array(positions), np.array(forwards)


def walk_path(db, side: int, frames: int, path: str) -> tuple[np.ndarray, np.ndarray]:
    """The walkthrough's path: :func:`street_path`, or ``farfield walkthrough``'s loop."""
    if path not in ("streets", "loop"):
        raise ValueError(f"unknown path {path!r}")
    return street_path(side, frames) if path == "streets" else generate_path(db, frames)


def runtime_frame_ms(scene: Scene, impostor, directions, repeats: int = 3) -> tuple[float, float]:
    """Mean frame time (ms) over the cell's corners and centre looking along ``directions``:
    (full scene, near field + impostors), same renderer."""
    cell = BoxCell(np.asarray(impostor.viewcell["lo"]), np.asarray(impostor.viewcell["hi"]))
    axes = {"+x": (1, 0, 0), "-x": (-1, 0, 0), "+z": (0, 0, 1), "-z": (0, 0, -1), "+y": (0, 1, 0), "-y": (0, -1, 0)}
    points = np.concatenate([cell.corners(), cell.center[None]])
    runtime = EnvmapCellRenderer(scene, impostor)
    full_ms, fast_ms = [], []
    try:
        with MeshRenderer(scene.objects) as full:
            for p in points:
                near, far = depth_range_for(scene, cell, p, runtime.reach)
                for d in directions:
                    camera = camera_at(p, axes[d], impostor.fov_deg, impostor.resolution, near, far)
                    full_ms.append(1e3 * np.median([full.frame_seconds(camera) for _ in range(repeats)]))
                    fast_ms.append(1e3 * np.median([runtime.renderer.frame_seconds(camera) for _ in range(repeats)]))
    finally:
        runtime.release()
    return float(np.mean(full_ms)), float(np.mean(fast_ms))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small city and settings (smoke run)")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--out", default="benchmarks/out", help="folder for the plots")
    parser.add_argument("--only", choices=("walkthrough", "grid"), help="run only this part")
    parser.add_argument(
        "--grid-cells", default="8,4,2", help="microtexture grids of part 5, comma-separated (default 8,4,2)"
    )
    parser.add_argument(
        "--before", default="8392e0a", help="git revision whose runtime is walked beside this tree's ('' for none)"
    )
    parser.add_argument(
        "--path",
        choices=("streets", "loop", "both"),
        default="streets",
        help="the walkthrough's path (default: along the streets)",
    )
    parser.add_argument(
        "--walk", nargs=5, metavar=("DIR", "SIDE", "SUBDIVISIONS", "FRAMES", "PATH"), help=argparse.SUPPRESS
    )  # internal: one walk, JSON out
    args = parser.parse_args()
    if args.walk:
        directory, side, subdiv, frames, path = args.walk
        print(json.dumps(walk_database(Path(directory), int(side), int(subdiv), int(frames), path), default=float))
        return
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    side, subdiv = (12, 1) if args.quick else (36, 3)
    res, layers, frames = (128, 16, 12) if args.quick else (512, 64, 60)
    gl_context()
    info = renderer_info()
    print(f"renderer: {info.renderer} ({info.vendor}, {info.version})")
    t = time.perf_counter()
    scene = detailed_city(side, subdiv)
    print(
        f"city: {scene.triangle_count:,} triangles in {scene.object_count} objects (built in {time.perf_counter() - t:.1f} s)"
    )
    cells = street_grid(side)
    report: dict = {"renderer": info.renderer, "triangles": scene.triangle_count}

    # 1 + 2: generation and memory per cell, 4 and 6 directions, on the middle cell.
    middle = cells[len(cells) // 2][1]
    if args.only is None:
        generation(scene, middle, res, layers, report)
    if args.only in (None, "walkthrough"):
        walkthrough_section(args, scene, cells, res, layers, frames, side, subdiv, info, out, report)
    if args.only is None:
        trade(args, scene, middle, info, out, report)
    if args.only in (None, "grid"):
        grid_section(args, scene, cells, res, layers, frames, side, subdiv, report)
    if args.json:
        print(json.dumps(report, indent=1, default=float))


def generation(scene: Scene, middle: BoxCell, res: int, layers: int, report: dict) -> None:
    print(
        f"\n1-2. one cell ({middle.size[0]:.0f} m cube at {middle.center.tolist()}), {res} x {res} faces, {layers} layers"
    )
    print(
        f"{'dirs':>4} {'near field':>10} {'layers':>6} {'quads':>6} {'raw MB':>8} {'macro MB':>9} {'PNG KB':>8} {'raw/macro':>9} {'macro/PNG':>9} {'total s':>8}  stages (s)"
    )
    rows = []
    for directions in (HORIZONTAL, ("+x", "-x", "+y", "-y", "+z", "-z")):
        imp = bake_envmap(
            scene, middle, EnvmapOptions(resolution=res, fov_deg=90.0, layers=layers, directions=directions)
        )
        s = imp.stats
        row = {
            "directions": len(directions),
            **{k: s[k] for k in ("near_field", "layers", "quads", "raw_layer_bytes", "texture_bytes", "png_bytes")},
            "seconds": s["seconds"],
        }
        rows.append(row)
        stages = " ".join(f"{k} {v:.2f}" for k, v in s["seconds"].items() if k != "total")
        print(
            f"{len(directions):>4} {s['near_field']:>10.1f} {s['layers']:>6} {s['quads']:>6} {s['raw_layer_bytes'] / 1e6:>8.1f} "
            f"{s['texture_bytes'] / 1e6:>9.2f} {s['png_bytes'] / 1e3:>8.1f} {s['raw_layer_bytes'] / s['texture_bytes']:>9.1f} "
            f"{s['texture_bytes'] / s['png_bytes']:>9.1f} {s['seconds']['total']:>8.2f}  {stages}"
        )
    print("   seed 002 Table 2 (4 directions, 512, 64 layers): 256 MB -> 6.0 MB -> 0.288 MB, ratios 42.5 and 20.9")
    report["cell"] = rows


def walkthrough_section(
    args, scene: Scene, cells, res: int, layers: int, frames: int, side: int, subdiv: int, info, out: Path, report: dict
) -> None:
    """3: a walkthrough through a 3 x 1 x 3 grid, the runtime before and after."""
    print(f"\n3. walkthrough: {len(cells)} cells, 6 directions, {frames} frames")
    options = EnvmapOptions(resolution=res, fov_deg=90.0, layers=layers)
    t = time.perf_counter()
    baked = [(list(ijk), bake_envmap(scene, box, options)) for ijk, box in cells]
    bake_s = time.perf_counter() - t
    print(f"   baked in {bake_s:.1f} s ({bake_s / len(cells):.2f} s per cell)")
    tmp_db = tempfile.TemporaryDirectory()
    write_database(Path(tmp_db.name) / "db", "envmap", {}, baked)
    for path in ("streets", "loop") if args.path == "both" else (args.path,):
        walk_path_section(
            args,
            scene,
            Path(tmp_db.name),
            res,
            layers,
            frames,
            side,
            subdiv,
            info,
            out,
            report,
            path,
            bake_s / len(cells),
        )
    tmp_db.cleanup()


def walk_path_section(
    args,
    scene: Scene,
    directory: Path,
    res: int,
    layers: int,
    frames: int,
    side: int,
    subdiv: int,
    info,
    out: Path,
    report: dict,
    path: str,
    bake_per_cell: float,
) -> None:
    """3, on one path: the runtime before and after, then where its frame goes."""
    print(f"   path: {path}")
    runs = {}
    for label, rev in ([("before", args.before)] if args.before else []) + [("after", None)]:
        runs[label] = walk_in_process(directory, side, subdiv, frames, path, rev)
    walk = runs["after"]
    write_plot(
        walk,
        out / f"walkthrough-{path}.png",
        title=f"{scene.triangle_count:,}-triangle city, {res}x{res}, {layers} layers, {path} ({info.renderer})",
    )
    print(
        f"   {'runtime':<16} {'full ms':>8} {'runtime ms':>10} {'max ms':>7} {'speed-up':>8} {'holes':>6} {'colour err':>10}"
    )
    for label, run in runs.items():
        s = run["summary"]
        name = f"{label} ({args.before})" if label == "before" else "after (this tree)"
        print(
            f"   {name:<16} {s['full_ms_mean']:>8.1f} {s['impostor_ms_mean']:>10.2f} {s['impostor_ms_max']:>7.1f} {s['speedup_mean']:>7.2f}x "
            f"{s['hole_pixels']:>6} {s['colour_error_mean']:>10.3f}"
        )
    s = walk["summary"]
    print(
        f"   {s['cell_switches']} cell switches; largest colour difference {s['colour_error_max']} (0-255); plot: {out / f'walkthrough-{path}.png'}"
    )
    if "before" in runs:
        b = runs["before"]["summary"]
        print(
            f"   runtime frame {b['impostor_ms_mean']:.2f} -> {s['impostor_ms_mean']:.2f} ms ({b['impostor_ms_mean'] / s['impostor_ms_mean']:.2f}x); speed-up over the full scene {b['speedup_mean']:.2f}x -> {s['speedup_mean']:.2f}x"
        )
        report[f"walkthrough_before_{path}"] = {"revision": args.before, "summary": b}
    report[f"walkthrough_{path}"] = {"summary": s, "bake_seconds_per_cell": bake_per_cell}
    report[f"walkthrough_parts_{path}"] = frame_parts(scene, directory, frames, res, side, path)


def frame_parts(scene: Scene, directory: Path, frames: int, res: int, side: int, path: str) -> dict:
    """Mean ms per frame along the walkthrough's path (best of 5 draws a frame) of the full scene,
    the runtime, its near field alone and its layers alone, and of one opaque quad filling a
    frame of ``res`` pixels."""
    times: dict[str, list] = {}
    with ImpostorDatabase(directory / "db") as db, MeshRenderer(scene.objects) as full:
        positions, forwards = walk_path(db, side, frames, path)
        current, parts = None, {}
        try:
            for position, forward in zip(positions, forwards):
                found = db.find(position)
                if found is None or found.bundle is None:
                    continue
                if found.index != current:
                    for renderer in parts.values():
                        renderer.release()
                    current, runtime = found.index, EnvmapCellRenderer(scene, db.impostor(found.index))
                    near = [obj for obj, *_ in runtime.renderer._draws][: len(runtime.near.objects(scene))]
                    layers = [obj for obj, *_ in runtime.renderer._draws][len(near) :]
                    parts = {
                        "runtime": runtime.renderer,
                        "near field": MeshRenderer(near, [runtime.near.clip] * len(near)),
                        "layers": MeshRenderer(layers),
                    }
                camera = camera_at(
                    position,
                    forward,
                    runtime.impostor.fov_deg,
                    runtime.impostor.resolution,
                    *depth_range_for(scene, found.viewcell, position, runtime.reach),
                )
                for name, renderer in [("full scene", full), *parts.items()]:
                    renderer.frame_seconds(camera)
                    times.setdefault(name, []).append(min(renderer.frame_seconds(camera) for _ in range(5)))
        finally:
            for renderer in parts.values():
                renderer.release()
    wall = SceneObject(
        "wall",
        np.array([[-1.0, -1.0, 1.0], [1.0, -1.0, 1.0], [1.0, 1.0, 1.0], [-1.0, 1.0, 1.0]]),
        np.array([[0, 1, 2], [0, 2, 3]]),
    )
    with MeshRenderer([wall]) as one:
        camera = camera_at(np.zeros(3), [0.0, 0.0, 1.0], 60.0, res, 0.1, 10.0)
        one.frame_seconds(camera)
        times["one quad filling the frame"] = [min(one.frame_seconds(camera) for _ in range(30))]
    out = {name: 1e3 * float(np.mean(v)) for name, v in times.items()}
    print("   where the runtime's frame goes (same path, best of 5 draws a frame, mean ms):")
    for name, ms in out.items():
        print(f"     {name:<28} {ms:7.2f}")
    return out


def walk_database(directory: Path, side: int, subdiv: int, frames: int, path: str) -> dict:
    """The walkthrough of the database in ``directory``/db along ``path`` (``--walk``)."""
    gl_context()
    scene = detailed_city(side, subdiv)
    with ImpostorDatabase(directory / "db") as db:
        positions, forwards = walk_path(db, side, frames, path)
        return walkthrough(scene, db, positions, forwards, repeats=3)


def archived(revision: str, folder: Path) -> Path:
    """A folder in ``folder`` whose ``farfield`` package is the ``core/`` of git ``revision`` (put it
    first on a child process's import path to run that revision's code)."""
    root = folder / f"rev-{revision}"
    package = root / "farfield"
    package.mkdir(parents=True, exist_ok=True)
    archive = subprocess.run(["git", "archive", revision, "core"], check=True, capture_output=True, cwd=ROOT).stdout
    with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
        tar.extractall(package, filter="data")
    (package / "__init__.py").write_text("")
    return root


def walk_in_process(directory: Path, side: int, subdiv: int, frames: int, path: str, revision: str | None) -> dict:
    """:func:`walk_database` in a fresh process: with this tree's ``farfield``, or with the ``core/``
    of git ``revision`` (extracted beside ``directory`` and put first on the import path)."""
    env = dict(os.environ)
    if revision is not None:
        root = archived(revision, directory)
        env["PYTHONPATH"] = os.pathsep.join([str(root), env.get("PYTHONPATH", "")])
    command = [
        sys.executable,
        str(Path(__file__).resolve()),
        "--walk",
        str(directory),
        str(side),
        str(subdiv),
        str(frames),
        path,
    ]
    result = subprocess.run(command, check=True, capture_output=True, text=True, env=env, cwd=directory)
    return json.loads(result.stdout.strip().splitlines()[-1])


def grid_section(
    args, scene: Scene, cells, res: int, layers: int, frames: int, side: int, subdiv: int, report: dict
) -> None:
    """5: the walkthrough's cells baked at each microtexture grid, walked by this tree's runtime."""
    grids = [int(g) for g in args.grid_cells.split(",")]
    path = "loop" if args.path == "loop" else "streets"
    print(
        f"\n5. microtexture grid: {len(cells)} cells, {res}, {layers} layers, walked along {path} ({frames} frames, each walk in a fresh process)"
    )
    print(
        f"   {'grid':>4} {'quads':>7} {'texture MB':>10} {'bake s':>7} {'full ms':>8} {'runtime ms':>10} {'speed-up':>8} {'holes':>6} {'colour err':>10}"
    )
    rows = []
    for grid in grids:
        options = EnvmapOptions(resolution=res, fov_deg=90.0, layers=layers, grid_cell=grid)
        t = time.perf_counter()
        baked = [(list(ijk), bake_envmap(scene, box, options)) for ijk, box in cells]
        bake_s = time.perf_counter() - t
        with tempfile.TemporaryDirectory() as tmp:
            write_database(Path(tmp) / "db", "envmap", {}, baked)
            s = walk_in_process(Path(tmp), side, subdiv, frames, path, None)["summary"]
        row = {
            "grid_cell": grid,
            "quads": sum(imp.stats["quads"] for _, imp in baked),
            "texture_bytes": sum(imp.stats["texture_bytes"] for _, imp in baked),
            "bake_s": bake_s,
            **s,
        }
        rows.append(row)
        print(
            f"   {grid:>4} {row['quads']:>7,} {row['texture_bytes'] / 1e6:>10.1f} {bake_s:>7.1f} {s['full_ms_mean']:>8.1f} {s['impostor_ms_mean']:>10.2f} "
            f"{s['speedup_mean']:>7.2f}x {s['hole_pixels']:>6} {s['colour_error_mean']:>10.3f}"
        )
    report["grid"] = rows


def trade(args, scene: Scene, middle: BoxCell, info, out: Path, report: dict) -> None:
    """4: the trade, on the middle cell, horizontal directions."""
    print("\n4. trade (middle cell, 4 directions; frame times and errors over its 8 corners and centre)")
    print(
        f"{'res':>5} {'layers':>6} {'near field':>10} {'quads':>6} {'macro MB':>9} {'PNG KB':>8} {'gen s':>7} {'full ms':>8} {'imp ms':>7} {'holes':>6} {'err mean':>8}"
    )
    rows = []
    settings = (
        [(128, 8), (128, 16)] if args.quick else [(256, 16), (256, 32), (256, 64), (512, 16), (512, 32), (512, 64)]
    )
    for r, k in settings:
        t = time.perf_counter()
        imp = bake_envmap(scene, middle, EnvmapOptions(resolution=r, fov_deg=90.0, layers=k, directions=HORIZONTAL))
        gen = time.perf_counter() - t
        full_ms, fast_ms = runtime_frame_ms(scene, imp, HORIZONTAL, repeats=2)
        axes = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 0, 1.0], [0, 0, -1.0]])
        ev = evaluate_envmap(scene, imp, random_count=0, samples=1, directions=axes)["totals"]
        row = {"resolution": r, "layers": k, "near_field": imp.stats["near_field"], "quads": imp.stats["quads"], "texture_bytes": imp.stats["texture_bytes"],
               "png_bytes": imp.stats["png_bytes"], "generation_s": gen, "full_ms": full_ms, "impostor_ms": fast_ms,
               "hole_pixels": ev["hole_pixels"], "colour_error_mean": ev["colour_error_mean"]}  # fmt: skip
        rows.append(row)
        print(
            f"{r:>5} {k:>6} {row['near_field']:>10.1f} {row['quads']:>6} {row['texture_bytes'] / 1e6:>9.2f} {row['png_bytes'] / 1e3:>8.1f} "
            f"{gen:>7.2f} {full_ms:>8.1f} {fast_ms:>7.2f} {row['hole_pixels']:>6} {row['colour_error_mean']:>8.3f}"
        )
    report["trade"] = rows
    _trade_plot(rows, out / "trade.png", info.renderer)
    print(f"   plot: {out / 'trade.png'}")


def _trade_plot(trade: list[dict], path: Path, renderer: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 4, figsize=(15, 3.8))
    for r in sorted({row["resolution"] for row in trade}):
        rows = [row for row in trade if row["resolution"] == r]
        k = [row["layers"] for row in rows]
        axes[0].plot(k, [row["near_field"] for row in rows], marker="o", label=f"{r}")
        axes[1].plot(k, [row["texture_bytes"] / 1e6 for row in rows], marker="o", label=f"{r}")
        axes[2].plot(k, [row["generation_s"] for row in rows], marker="o", label=f"{r}")
        axes[3].plot(k, [row["impostor_ms"] for row in rows], marker="o", label=f"{r} impostors")
        axes[3].plot(k, [row["full_ms"] for row in rows], linestyle=":", color="grey")
    for ax, title in zip(
        axes, ("near-field distance (m)", "macrotextures (MB)", "generation (s)", "frame time (ms; dotted: full scene)")
    ):
        ax.set_xlabel("layers")
        ax.set_title(title)
        ax.legend(title="resolution")
    fig.suptitle(f"envmap trade, one 10 m cell, 4 directions ({renderer})")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    main()
