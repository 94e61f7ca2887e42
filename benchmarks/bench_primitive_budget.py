"""Primitive-budget placement with LDIs (seed 004, issue 28): the shape of Table 1, LDI quality at the
star-shape's boundary, and a like-for-like comparison with the frame-time placement (seed 000).

Three tables, measured in one run on one scene and view space (a procedural city, the view space a
box at street level over its middle):

1. **Table 1's shape**: for budgets ``P`` as shares of the model, the grid (points per level),
   images, images per grid point (Fig. 15), preprocessing seconds, and the guarantee over
   ``--views`` random (eye, yaw) pairs (pitch 0): the share within ``P``, p99 / ``p_opt``, and how far
   the images' own views sit under ``p_opt`` (Fig. 16).
2. **LDIs**: ``--images`` images sampled from the middle budget, each built from one and from
   nine construction images.  Per image: build seconds, samples, the bytes the GPU drawer uploads
   (20 a sample) and the bytes the bundle stores (a colour and a depth PNG per layer; seed 004 §6
   stored its LDIs gzip'd).  Hole pixels of the hybrid frame (geometry + warped
   LDI, after the 3x3 pass) against the full scene are taken at ``--eyes`` eyes per image on its
   grid point's star sphere, the farthest eyes that may use it, each looking at the image.  Holes
   are reported as a share of the subset's footprint (pixel-weighted; per view mean and p99),
   and cracks as holes within 2 pixels of the quad's outline.
3. **Against the frame-time placement** at the middle budget, on the same ``--walk`` random views
   (uniform positions, uniform yaw, pitch 0; 60°): primitives drawn (share within P, p99, max),
   frame time (median of 3 draws; llvmpipe or the GPU the run has), hole pixels against the full
   scene, memory (baked), impostors or images, and preprocessing seconds.  The frame-time
   placement runs with the primitive cost model (t = triangles + quads, seed 000 §5.8.3); its
   impostors are baked and walked by the placement runtime.  The LDI side's memory is
   extrapolated from the images baked for the walk: their mean bytes times the images placed.
   That is also how seed 004 §6 estimated its Table 1.

    .venv/bin/python benchmarks/bench_primitive_budget.py            # about 20 minutes on 2 cores
    .venv/bin/python benchmarks/bench_primitive_budget.py --quick    # a few minutes
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from farfield.core import procedural  # noqa: E402
from farfield.core.impostor.database import ImpostorDatabase  # noqa: E402
from farfield.core.impostor.glb import page_png  # noqa: E402
from farfield.core.ldi.pages import ldi_payload_and_pages  # noqa: E402
from farfield.core.placement.cost_model import primitive_model  # noqa: E402
from farfield.core.placement.database import bake_placement, write_placement_database  # noqa: E402
from farfield.core.placement.image_frames import boundary_eyes, cell_objects, frame_holes, image_ldi, view_camera  # noqa: E402
from farfield.core.placement.planner import PlacementSettings, place  # noqa: E402
from farfield.core.placement.solution_grid import BudgetSettings, check_views, place_primitives  # noqa: E402
from farfield.core.placement.yaw_ranges import drawn_cells, forward  # noqa: E402
from farfield.core.quality.walkthrough import placement_walkthrough  # noqa: E402
from farfield.core.render.context import gl_context  # noqa: E402
from farfield.core.render.raster import MeshRenderer  # noqa: E402
from farfield.core.render.splats import SplatRenderer  # noqa: E402

FOV_DEG = 60.0


def scene_and_view_space(buildings: int, detail: int):
    scene = procedural.city(buildings, seed=0, detail=detail)
    lo, hi = scene.bounds
    a, b = 0.7 * lo + 0.3 * hi, 0.3 * lo + 0.7 * hi
    return scene, np.array([a[0], 2.0, a[2]]), np.array([b[0], 6.0, b[2]])


def ldi_bytes(ldi) -> tuple[int, int]:
    """(splat, stored) bytes of an LDI: what the GPU drawer uploads (20 bytes a sample) and its pages as
    the bundle stores them (a colour and a depth PNG per layer, farfield.core.ldi.pages)."""
    _, pages = ldi_payload_and_pages(ldi)
    return 20 * ldi.count, sum(len(page_png(p)) for p in pages)


def table1(scene, lo, hi, shares: list[float], views: int, max_level: int) -> list[dict]:
    rows = []
    print(f"{'P/model':>7} {'P':>8} {'p_opt':>8} {'points':>7} {'per level':>22} {'images':>7} {'per point':>28} {'s':>6} "
          f"{'<=P':>7} {'p99/p_opt':>9} {'max/P':>6} {'img/p_opt med':>13}", flush=True)  # fmt: skip
    for share in shares:
        p = share * scene.triangle_count
        started = time.perf_counter()
        placement = place_primitives(scene, lo, hi, BudgetSettings(primitives=p, fov_deg=FOV_DEG, max_level=max_level))
        seconds = time.perf_counter() - started
        check = check_views(placement, views, seed=1)
        s = placement.summary()
        ratio = s["image_drawn_over_p_opt"]
        row = {
            "share": share,
            "P": p,
            "p_opt": placement.p_opt,
            "summary": s,
            "seconds": seconds,
            "check": check,
            "placement": placement,
        }
        rows.append(row)
        per_point = ", ".join(f"{k}:{v}" for k, v in s["points_with_images"].items())
        print(f"{share:>7.2f} {p:>8.0f} {placement.p_opt:>8.0f} {s['grid_points']:>7} {str(s['points_per_level']):>22} {s['images']:>7} "
              f"{per_point:>28} {seconds:>6.1f} {100 * check['within_p']:>6.2f}% {check['p99_over_p_opt']:>9.3f} {check['max'] / p:>6.3f} "
              f"{(ratio or {}).get('median', math.nan):>13.4f}", flush=True)  # fmt: skip
    return rows


def ldi_quality(scene, placement, count: int, eyes: int, resolution: int, rng) -> dict:
    points = [i for i, p in enumerate(placement.points) if p.images]
    picks = [
        (int(i), int(rng.integers(len(placement.points[i].images))))
        for i in rng.choice(points, min(count, len(points)), replace=False)
    ]
    out = {}
    for n in (1, 9):
        holes = footprint = cracks = 0
        shares, build, raw, packed, samples = [], [], [], [], []  # raw: splat bytes; packed: stored PNG bytes
        for pi, ii in picks:
            point = placement.points[pi]
            image = point.images[ii]
            started = time.perf_counter()
            made = image_ldi(scene, placement, point, image, resolution, n)
            build.append(time.perf_counter() - started)
            r, g = ldi_bytes(made.ldi)
            raw.append(r), packed.append(g), samples.append(made.ldi.count)
            eye_rng = np.random.default_rng(1000 * pi + ii)  # the same eyes for 1 and 9 images
            for eye, yaw in boundary_eyes(point, image, placement.half, eyes, eye_rng):
                result, _ = frame_holes(scene, placement, eye, yaw, pi, ii, made.ldi, resolution, 0.05, 1e5)
                if result.footprint:
                    holes += result.holes
                    footprint += result.footprint
                    cracks += result.border_holes
                    shares.append(result.share)
        out[n] = {"images": len(picks), "views": len(shares), "holes": holes, "footprint": footprint, "cracks": cracks,
                  "hole_share": holes / max(footprint, 1), "view_share_mean": float(np.mean(shares)) if shares else math.nan,
                  "view_share_p99": float(np.percentile(shares, 99)) if shares else math.nan, "build_s_mean": float(np.mean(build)),
                  "splat_bytes_mean": float(np.mean(raw)), "stored_bytes_mean": float(np.mean(packed)), "samples_mean": float(np.mean(samples))}  # fmt: skip
    print(f"{'LDI from':>9} {'images':>6} {'views':>5} {'holes / footprint':>17} {'per view mean':>13} {'p99':>7} {'crack px':>8} "
          f"{'build s':>7} {'samples':>8} {'KiB splats':>10} {'KiB stored':>10}")  # fmt: skip
    for n, q in out.items():
        print(f"{n:>9} {q['images']:>6} {q['views']:>5} {100 * q['hole_share']:>16.2f}% {100 * q['view_share_mean']:>12.2f}% "
              f"{100 * q['view_share_p99']:>6.1f}% {q['cracks']:>8} {q['build_s_mean']:>7.2f} {q['samples_mean']:>8.0f} "
              f"{q['splat_bytes_mean'] / 1024:>10.1f} {q['stored_bytes_mean'] / 1024:>10.1f}", flush=True)  # fmt: skip
    return out


def _median_frame(renderer, camera, repeats: int = 3) -> float:
    renderer.render(camera)  # warm: the first draw of a renderer compiles and uploads
    return 1000.0 * float(np.median([renderer.frame_seconds(camera) for _ in range(repeats)]))


def ldi_walk(scene, placement, positions, yaws, resolution: int) -> dict:
    """The primitive-budget runtime on the walk: primitives, frame ms, holes; LDIs baked as views need them."""
    ldis, bytes_, frames, build = {}, [], [], []
    started = time.perf_counter()
    for eye, yaw in zip(positions, yaws):
        view = placement.view(eye, yaw)
        camera = view_camera(eye, yaw, 2 * placement.half, resolution, 0.05, 1e5)
        cells = view["cells"]
        seen = drawn_cells(placement.cells.lo, placement.cells.hi, eye, yaw, placement.half)
        frame = {
            "primitives": view["primitives"],
            "plain_primitives": int(placement.cells.triangles[seen].sum()),
            "image": view["image"] >= 0,
        }
        geometry = cell_objects(scene, placement.cells, cells) if cells.any() else []
        if view["image"] >= 0:
            key = (view["point"], view["image"])
            if key not in ldis:
                t0 = time.perf_counter()
                made = image_ldi(
                    scene, placement, placement.points[key[0]], placement.points[key[0]].images[key[1]], resolution, 9
                )
                build.append(time.perf_counter() - t0)
                ldis[key] = made.ldi
                bytes_.append(ldi_bytes(made.ldi))
            holes, _ = frame_holes(scene, placement, eye, yaw, key[0], key[1], ldis[key], resolution, 0.05, 1e5)
            frame["holes"] = holes.holes
            with SplatRenderer(geometry, [ldis[key]]) as r:
                frame["ms"] = _median_frame(r, camera)
        else:
            frame["holes"] = 0
            with MeshRenderer(geometry) as r:
                frame["ms"] = _median_frame(r, camera)
        frames.append(frame)
    raw = np.mean([b[0] for b in bytes_]) if bytes_ else 0.0
    packed = np.mean([b[1] for b in bytes_]) if bytes_ else 0.0
    return {"frames": frames, "seconds": time.perf_counter() - started, "ldis_baked": len(ldis),
            "memory_splat_bytes": raw * placement.images, "memory_stored_bytes": packed * placement.images,
            "build_s_mean": float(np.mean(build)) if build else 0.0}  # fmt: skip


def frametime_walk(scene, lo, hi, p: float, positions, yaws, resolution: int) -> dict:
    settings = PlacementSettings(t_max=p, model=primitive_model(), options={"resolution": resolution, "fov_deg": FOV_DEG},
                                 cpv_size=float(np.max(hi - lo)) / 4, cells="both", vdi_deg=45.0)  # fmt: skip
    started = time.perf_counter()
    placement = place(scene, lo, hi, settings)
    plan_s = time.perf_counter() - started
    started = time.perf_counter()
    impostors = bake_placement(scene, placement)
    bake_s = time.perf_counter() - started
    drawn = {imp["id"] for imp in placement.impostors if imp["cpvs"]}
    with tempfile.TemporaryDirectory(prefix="farfield-bench-") as tmp:
        write_placement_database(Path(tmp), placement, impostors)
        with ImpostorDatabase(Path(tmp)) as db:
            result = placement_walkthrough(scene, db, positions, forward(np.asarray(yaws)), repeats=3)
    return {"result": result, "plan_s": plan_s, "bake_s": bake_s, "impostors": len(drawn), "summary": placement.summary,
            "memory_bytes": sum(imp.texture_bytes for i, imp in impostors.items() if i in drawn),
            "stored_bytes": sum(len(page_png(pg)) for i, imp in impostors.items() if i in drawn for pg in imp.pages)}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a smaller city, fewer budgets, views and images")
    parser.add_argument("--buildings", type=int, default=None, help="city buildings (default 144; --quick 64)")
    parser.add_argument("--detail", type=int, default=8, help="the city's most quads per building face side")
    parser.add_argument(
        "--shares", default=None, help="budgets P as shares of the model, comma-separated (default 0.2,0.3,0.4,0.5)"
    )
    parser.add_argument("--views", type=int, default=10_000, help="random (eye, yaw) views of the guarantee's check")
    parser.add_argument("--max-level", type=int, default=4)
    parser.add_argument("--images", type=int, default=None, help="LDIs sampled for table 2 (default 24; --quick 8)")
    parser.add_argument("--eyes", type=int, default=6, help="boundary eyes per sampled LDI")
    parser.add_argument("--walk", type=int, default=None, help="random views of table 3 (default 100; --quick 30)")
    parser.add_argument("--resolution", type=int, default=256)
    parser.add_argument("--json", default=None, help="write the tables here")
    args = parser.parse_args()
    buildings = args.buildings or (64 if args.quick else 144)
    shares = [float(x) for x in (args.shares or ("0.3,0.5" if args.quick else "0.2,0.3,0.4,0.5")).split(",")]
    images = args.images or (8 if args.quick else 24)
    walk = args.walk or (30 if args.quick else 100)
    scene, lo, hi = scene_and_view_space(buildings, args.detail)
    print(f"city({buildings}, seed=0, detail={args.detail}): {scene.triangle_count} triangles, {scene.object_count} objects; view space "
          f"{lo.tolist()} .. {hi.tolist()}; fov {FOV_DEG:g}°; renderer {gl_context().info['GL_RENDERER']}", flush=True)  # fmt: skip
    print("\n1. Table 1's shape", flush=True)
    rows = table1(scene, lo, hi, shares, args.views, args.max_level)
    middle = rows[len(rows) // 2]
    placement = middle["placement"]
    rng = np.random.default_rng(0)
    print(f"\n2. LDIs at P = {middle['P']:.0f} ({middle['share']:g} of the model), {args.resolution} px", flush=True)
    quality = ldi_quality(scene, placement, images, args.eyes, args.resolution, rng)
    print(
        f"\n3. Against the frame-time placement at P = {middle['P']:.0f}, {walk} random views, {args.resolution} px",
        flush=True,
    )
    positions = lo + rng.random((walk, 3)) * (hi - lo)
    yaws = rng.random(walk) * 2 * math.pi
    ours = ldi_walk(scene, placement, positions, yaws, args.resolution)
    theirs = frametime_walk(scene, lo, hi, middle["P"], positions, yaws, args.resolution)
    p = middle["P"]
    prims = np.array([f["primitives"] for f in ours["frames"]])
    ms = np.array([f["ms"] for f in ours["frames"]])
    holes = np.array([f["holes"] for f in ours["frames"]])
    tf = theirs["result"]["frames"]
    t_prims = np.array([f["triangles"] + f["quads"] for f in tf])
    t_ms = np.array([f["runtime_ms"] for f in tf])
    plain_ms = np.array([f["plain_ms"] for f in tf])
    t_holes = np.array([f.get("hole_pixels", 0) for f in tf])
    prep = middle["seconds"] + ours["build_s_mean"] * placement.images
    print(
        f"{'placement':>22} {'<=P':>6} {'p99 prims':>9} {'max':>7} {'p50 ms':>6} {'p99 ms':>6} {'hole px (views)':>15} {'MiB (stored)':>16} {'# images':>8} {'prep s':>7}"
    )
    print(f"{'primitive-budget (LDI)':>22} {100 * np.mean(prims <= p):>5.1f}% {np.percentile(prims, 99):>9.0f} {prims.max():>7.0f} {np.median(ms):>6.2f} "
          f"{np.percentile(ms, 99):>6.2f} {holes.sum():>8} ({np.count_nonzero(holes)}) {ours['memory_splat_bytes'] / 2**20:>7.1f} ({ours['memory_stored_bytes'] / 2**20:.1f}) "
          f"{placement.images:>8} {prep:>7.1f}")  # fmt: skip
    print(f"{'frame-time (layered)':>22} {100 * np.mean(t_prims <= p):>5.1f}% {np.percentile(t_prims, 99):>9.0f} {t_prims.max():>7.0f} {np.median(t_ms):>6.2f} "
          f"{np.percentile(t_ms, 99):>6.2f} {t_holes.sum():>8} ({np.count_nonzero(t_holes)}) {theirs['memory_bytes'] / 2**20:>7.1f} ({theirs['stored_bytes'] / 2**20:.2f}) {theirs['impostors']:>8} "
          f"{theirs['plan_s'] + theirs['bake_s']:>7.1f}")  # fmt: skip
    plain_prims = np.array([f["plain_primitives"] for f in ours["frames"]])
    print(f"{'plain geometry':>22} {100 * np.mean(plain_prims <= p):>5.1f}% {np.percentile(plain_prims, 99):>9.0f} {plain_prims.max():>7.0f} "
          f"{np.median(plain_ms):>6.2f} {np.percentile(plain_ms, 99):>6.2f}")  # fmt: skip
    ts = theirs["summary"]
    print(f"(frame-time: planned in {theirs['plan_s']:.1f} s, baked in {theirs['bake_s']:.1f} s, {ts['cpvs']} CPVs of which {ts['cpvs_unsolved']} unsolved and "
          f"{ts['cpvs_unsolvable']} unsolvable by the model; memory: atlas pages raw (as PNG). primitive-budget: grid {middle['seconds']:.1f} s, "
          f"{ours['ldis_baked']} LDIs baked for the walk, {ours['build_s_mean']:.2f} s each; memory: splats uploaded (LDI pages as PNG), and prep s, "
          f"extrapolated from those LDIs to all {placement.images} images, as seed 004 §6 did)")  # fmt: skip
    if args.json:
        for r in rows:
            r.pop("placement")
        Path(args.json).write_text(json.dumps({"table1": rows, "ldi": quality, "walk": {"ldi": ours, "frame_time": {k: v for k, v in theirs.items() if k != "result"}}},
                                              default=float, indent=1))  # fmt: skip


if __name__ == "__main__":
    main()
