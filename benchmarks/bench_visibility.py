"""From-region visibility (issue 57 item 1): sampled potentially visible sets on the benchmark cities, and what they do to a placement.

Usage: ``.venv/bin/python benchmarks/bench_visibility.py [--scene city,dense,downtown,street] [--parts pvs,estimates,runtime,walk,memory] [--views 100] [--json OUT]``

Per scene (the scenes and view spaces of ``bench_placement.py``; ``street`` is the 400-building city
with the view space at street level, 1.5..2.5 m, over the same square), with the CPV size the view
space's longest side / ``--cpv-divisions`` and ``--vdi-deg`` view-direction intervals (45° unless given), at ``--resolution``:

1. **The PVS** (:class:`farfield.core.visibility.pvs.RegionVisibility`, defaults: 2 samples per
   region side, no adaptive level, occluder erosion of half a lattice cell's diagonal with 2 peels
   (``--erosion``, ``--peels``; ``--erosion 0 --levels 1`` is the earlier default), cube faces of one
   texel per 2 output pixels, margin one lattice step): points
   rendered and seconds; the mean PVS of a smallest region as a share of the elements and of the
   triangles; and the **false-invisible rate** against a uniform lattice of plain points (no
   erosion; ``--dense-samples``, default 8 per side): elements the dense sampling sees and
   the PVS lacks, and the most cube-map texels (and nominal output pixels) they cover from one
   dense point (:func:`farfield.core.visibility.pvs.false_invisible`).
2. **Estimate ÷ measured** on ``--views`` random views (``bench_placement.estimate_rows``'s): the
   time of each view's problem view with no impostor (what the planner budgets), without and with
   visibility, over the measured plain frame (the runtime draws every element in its frustum).
3. **The runtime culling to the PVS** (``--parts runtime``, issue 57 item 2): the PVS of every
   smallest region stored in a placement database (:mod:`farfield.core.visibility.region_sets`; the
   placement at an unreachable t_max, so no impostor: every frame is geometry), then a walkthrough
   of ``--views`` random views: per frame the runtime drawing only the PVS of the eye's region and
   the plain geometry (every element in the frustum), timed from the same camera one after the
   other (medians of 3 draws); triangles drawn; hole pixels and PVS-dropped pixels against the
   full scene; and estimate ÷ measured: the problem view's time with visibility over the
   PVS-culled frame, beside the time without visibility over the plain frame.
4. **A placement walked** (``--parts walk``): the placement with visibility at t_max = half the
   worst view's estimate (as part 5), its impostors baked here, walked along ``--views`` random
   views with the runtime drawing the PVS: the share of views within t_max (measured, and by the
   estimate), hole pixels and PVS-dropped pixels against the full scene, and estimate ÷ measured
   of the frames (the CPV's time after placement, or the model over the PVS in the frustum, over
   the runtime's frame).
5. **Memory**: the placement at t_max = half the worst view's estimate (the walkthrough's reference
   budget), without and with visibility (the cost model's memory estimate; nothing baked), beside
   the coarsest envmap grid meeting the same t_max by the model (``bench_placement``'s estimate),
   without and with visibility (each cell's near field counts only the PVS of the smallest regions
   it meets, ``bench_placement.cell_pvs``); one PVS serves both.

Everything on one process; GL through EGL (llvmpipe on the CPU machine).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_placement import (  # noqa: E402
    _worst_view,
    cell_pvs,
    city_scene,
    coarsest_envmap_cell,
    downtown_scene,
    envmap_grid_memory,
    leaf_regions,
    mib,
    problem_view_times,
)

from farfield.core.placement.cost_model import LLVMPIPE_MODEL  # noqa: E402
from farfield.core.placement.hierarchy import Elements, Hierarchy  # noqa: E402
from farfield.core.placement.planner import PlacementSettings, place  # noqa: E402
from farfield.core.placement.view_space import DEFAULT_DEPTH_COMPLEXITY, problem_view_space  # noqa: E402
from farfield.core.render.context import renderer_info  # noqa: E402
from farfield.core.visibility.pvs import RegionVisibility, false_invisible  # noqa: E402

FOV = math.radians(45.0)
VDI_DEG = 45.0  # the view-direction intervals' angle (--vdi-deg; the planner's default is 11.25)


def scene_of(name: str):
    if name == "city":
        return city_scene(True, 400, 16)
    if name == "dense":
        return city_scene(True, 49, 64)
    if name == "downtown":
        return downtown_scene(False)
    if name == "street":
        scene, lo, hi = city_scene(True, 400, 16)
        ground = float(scene.bounds[0][1])
        lo, hi = lo.copy(), hi.copy()
        lo[1], hi[1] = ground + 1.5, ground + 2.5
        return scene, lo, hi
    raise SystemExit(f"unknown scene {name!r}")


def pvs_rows(
    scene, lo, hi, cpv: float, resolution: int, samples: int, levels: int, dense_samples: int, erosion, peels: int
) -> dict:
    elements = Elements.of(scene)
    sparse = RegionVisibility(scene, elements, lo, hi, cpv, resolution, FOV, samples_per_side=samples, levels=levels,
                              erosion=erosion, peels=peels)  # fmt: skip
    plain = RegionVisibility(scene, elements, lo, hi, cpv, resolution, FOV, samples_per_side=dense_samples, erosion=0.0)
    dense = RegionVisibility(
        scene,
        elements,
        lo,
        hi,
        cpv,
        resolution,
        FOV,
        samples_per_side=dense_samples,
        levels=0,
        renderer=plain.renderer,  # the reference: points without erosion
    )
    regions = leaf_regions(lo, hi, cpv)
    started = time.perf_counter()
    sizes = [sparse.pvs(a, b) for a, b in regions]
    sparse_s = time.perf_counter() - started
    share = float(np.mean([s.size for s in sizes])) / elements.count
    tri_share = float(np.mean([elements.triangles[s].sum() for s in sizes])) / float(elements.triangles.sum())
    fi = false_invisible(sparse, dense, regions)
    row = {
        "elements": elements.count, "triangles": int(elements.triangles.sum()), "regions": len(regions),
        "samples_per_side": samples, "levels": levels, "dense_samples_per_side": dense_samples,
        "lattice": sparse.lattice.counts.tolist(), "points": sparse.points_rendered, "face": sparse.renderer.face,
        "margin": sparse.margin, "pvs_s": sparse_s, "pvs_element_share": share, "pvs_triangle_share": tri_share,
        "dense_points": dense.points_rendered, "false_invisible": fi,
        "erosion": sparse.renderer.erosion, "peels": sparse.renderer.peels,
    }  # fmt: skip
    sparse.release()
    plain.release()
    return row


def estimate_ratios(scene, lo, hi, cpv: float, resolution: int, views: int, seed: int) -> dict:
    """Per random view: its problem view's time (no impostor) without / with visibility, over the
    measured plain frame; as ``bench_placement.estimate_rows`` measures it."""
    import tempfile

    from farfield.core.impostor.database import ImpostorDatabase
    from farfield.core.placement.database import write_placement_database
    from farfield.core.quality.walkthrough import placement_walkthrough, random_views

    positions, forwards = random_views(lo, hi, views, seed)
    empty = place(
        scene,
        lo,
        hi,
        PlacementSettings(
            t_max=1e12, model=LLVMPIPE_MODEL, options={"resolution": resolution}, cpv_size=cpv, vdi_deg=VDI_DEG
        ),
    )
    with tempfile.TemporaryDirectory(prefix="farfield-bench-") as tmp:
        write_placement_database(Path(tmp) / "db", empty, {})
        with ImpostorDatabase(Path(tmp) / "db") as db:
            frames = placement_walkthrough(scene, db, positions, forwards, repeats=3, compare=False)["frames"]
    measured = np.array([f["plain_ms"] for f in frames])
    slow = measured >= np.percentile(measured, 75)
    elements = Elements.of(scene)
    hierarchy = Hierarchy.build(elements)
    out = {"plain_ms_p50": float(np.median(measured)), "plain_ms_p99": float(np.percentile(measured, 99))}
    for vis in (False, True):
        visible = RegionVisibility(scene, elements, lo, hi, cpv, resolution, FOV) if vis else None
        pv = problem_view_space(
            elements,
            hierarchy,
            lo,
            hi,
            LLVMPIPE_MODEL,
            1e-12,
            FOV,
            resolution,
            cpv,
            VDI_DEG,
            DEFAULT_DEPTH_COMPLEXITY,
            visible,
        )
        if visible is not None:
            visible.release()
        est = problem_view_times(pv, positions, forwards)
        ratio = est / measured
        key = "visibility" if vis else "none"
        out[key] = {
            "ratio_p50": float(np.median(ratio)), "ratio_p95": float(np.percentile(ratio, 95)),
            "ratio_p50_slowest_quarter": float(np.median(ratio[slow])), "under_30pct": float(np.mean(ratio < 0.7)),
            "estimate_p99_ms": float(np.percentile(est, 99)),
        }  # fmt: skip
    return out


def runtime_rows(scene, lo, hi, cpv: float, resolution: int, views: int, seed: int, **pvs_options) -> dict:
    """The runtime culling to the stored PVS against drawing the frustum (module docstring, part 3)."""
    import tempfile
    from dataclasses import replace

    from farfield.core.impostor.database import ImpostorDatabase
    from farfield.core.placement.database import write_placement_database
    from farfield.core.quality.walkthrough import placement_walkthrough, random_views
    from farfield.core.visibility.region_sets import raw_size, region_sets, stored_size

    positions, forwards = random_views(lo, hi, views, seed)
    elements = Elements.of(scene)
    hierarchy = Hierarchy.build(elements)
    args = (elements, hierarchy, lo, hi, LLVMPIPE_MODEL, 1e-12, FOV, resolution, cpv, VDI_DEG, DEFAULT_DEPTH_COMPLEXITY)
    visible = RegionVisibility(scene, elements, lo, hi, cpv, resolution, FOV, **pvs_options)
    started = time.perf_counter()
    try:
        with_vis = problem_view_space(*args, visible)
        sets = region_sets(visible, elements.names, lo, hi, cpv)
    finally:
        visible.release()
    pvs_s = time.perf_counter() - started
    without = problem_view_space(*args)
    empty = place(scene, lo, hi, PlacementSettings(t_max=1e12, model=LLVMPIPE_MODEL, options={"resolution": resolution},
                                                   cpv_size=cpv, vdi_deg=VDI_DEG))  # fmt: skip
    with tempfile.TemporaryDirectory(prefix="farfield-bench-") as tmp:
        write_placement_database(Path(tmp) / "db", replace(empty, visibility=sets), {})
        with ImpostorDatabase(Path(tmp) / "db") as db:
            result = placement_walkthrough(scene, db, positions, forwards, repeats=3, compare=True)
    frames, summary = result["frames"], result["summary"]
    run = np.array([f["runtime_ms"] for f in frames])
    plain = np.array([f["plain_ms"] for f in frames])
    out = {
        "pvs_s": pvs_s, "regions": len(sets["sets"]), "stored_bytes": stored_size(sets), "raw_bytes": raw_size(sets),
        "frames": len(frames), "frames_with_pvs": summary.get("frames_with_pvs", 0),
        "culled_ms_p50": float(np.median(run)), "culled_ms_p95": float(np.percentile(run, 95)),
        "plain_ms_p50": float(np.median(plain)), "plain_ms_p95": float(np.percentile(plain, 95)),
        "speedup_median": float(np.median(plain / run)),
        "culled_triangles_mean": float(np.mean([f["triangles"] for f in frames])),
        "plain_triangles_mean": float(np.mean([f["plain_triangles"] for f in frames])),
        "culled_elements_mean": float(np.mean([f["elements"] for f in frames])),
        "plain_elements_mean": float(np.mean([f["plain_draw_calls"] for f in frames])),
        "hole_pixels": summary.get("hole_pixels"), "max_hole_pixels": summary.get("max_hole_pixels"),
        "pvs_dropped_pixels": summary.get("pvs_dropped_pixels"), "max_pvs_dropped_pixels": summary.get("max_pvs_dropped_pixels"),
        "frames_with_holes": int(sum(f["hole_pixels"] > 0 for f in frames)),
        "pixels": int(resolution) ** 2,
    }  # fmt: skip
    for key, pv, measured in (("none", without, plain), ("visibility", with_vis, run)):
        ratio = problem_view_times(pv, positions, forwards) / measured
        slow = measured >= np.percentile(measured, 75)
        out[key] = {
            "ratio_p50": float(np.median(ratio)), "ratio_p95": float(np.percentile(ratio, 95)),
            "ratio_p50_slowest_quarter": float(np.median(ratio[slow])), "under_30pct": float(np.mean(ratio < 0.7)),
        }  # fmt: skip
    return out


def walk_rows(scene, lo, hi, cpv: float, resolution: int, views: int, seed: int) -> dict:
    """A placement with visibility, baked and walked (module docstring, part 4)."""
    import tempfile

    from farfield.core.impostor.database import ImpostorDatabase
    from farfield.core.placement.database import bake_placement, write_placement_database
    from farfield.core.quality.walkthrough import placement_walkthrough, random_views

    t_max = 0.5 * _worst_view(scene, lo, hi, LLVMPIPE_MODEL, resolution)
    settings = PlacementSettings(t_max=t_max, model=LLVMPIPE_MODEL, options={"resolution": resolution}, cpv_size=cpv,
                                 vdi_deg=VDI_DEG, visibility=True)  # fmt: skip
    started = time.perf_counter()
    placement = place(scene, lo, hi, settings)
    plan_s = time.perf_counter() - started
    started = time.perf_counter()
    impostors = bake_placement(scene, placement)
    bake_s = time.perf_counter() - started
    positions, forwards = random_views(lo, hi, views, seed)
    with tempfile.TemporaryDirectory(prefix="farfield-bench-") as tmp:
        write_placement_database(Path(tmp) / "db", placement, impostors)
        with ImpostorDatabase(Path(tmp) / "db") as db:
            result = placement_walkthrough(scene, db, positions, forwards, repeats=3, compare=True)
    frames, s = result["frames"], result["summary"]
    ratio = np.array([f["estimate"] / f["runtime_ms"] for f in frames])
    return {
        "t_max": t_max, "plan_s": plan_s, "bake_s": bake_s, "impostors": placement.summary["impostors"],
        "memory_bytes": placement.summary["memory_bytes"], "cpvs": placement.summary["cpvs"],
        "share_within_t_max": s["share_within_t_max"], "share_estimate_within_t_max": s["share_estimate_within_t_max"],
        "runtime_ms_p50": s["runtime_ms_p50"], "runtime_ms_p99": s["runtime_ms_p99"], "plain_ms_p99": s["plain_ms_p99"],
        "hole_pixels": s.get("hole_pixels"), "max_hole_pixels": s.get("max_hole_pixels"),
        "pvs_dropped_pixels": s.get("pvs_dropped_pixels"), "frames_with_pvs": s.get("frames_with_pvs"),
        "ratio_p50": float(np.median(ratio)), "ratio_p95": float(np.percentile(ratio, 95)),
        "under_30pct": float(np.mean(ratio < 0.7)), "frames": len(frames),
    }  # fmt: skip


def memory_rows(scene, lo, hi, cpv: float, resolution: int) -> dict:
    """Part 5: the placement and the coarsest envmap grid at the same t_max, each without and with
    visibility (one PVS, the planner's defaults, shared by both; the grid's cells count the PVS of
    the smallest regions they meet, ``bench_placement.cell_pvs``)."""
    worst = _worst_view(scene, lo, hi, LLVMPIPE_MODEL, resolution)
    t_max = 0.5 * worst
    out = {"t_max": t_max}
    elements = Elements.of(scene)
    visible = RegionVisibility(scene, elements, lo, hi, cpv, resolution, FOV)
    try:
        for vis in (False, True):
            settings = PlacementSettings(
                t_max=t_max, model=LLVMPIPE_MODEL, options={"resolution": resolution}, cpv_size=cpv, vdi_deg=VDI_DEG
            )
            started = time.perf_counter()
            p = place(scene, lo, hi, settings, visible=visible if vis else None)
            out["visibility" if vis else "none"] = {
                "memory_bytes": p.summary["memory_bytes"], "impostors": p.summary["impostors"], "cpvs": p.summary["cpvs"],
                "cpvs_unsolved": p.summary["cpvs_unsolved"], "cpvs_unsolvable": p.summary["cpvs_unsolvable"],
                "seconds": time.perf_counter() - started, "steps": p.seconds,
            }  # fmt: skip
        pvs = cell_pvs(visible, elements.count, lo, hi, cpv)
        for key, grid_pvs in (("envmap_grid", None), ("envmap_grid_visibility", pvs)):
            cell, over = coarsest_envmap_cell(elements, lo, hi, t_max, LLVMPIPE_MODEL, resolution, 1024, grid_pvs)
            grid = envmap_grid_memory(scene, lo, hi, cell, t_max, LLVMPIPE_MODEL, resolution, pvs=grid_pvs)
            out[key] = {"cell": cell, "over": over, **grid}
        out["pvs"] = visible.stats()
    finally:
        visible.release()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="city,dense,downtown,street")
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--cpv-divisions", type=int, default=4)
    parser.add_argument("--views", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--parts", default="pvs,estimates,memory")
    parser.add_argument("--samples", type=int, default=2, help="PVS: samples per smallest region side")
    parser.add_argument("--levels", type=int, default=0, help="PVS: adaptive refinement levels")
    parser.add_argument(
        "--erosion",
        default="auto",
        help="PVS: occluder erosion in scene units (auto: half a lattice cell's diagonal; 0: none)",
    )
    parser.add_argument(
        "--peels", type=int, default=4, help="PVS: layers peeled behind an eroded point's first surfaces"
    )
    parser.add_argument(
        "--dense-samples", type=int, default=8, help="the denser uniform sampling the PVS is compared with"
    )
    parser.add_argument(
        "--vdi-deg", type=float, default=45.0, help="view-direction intervals' angle (the planner's default: 11.25)"
    )
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    global VDI_DEG
    VDI_DEG = args.vdi_deg
    parts = args.parts.split(",")
    print(
        f"# {renderer_info().renderer}; {args.resolution} px, 45°, CPV = side / {args.cpv_divisions}, {args.vdi_deg:g}° intervals",
        flush=True,
    )
    rows = []
    for name in args.scene.split(","):
        scene, lo, hi = scene_of(name)
        cpv = float(np.max(hi - lo)) / args.cpv_divisions
        row = {
            "scene": name,
            "triangles": scene.triangle_count,
            "objects": scene.object_count,
            "view_space": [lo.tolist(), hi.tolist()],
            "cpv": cpv,
        }
        print(
            f"## {name}: {scene.triangle_count:,} triangles, {scene.object_count} objects; view space {lo.round(1).tolist()} .. {hi.round(1).tolist()}, CPV {cpv:.4g}",
            flush=True,
        )
        if "pvs" in parts:
            r = row["pvs"] = pvs_rows(
                scene, lo, hi, cpv, args.resolution, args.samples, args.levels, args.dense_samples,
                None if args.erosion == "auto" else float(args.erosion), args.peels,
            )  # fmt: skip
            fi = r["false_invisible"]
            print(f"   PVS ({args.samples} per side, {args.levels} levels, erosion {r['erosion']:.3g}, {r['peels']} peels): lattice {r['lattice']} ({r['points']} points, faces {r['face']} px, margin {r['margin']:.3g}) in {r['pvs_s']:.1f} s; "
                  f"mean PVS {100 * r['pvs_element_share']:.1f} % of {r['elements']} elements, {100 * r['pvs_triangle_share']:.1f} % of triangles; "
                  f"against {r['dense_points']} points: {fi['missing']} missing in {fi['regions_missing']}/{fi['regions']} regions "
                  f"({100 * fi['missing_share']:.2f} % of dense PVS entries), at most {fi['max_missing_texels']} texels "
                  f"(~{fi['max_missing_pixels']:.0f} output px) from one point", flush=True)  # fmt: skip
        if "estimates" in parts:
            r = row["estimates"] = estimate_ratios(scene, lo, hi, cpv, args.resolution, args.views, args.seed)
            for key in ("none", "visibility"):
                e = r[key]
                print(f"   estimate ÷ measured ({key}): p50 {e['ratio_p50']:.2f}, p95 {e['ratio_p95']:.2f}, slowest quarter p50 {e['ratio_p50_slowest_quarter']:.2f}, "
                      f"under by > 30 %: {100 * e['under_30pct']:.1f} %; plain p50 {r['plain_ms_p50']:.2f} ms, p99 {r['plain_ms_p99']:.2f} ms", flush=True)  # fmt: skip
        if "runtime" in parts:
            r = row["runtime"] = runtime_rows(
                scene, lo, hi, cpv, args.resolution, args.views, args.seed, samples_per_side=args.samples,
                levels=args.levels, erosion=None if args.erosion == "auto" else float(args.erosion), peels=args.peels,
            )  # fmt: skip
            print(f"   runtime with the stored PVS ({r['regions']} regions, {r['stored_bytes']:,} B stored vs {r['raw_bytes']:,} B raw bits; PVS {r['pvs_s']:.1f} s): "
                  f"{r['frames_with_pvs']}/{r['frames']} frames culled; frame ms p50 {r['culled_ms_p50']:.2f} / p95 {r['culled_ms_p95']:.2f} "
                  f"vs frustum only {r['plain_ms_p50']:.2f} / {r['plain_ms_p95']:.2f} (speed-up median {r['speedup_median']:.2f}x); "
                  f"triangles mean {r['culled_triangles_mean']:,.0f} vs {r['plain_triangles_mean']:,.0f}, elements {r['culled_elements_mean']:.1f} vs {r['plain_elements_mean']:.1f}; "
                  f"hole pixels {r['hole_pixels']} (max {r['max_hole_pixels']} of {r['pixels']} in a frame, {r['frames_with_holes']} frames), "
                  f"PVS-dropped pixels {r['pvs_dropped_pixels']} (max {r['max_pvs_dropped_pixels']})", flush=True)  # fmt: skip
            for key in ("none", "visibility"):
                e = r[key]
                print(f"   estimate ÷ measured ({key}; measured: {'PVS-culled' if key == 'visibility' else 'frustum-only'} frame): p50 {e['ratio_p50']:.2f}, "
                      f"p95 {e['ratio_p95']:.2f}, slowest quarter p50 {e['ratio_p50_slowest_quarter']:.2f}, under by > 30 %: {100 * e['under_30pct']:.1f} %", flush=True)  # fmt: skip
        if "walk" in parts:
            r = row["walk"] = walk_rows(scene, lo, hi, cpv, args.resolution, args.views, args.seed)
            print(f"   placement with visibility at t_max {r['t_max']:.3g} ms: {r['impostors']} impostors, {mib(r['memory_bytes']):.1f} MiB, {r['cpvs']} CPVs; "
                  f"planned in {r['plan_s']:.0f} s, baked in {r['bake_s']:.0f} s; walked {r['frames']} views ({r['frames_with_pvs']} PVS-culled): "
                  f"{100 * r['share_within_t_max']:.0f} % within t_max measured, {100 * r['share_estimate_within_t_max']:.0f} % by the estimate; "
                  f"runtime ms p50 {r['runtime_ms_p50']:.2f}, p99 {r['runtime_ms_p99']:.2f} (plain p99 {r['plain_ms_p99']:.2f}); "
                  f"hole pixels {r['hole_pixels']} (max {r['max_hole_pixels']}), PVS-dropped {r['pvs_dropped_pixels']}; "
                  f"estimate ÷ measured p50 {r['ratio_p50']:.2f}, p95 {r['ratio_p95']:.2f}, under by > 30 %: {100 * r['under_30pct']:.0f} %", flush=True)  # fmt: skip
        if "memory" in parts:
            r = row["memory"] = memory_rows(scene, lo, hi, cpv, args.resolution)
            for key in ("none", "visibility"):
                m, g = r[key], r["envmap_grid" if key == "none" else "envmap_grid_visibility"]
                print(f"   placement ({key}) at t_max {r['t_max']:.3g} ms: {mib(m['memory_bytes']):.1f} MiB, {m['impostors']} impostors, {m['cpvs']} CPVs "
                      f"({m['cpvs_unsolved']} unsolved, {m['cpvs_unsolvable']} unsolvable), {m['seconds']:.0f} s; grid ÷ placement "
                      + (f"{g['memory_bytes'] / m['memory_bytes']:.2f}" if m["memory_bytes"] > 0 else "inf (no impostor needed)"), flush=True)  # fmt: skip
            for key in ("envmap_grid", "envmap_grid_visibility"):
                g = r[key]
                print(f"   {key.replace('_', ' ')}: {g['cells']} cells of {g['cell']:.3g} ({g['over']} over), {mib(g['memory_bytes']):.1f} MiB (estimated)",
                      flush=True)  # fmt: skip
        rows.append(row)
        if args.json:
            Path(args.json).write_text(json.dumps(rows, indent=1, default=float))


if __name__ == "__main__":
    main()
