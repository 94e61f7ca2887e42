"""Octahedral impostors measured: error against distance beside the computed accuracy distance, the
layered impostors at equal memory, and the lit error with and without the material channel.

Three sections (``--section``, default all), each printing its tables (``--markdown PATH`` appends
them as markdown, the tables of docs/techniques/octahedral.md and docs/measurements/octahedral.md):

``distance``
    Per part (the procedural tree of three boxes, and the shared helmet, scrub pine and duck) and per
    grid N x N (8, 12, 16, 24, 32) and frame resolution (32 and 64 texels): the bake's computed
    accuracy distance for the output (``--resolution`` px, default 64, at 45°), then hole pixels and
    pixels bloated beyond one pixel and the mean colour error (farfield.core.quality.evaluation,
    2 x 2 samples per pixel, coarse errors confirmed at the fine sampling), against the real
    geometry from the outside-sphere cell's 14 corner viewpoints (top-down, from below, grazing from
    four sides, four at 45° above and four below) and 2 seeded random directions, at each distance of
    a ladder of fractions of the accuracy distance (sqrt 2 ... 1/8, steps of sqrt 2, measured from far
    to near and, without ``--full-ladder``, stopped after two rungs in error: "-").  The
    **measured** accuracy distance is the smallest distance of the ladder from which every sampled
    view, there and at every farther rung, is within one pixel (no hole, no bloat beyond one).
``layered``
    At equal memory: six layered impostors (square shaft cells of 90° around +-x, +-y, +-z: the cube's
    faces, together every direction) for viewpoints ``k`` to ``2k`` bounding radii away, against the
    octahedral impostor (frame resolution 32) whose grid gives the nearest texture memory; error from
    each shaft's corners and 2 random points (the octahedral from the same points), memory, bake
    time, and the time to draw one frame at 512 px (llvmpipe: the shader's cost, see the docs).
``lit``
    The helmet's lit error (farfield.core.quality.lit, five test lights, 2 x 2 samples) with the
    material channel against without (matte), 4 radii away.

    python benchmarks/bench_octahedral.py [--section distance|layered|lit] [--parts tree,helmet,pine,duck]
        [--grids 8,12,16,24,32] [--frames 32,64] [--resolution 64] [--full-ladder] [--markdown PATH]

The distance section takes about 33 minutes with ``--full-ladder`` on the 2-core llvmpipe machine (its
nearest rungs at the largest grids cost most: the part fills the view), the layered section about
10, the lit one 1.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from farfield.core.exchange import load_scene  # noqa: E402
from farfield.core.procedural import box_object  # noqa: E402
from farfield.core.quality.evaluation import depth_bounds, evaluate_at  # noqa: E402
from farfield.core.render.context import renderer_info  # noqa: E402
from farfield.core.render.raster import Camera  # noqa: E402
from farfield.core.scene import Scene  # noqa: E402
from farfield.core.techniques import get_technique  # noqa: E402
from farfield.core.techniques.octahedral.frames import pages_layout  # noqa: E402
from farfield.core.viewcells import ShaftCell, SphereOutsideCell  # noqa: E402

SCENES = Path(__file__).resolve().parents[2] / "shared" / "scenes"
SHARED = {
    "helmet": "damaged_helmet/DamagedHelmet.glb",
    "pine": "scrub_pine/scrubPine.obj",
    "duck": "duck/duck.obj",
}
# Fractions of the computed accuracy distance the distance section measures at (steps of sqrt 2).
LADDER = tuple(2.0 ** (k / 2.0) for k in range(-6, 2))
RANDOM_VIEWS = 2
SAMPLES = 2
TIMING_RESOLUTION = 512


def tree() -> Scene:
    """A small procedural tree: a trunk, a crown and a red branch to one side (2.2 units tall)."""
    return Scene.from_objects(
        [
            box_object("trunk", [-0.15, -0.15, 0.0], [0.15, 0.15, 1.0], (0.45, 0.3, 0.15, 1.0)),
            box_object("crown", [-0.7, -0.5, 1.0], [0.7, 0.5, 2.2], (0.1, 0.6, 0.2, 1.0)),
            box_object("branch", [0.3, -0.1, 0.2], [1.0, 0.1, 0.5], (0.8, 0.2, 0.2, 1.0)),
        ],
        "tree",
    )


def part(name: str) -> Scene:
    return tree() if name == "tree" else load_scene(SCENES / SHARED[name])


def centre_of(scene: Scene) -> np.ndarray:
    return 0.5 * (scene.bounds[0] + scene.bounds[1])


def bake_octahedral(scene: Scene, grid: int, frame_resolution: int, resolution: int, channels: str = "albedo"):
    """(impostor, seconds) of an octahedral bake for every viewpoint beyond the bounding box's corners."""
    technique = get_technique("octahedral")
    options = technique.options({"grid": grid, "frame_resolution": frame_resolution, "channels": channels}, resolution)
    centre = centre_of(scene)
    reach = float(np.linalg.norm(scene.bounds[1] - scene.bounds[0]))  # beyond the bounding sphere
    start = time.perf_counter()
    impostor = technique.bake(scene, SphereOutsideCell(centre, reach), options, None, None)
    return impostor, time.perf_counter() - start


def sphere_views(centre: np.ndarray, distance: float, seed: int) -> np.ndarray:
    """The outside-sphere cell's corners at ``distance`` and ``RANDOM_VIEWS`` random directions on it."""
    cell = SphereOutsideCell(centre, distance)
    return np.concatenate([cell.corners(), cell.sample_random(RANDOM_VIEWS, seed, depth=0.0)])


def errors(scene: Scene, impostor, points: np.ndarray) -> dict:
    return evaluate_at(scene, impostor, points, ["random"] * len(points), samples=SAMPLES, confirm_windows=16).totals


class Tables:
    """Prints each table as it comes; keeps the markdown for ``--markdown``."""

    def __init__(self):
        self.markdown: list[str] = []

    def table(self, title: str, header: list[str], rows: list[list[str]]) -> None:
        print(f"\n{title}")
        widths = [max(len(h), *(len(r[i]) for r in rows)) if rows else len(h) for i, h in enumerate(header)]
        print("  ".join(h.rjust(w) for h, w in zip(header, widths)))
        for row in rows:
            print("  ".join(c.rjust(w) for c, w in zip(row, widths)), flush=True)
        self.markdown += [f"\n{title}\n", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        self.markdown += ["| " + " | ".join(row) + " |" for row in rows]


def distance_section(args, tables: Tables) -> None:
    header = ["part", "N", "F", "D_acc", "D_acc/r", "D_meas", "D_meas/r", "meas/acc"]
    header += [f"x{f:.3g}" for f in LADDER] + ["colour x1", "bake s"]
    for name in args.parts:
        scene = part(name)
        centre = centre_of(scene)
        rows = []
        for frame_resolution in args.frames:
            for grid in args.grids:
                impostor, seconds = bake_octahedral(scene, grid, frame_resolution, args.resolution)
                d_acc, radius = impostor.stats["accuracy_distance"], impostor.payload.radius
                cells, clean, colour = ["-"] * len(LADDER), [False] * len(LADDER), math.nan
                start = time.perf_counter()
                for k in reversed(range(len(LADDER))):  # from far to near
                    factor = LADDER[k]
                    t = errors(scene, impostor, sphere_views(centre, factor * d_acc, 100 + k))
                    cells[k] = f"{t['hole_pixels']}/{t['bloat_beyond_1px']}"
                    clean[k] = t["hole_pixels"] == 0 and t["bloat_beyond_1px"] == 0
                    if factor == 1.0:
                        colour = t["colour_error_mean"]
                    if not args.full_ladder and not any(clean[k : k + 2]):
                        break  # two rungs in error: nearer ones only grow (and cost the most: the part fills the view)
                # The smallest rung from which every rung out is clean.
                first = next((k for k in range(len(LADDER)) if all(clean[k:])), None)
                measured = LADDER[first] * d_acc if first is not None else math.inf
                rows.append(
                    [name, str(grid), str(frame_resolution), f"{d_acc:.4g}", f"{d_acc / radius:.1f}",
                     f"{measured:.4g}", f"{measured / radius:.1f}", f"{measured / d_acc:.2f}", *cells,
                     f"{colour:.2f}", f"{seconds:.1f}"]
                )  # fmt: skip
                print(f"  {name} N={grid} F={frame_resolution}: bake {seconds:.1f} s, "
                      f"evaluation {time.perf_counter() - start:.1f} s", flush=True)  # fmt: skip
        tables.table(
            f"Error against distance, {name} (bounding radius r = {impostor.payload.radius:.4g} units), "
            f"{args.resolution} px at 45°, channels albedo; each rung: hole pixels / pixels bloated beyond one, "
            f"summed over {14 + RANDOM_VIEWS} views",
            header,
            rows,
        )


def shafts(centre: np.ndarray, near: float, far: float) -> list[ShaftCell]:
    """Six square shafts of 90° around +-x, +-y, +-z from ``near`` to ``far`` (the cube's faces)."""
    axes = np.concatenate([np.eye(3), -np.eye(3)])
    return [ShaftCell(centre, axis, math.pi / 2, near, far) for axis in axes]


def octahedral_bytes(grid: int, frame_resolution: int) -> int:
    """Texture bytes of an octahedral bake (its atlas pages), from the layout alone."""
    _, _, sides = pages_layout(grid, frame_resolution, 4, 4096)
    return int(sum(4 * s * s for s in sides))


def frame_ms(renderer, eye: np.ndarray, centre: np.ndarray, extent: np.ndarray, repeats: int = 15) -> float:
    """Median milliseconds to draw one frame at TIMING_RESOLUTION px from ``eye``."""
    forward = (centre - eye) / np.linalg.norm(centre - eye)
    near, far = depth_bounds(eye, forward, extent)
    camera = Camera.look_at(eye, centre, math.radians(45.0), TIMING_RESOLUTION, near, far)
    renderer.render(camera)  # warm: programs, targets
    return 1000.0 * statistics.median(renderer.frame_seconds(camera) for _ in range(repeats))


def layered_section(args, tables: Tables) -> None:
    layered = get_technique("layered")
    header = ["part", "distance (r)", "technique", "texture KiB", "holes", "bloat>1", "colour err",
              "bake s", f"frame ms ({TIMING_RESOLUTION} px)"]  # fmt: skip
    rows = []
    for name in args.parts:
        scene = part(name)
        centre = centre_of(scene)
        radius = 0.5 * float(np.linalg.norm(scene.bounds[1] - scene.bounds[0]))
        for k in args.distances:
            cells = shafts(centre, k * radius, 2 * k * radius)
            impostors, bake_s, total = [], 0.0, {"hole_pixels": 0, "bloat_beyond_1px": 0}
            colour = []
            views = []
            for index, cell in enumerate(cells):
                start = time.perf_counter()
                impostor = layered.bake(scene, cell, layered.options({}, args.resolution), None, None)
                bake_s += time.perf_counter() - start
                impostors.append(impostor)
                points = np.concatenate([cell.corners(), cell.sample_random(RANDOM_VIEWS, 200 + index)])
                views.append(points)
                t = errors(scene, impostor, points)
                total = {key: total[key] + t[key] for key in total}
                colour.append(t["colour_error_mean"])
            memory = sum(i.stats["texture_bytes"] for i in impostors)
            geometry = sum(i.stats.get("geometry_bytes", 0) for i in impostors)
            eye = centre + 1.5 * k * radius * np.array([1.0, 0.0, 0.0])
            extent = np.concatenate([impostors[0].payload.world_points(), scene.bounds])
            with impostors[0].payload.renderer(impostors[0]) as renderer:
                layered_ms = frame_ms(renderer, eye, centre, extent)
            rows.append([name, f"{k:g}-{2 * k:g}", f"layered x6 ({geometry / 1024:.0f} KiB quads)",
                         f"{memory / 1024:.0f}", str(total["hole_pixels"]), str(total["bloat_beyond_1px"]),
                         f"{np.mean(colour):.2f}", f"{bake_s:.1f}", f"{layered_ms:.2f}"])  # fmt: skip
            # The octahedral grid (frames of 32 texels) whose atlas is nearest that memory.
            grid = min(range(2, 65), key=lambda n: abs(octahedral_bytes(n, 32) - memory))
            impostor, seconds = bake_octahedral(scene, grid, 32, args.resolution)
            points = np.concatenate(views)
            t = errors(scene, impostor, points)
            extent = np.concatenate([impostor.payload.world_points(), scene.bounds])
            with impostor.payload.renderer(impostor) as renderer:
                octa_ms = frame_ms(renderer, eye, centre, extent)
            d_acc = impostor.stats["accuracy_distance"] / impostor.payload.radius
            rows.append([name, f"{k:g}-{2 * k:g}", f"octahedral {grid}x{grid}x32 (D_acc {d_acc:.0f} r)",
                         f"{impostor.stats['texture_bytes'] / 1024:.0f}", str(t["hole_pixels"]),
                         str(t["bloat_beyond_1px"]), f"{t['colour_error_mean']:.2f}", f"{seconds:.1f}",
                         f"{octa_ms:.2f}"])  # fmt: skip
            print(f"  {name} {k}: done", flush=True)
    tables.table(
        f"At equal memory: six layered shaft impostors against one octahedral impostor, {args.resolution} px at 45°, "
        f"albedo; errors summed over each shaft's corners and {RANDOM_VIEWS} random points (the octahedral from the "
        "same points)",
        header,
        rows,
    )


def lit_section(args, tables: Tables) -> None:
    from farfield.core.quality.lit import evaluate_lit_at, lit_figures

    scene = part("helmet")
    rows = []
    for channels in ("albedo+normal+depth", "albedo+normal+material+depth"):
        impostor, seconds = bake_octahedral(scene, 13, 64, 128, channels)
        cell = SphereOutsideCell(impostor.payload.centre, 4.0 * impostor.payload.radius)
        points = np.concatenate([cell.corners(), cell.sample_random(RANDOM_VIEWS, 7, depth=0.0)])
        f = lit_figures(evaluate_lit_at(scene, impostor, points, ["random"] * len(points), samples=SAMPLES))
        kib = sum(impostor.stats["channel_bytes"].values()) / 1024
        rows.append([channels, f"{kib:.0f}", f"{f['unlit_mean']:.1f}", f"{f['lit_mean_worst']:.1f}",
                     f"{f['flat_mean_worst']:.1f}", f"{f['lit_to_unlit_worst']:.2f}", f"{f['roughness_error_mean']:.3f}",
                     f"{f['metallic_error_mean']:.3f}", f"{f['occlusion_error_mean']:.3f}",
                     f"{f['emissive_error_mean']:.4f}", f"{seconds:.1f}"])  # fmt: skip
    tables.table(
        "Lit: the helmet, 13 x 13 frames of 64 texels, 128 px at 45°, 4 radii away, 16 views, five test lights "
        "(worst light's mean sRGB error)",
        [
            "channels",
            "texture KiB",
            "unlit",
            "lit",
            "flat cards",
            "lit/unlit",
            "roughness err",
            "metallic err",
            "occlusion err",
            "emissive err",
            "bake s",
        ],  # fmt: skip
        rows,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--section", choices=("distance", "layered", "lit", "all"), default="all")
    parser.add_argument("--parts", default="tree,helmet,pine,duck")
    parser.add_argument("--grids", default="8,12,16,24,32")
    parser.add_argument("--frames", default="32,64", help="frame resolutions, texels")
    parser.add_argument("--distances", default="4,8,16", help="layered section: near ends of the shafts, radii")
    parser.add_argument("--resolution", type=int, default=64, help="output pixels per side")
    parser.add_argument("--markdown", type=Path, help="append the tables, as markdown, to this file")
    parser.add_argument(
        "--full-ladder",
        action="store_true",
        help="distance section: every rung (else it stops inwards after two in error)",
    )
    args = parser.parse_args()
    args.parts = args.parts.split(",")
    args.grids = [int(g) for g in args.grids.split(",")]
    args.frames = [int(f) for f in args.frames.split(",")]
    args.distances = [float(d) for d in args.distances.split(",")]
    print(f"renderer: {renderer_info()}")
    tables = Tables()
    start = time.perf_counter()
    for section, run in (("distance", distance_section), ("layered", layered_section), ("lit", lit_section)):
        if args.section in (section, "all"):
            run(args, tables)
    print(f"\n{time.perf_counter() - start:.0f} s")
    if args.markdown:
        with args.markdown.open("a") as out:
            out.write("\n".join(tables.markdown) + "\n")


if __name__ == "__main__":
    main()
