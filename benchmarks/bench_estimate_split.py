"""Issue 57 item 4: where the walkthrough's estimate ÷ measured comes from, view by view.

Usage: ``.venv/bin/python benchmarks/bench_estimate_split.py [--scene street,downtown,city] [--views 100]
[--model MODEL.json] [--depth-complexity 4] [--json OUT]``

Per scene (``bench_visibility.py``'s scenes, CPV size, 45° intervals and walk: the placement with
visibility at t_max = half the worst view's estimate, baked, walked along ``--views`` random views
with the runtime drawing the PVS), for every frame:

* ``measured``: the runtime's frame (median of 3 draws interleaved with the plain geometry's, after
  untimed rounds of both, ``frames_ms``);
* ``estimate``: what the walkthrough compares it with (the CPV's time after placement, or for a view
  in no CPV the model over the PVS's elements in the frustum);
* (a) ``drawn_covered``: the model over exactly what the frame draws (frustum ∩ PVS, the impostors
  as drawn): ``d + sum(a calls + b triangles) + c * covered geometry pixels + e * covered impostor
  pixels + f * quads + g * impostors``, covered pixels counted on the frame's own images (what
  calibration's ``pixels`` are);
* (a') ``drawn_discs``: the same with the planner's pixel estimate (``element_pixels`` from the
  eye: bounding-sphere discs, or box faces where smaller, capped at ``--depth-complexity`` frames) in place of the covered geometry pixels;
* (b) the CPV aggregation: ``estimate ÷ drawn_discs`` on the frames in a CPV.

Each ratio's p50, p95 and share of frames under by more than 30 % (ratio < 0.7) is printed; the
per-frame rows go to ``--json``.  ``--model`` plans and estimates with another cost model (a file
of ``farfield calibrate --out``), ``--depth-complexity`` with another pixel cap, ``--vdi-deg`` and
``--cpv-divisions`` with other CPVs, ``--t-max`` at fixed budgets (per scene, ms) instead of half
the worst view's estimate by the model.

``--parts cpv`` (no GL timing): every (smallest region, interval) as a CPV, and per CPV
``--cpv-samples`` views sampled in it; how far the CPV's estimate lies over its worst sampled
view, and that over its median one (:func:`cpv_spread`).

Usage: ``.venv/bin/python benchmarks/bench_estimate_split.py --t-max 3.27,5.51,3.4 --depth-complexity 4``
(before 2026-12-07's default), ``... --depth-complexity 1`` (after), ``--parts cpv --cpv-samples 32``.
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
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_visibility import scene_of  # noqa: E402

from farfield.core.impostor.database import ImpostorDatabase  # noqa: E402
from farfield.core.placement.cost_model import LLVMPIPE_MODEL, CostModel  # noqa: E402
from farfield.core.placement.database import bake_placement, write_placement_database  # noqa: E402
from farfield.core.placement.frame_pixels import box_frame_pixels  # noqa: E402
from farfield.core.placement.hierarchy import Elements, Hierarchy  # noqa: E402
from farfield.core.placement.planner import PlacementSettings, place  # noqa: E402
from farfield.core.placement.runtime import PlacementRenderer, plain_estimate  # noqa: E402
from farfield.core.placement.view_space import DEFAULT_DEPTH_COMPLEXITY, element_pixels, problem_view_space  # noqa: E402
from farfield.core.quality.walkthrough import frame_ms, frames_ms, random_views  # noqa: E402
from farfield.core.render.context import renderer_info  # noqa: E402


def ratios(r: np.ndarray) -> dict:
    r = np.asarray(r, dtype=float)
    if r.size == 0:
        return {"n": 0, "p50": math.nan, "p95": math.nan, "under_30pct": math.nan}
    return {
        "n": int(r.size),
        "p50": float(np.median(r)),
        "p95": float(np.percentile(r, 95)),
        "under_30pct": float(np.mean(r < 0.7)),
    }


def worst_view(scene, lo, hi, model: CostModel, resolution: int, depth: float) -> float:
    """``bench_placement._worst_view`` (the worst CPV of side / 8 and 11.25° with no impostor) at
    ``depth`` frames of pixels at most, so that t_max is half the worst view's estimate by the
    model the placement uses."""
    elements = Elements.of(scene)
    pv = problem_view_space(elements, Hierarchy.build(elements), lo, hi, model, 1e-9, math.radians(45.0), resolution,
                            float(np.max(hi - lo)) / 8.0, 11.25, depth)  # fmt: skip
    return float(pv.time.max())


def walk_split(
    scene,
    lo,
    hi,
    cpv: float,
    resolution: int,
    views: int,
    seed: int,
    model: CostModel,
    depth: float,
    vdi_deg: float = 45.0,
    t_max: float | None = None,
):
    if t_max is None:
        t_max = 0.5 * worst_view(scene, lo, hi, model, resolution, depth)
    settings = PlacementSettings(t_max=t_max, model=model, options={"resolution": resolution}, cpv_size=cpv,
                                 vdi_deg=vdi_deg, visibility=True, depth_complexity=depth)  # fmt: skip
    started = time.perf_counter()
    placement = place(scene, lo, hi, settings)
    plan_s = time.perf_counter() - started
    impostors = bake_placement(scene, placement)
    positions, forwards = random_views(lo, hi, views, seed)
    a, b, c, d = model.geometry
    e, f, g = model.impostor
    frames = []
    with tempfile.TemporaryDirectory(prefix="farfield-bench-") as tmp:
        write_placement_database(Path(tmp) / "db", placement, impostors)
        with ImpostorDatabase(Path(tmp) / "db") as db, PlacementRenderer(scene, db) as rt:
            empty_ms = None
            for position, forward in zip(positions, forwards):
                camera, draws, fig = rt.prepare(position, forward)
                _, plain_draws, plain = rt.prepare(position, forward, plain=True, camera=camera, pvs=True)
                if empty_ms is None:
                    empty_ms = frame_ms(lambda: rt.frame_seconds(camera, []), 9)
                measured, plain_ms = frames_ms(
                    [lambda: rt.frame_seconds(camera, draws), lambda: rt.frame_seconds(camera, plain_draws)], 3
                )
                selected = np.array(fig.drawn, dtype=np.int64)
                plain_sel = np.array(plain.drawn, dtype=np.int64)
                geometry = rt.geometry_draws(selected)
                shown = draws[len(geometry) :]
                cov_geometry = int(np.count_nonzero(rt.render(camera, geometry)[..., 3])) if geometry else 0
                cov_impostor = int(np.count_nonzero(rt.render(camera, shown)[..., 3])) if shown else 0
                cov_plain = int(np.count_nonzero(rt.render(camera, plain_draws)[..., 3])) if plain_draws else 0
                el = rt.elements
                base = float(np.sum(model.geometry_time(el.draw_calls[selected], el.triangles[selected], 0.0)))
                imp = e * cov_impostor + f * fig.quads + g * fig.impostors
                discs = plain_estimate(model, el, selected, position, math.radians(rt.fov_deg), rt.resolution, depth)
                clipped = plain_estimate(model, el, selected, position, 0.0, 0, depth, camera)
                # The pixel terms alone (model units / c = pixels), each capped at ``depth`` frames.
                cap = depth * rt.resolution**2
                b = el.bounds[selected]
                px_free = min(cap, float(element_pixels(el, position, position, math.radians(rt.fov_deg), rt.resolution,
                                                        selected).sum())) if selected.size else 0.0  # fmt: skip
                px_clipped = min(cap, float(box_frame_pixels(camera, b[:, 0], b[:, 1]).sum())) if selected.size else 0.0
                frames.append({
                    "cpv": fig.cpv, "status": fig.status, "measured": measured, "estimate": fig.estimate,
                    "drawn_covered": d + base + c * cov_geometry + imp, "drawn_discs": discs + imp,
                    "drawn_clipped": clipped + imp, "pixels_free": px_free, "pixels_clipped": px_clipped,
                    # the estimate before 2026-12-07 (clip30): direction-free pixels where the view is in no CPV
                    "estimate_free": fig.estimate if fig.cpv is not None else discs,
                    "plain_ms": plain_ms, "plain_covered": cov_plain,
                    "plain_draw_calls": int(el.draw_calls[plain_sel].sum()) if plain_sel.size else 0,
                    "plain_triangles": int(el.triangles[plain_sel].sum()) if plain_sel.size else 0,
                    "plain_discs": plain_estimate(model, el, plain_sel, position, math.radians(rt.fov_deg), rt.resolution, depth),
                    "draw_calls": int(el.draw_calls[selected].sum()) if selected.size else 0,
                    "triangles": int(el.triangles[selected].sum()) if selected.size else 0,
                    "covered_geometry": cov_geometry, "covered_impostor": cov_impostor,
                    "quads": fig.quads, "impostors": fig.impostors,
                })  # fmt: skip
    m = np.array([fr["measured"] for fr in frames])
    est = np.array([fr["estimate"] for fr in frames])
    cov = np.array([fr["drawn_covered"] for fr in frames])
    disc = np.array([fr["drawn_discs"] for fr in frames])
    clip = np.array([fr["drawn_clipped"] for fr in frames])
    est_free = np.array([fr["estimate_free"] for fr in frames])
    in_cpv = np.array([fr["cpv"] is not None for fr in frames])
    geo = np.array([fr["covered_geometry"] for fr in frames], dtype=float)
    seen = geo > 0  # the pixel ratios over frames that cover some geometry
    px_free = np.array([fr["pixels_free"] for fr in frames])
    px_clip = np.array([fr["pixels_clipped"] for fr in frames])
    return {
        "t_max": t_max, "plan_s": plan_s, "impostors": placement.summary["impostors"],
        "memory_bytes": placement.summary["memory_bytes"], "empty_ms": empty_ms,
        "within_t_max": float(np.mean(m <= t_max)), "estimate_within_t_max": float(np.mean(est <= t_max * (1 + 1e-9))),
        "measured_p50": float(np.median(m)), "measured_p99": float(np.percentile(m, 99)),
        "frames_in_cpv": int(in_cpv.sum()),
        "estimate_over_measured": ratios(est / m), "drawn_covered_over_measured": ratios(cov / m),
        "drawn_discs_over_measured": ratios(disc / m), "discs_over_covered": ratios(disc / cov),
        "drawn_clipped_over_measured": ratios(clip / m), "estimate_free_over_measured": ratios(est_free / m),
        "pixels_free_over_covered": ratios(px_free[seen] / geo[seen]),
        "pixels_clipped_over_covered": ratios(px_clip[seen] / geo[seen]),
        "cpv_over_drawn_discs": ratios(est[in_cpv] / disc[in_cpv]), "frames": frames,
    }  # fmt: skip


def cpv_spread(
    scene, lo, hi, cpv: float, resolution: int, model: CostModel, depth: float, vdi_deg: float, samples: int, seed: int
) -> dict:
    """Part ``cpv``: how much of (b) any upper bound over a CPV must keep.  Every (smallest region,
    VDI) of the view space as a CPV (t_max ~0, with the planner's PVS), and per CPV ``samples``
    views (eyes uniform in the region, directions uniform in the VDI's face square): the model over
    each view's PVS in its frustum (discs from the eye, as the walk's estimate of a view in no CPV).
    ``cpv_over_worst``: the CPV's estimate over its worst sampled view (what per-direction or
    per-position sub-intervals could win at most); ``worst_over_median``: its worst sampled view
    over its median one (what no bound over the whole CPV can avoid)."""
    from farfield.core.placement.runtime import boxes_in_frustum
    from farfield.core.techniques.envmap.runtime import camera_at
    from farfield.core.visibility.pvs import RegionVisibility

    elements = Elements.of(scene)
    fov = math.radians(45.0)
    visible = RegionVisibility(scene, elements, lo, hi, cpv, resolution, fov)
    try:
        pv = problem_view_space(elements, Hierarchy.build(elements), lo, hi, model, 1e-12, fov, resolution, cpv,
                                vdi_deg, depth, visible)  # fmt: skip
        pvs = [visible.pvs(pv.region_lo[r], pv.region_hi[r]) for r in range(pv.region_lo.shape[0])]
    finally:
        visible.release()
    rng = np.random.default_rng(seed)
    b = elements.bounds
    over_worst, worst_over_median = [], []
    for k in range(pv.count):
        r, vdi = int(pv.cpv_region[k]), pv.cpv_vdi[k]
        x0, x1, y0, y1 = vdi.ranges()
        eyes = rng.uniform(pv.region_lo[r], pv.region_hi[r], (samples, 3))
        dirs = vdi.directions(rng.uniform(x0, x1, samples), rng.uniform(y0, y1, samples))
        ids = np.asarray(pvs[r], dtype=np.int64)
        times = []
        for eye, forward in zip(eyes, dirs):
            camera = camera_at(eye, forward, 45.0, resolution, 0.1, 1e4)
            seen = ids[boxes_in_frustum(camera, b[ids, 0], b[ids, 1])] if ids.size else ids
            times.append(plain_estimate(model, elements, seen, eye, fov, resolution, depth))
        times = np.array(times)
        over_worst.append(pv.time[k] / times.max())
        worst_over_median.append(times.max() / np.median(times))
    return {"cpvs": pv.count, "samples": samples, "cpv_over_worst": ratios(np.array(over_worst)),
            "worst_over_median": ratios(np.array(worst_over_median))}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="street,downtown,city")
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--cpv-divisions", type=int, default=4)
    parser.add_argument("--views", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--model", default=None, help="a cost model file (default: the builtin LLVMPIPE_MODEL)")
    parser.add_argument("--depth-complexity", type=float, default=DEFAULT_DEPTH_COMPLEXITY)
    parser.add_argument("--vdi-deg", type=float, default=45.0, help="the smallest view-direction interval")
    parser.add_argument(
        "--t-max", default=None, help="t_max per scene, ms, comma-separated (default: half the worst view's estimate)"
    )
    parser.add_argument("--parts", default="walk", help="walk, cpv (see cpv_spread), or both")
    parser.add_argument("--cpv-samples", type=int, default=32, help="part cpv: views sampled per CPV")
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    model = LLVMPIPE_MODEL if args.model is None else CostModel.load(args.model)
    print(f"# {renderer_info().renderer}; {args.resolution} px, 45°, CPV = side / {args.cpv_divisions}; model "
          f"{args.model or 'builtin'} {model.geometry}, depth complexity {args.depth_complexity:g}, "
          f"VDI {args.vdi_deg:g}°", flush=True)  # fmt: skip
    print(f"{'scene':<9} {'t_max':>6} {'imp':>4} {'MiB':>6} {'in t':>5} {'by est':>6} {'in CPV':>6}  "
          f"{'est/meas':>20} {'(a) covered/meas':>20} {'(a) discs/meas':>20} {'(b) CPV/discs':>20}")  # fmt: skip
    rows = []
    budgets = [None] * len(args.scene.split(",")) if args.t_max is None else [float(t) for t in args.t_max.split(",")]
    for name, budget in zip(args.scene.split(","), budgets, strict=True):
        scene, lo, hi = scene_of(name)
        cpv = float(np.max(hi - lo)) / args.cpv_divisions
        if "cpv" in args.parts:
            c = cpv_spread(scene, lo, hi, cpv, args.resolution, model, args.depth_complexity, args.vdi_deg,
                           args.cpv_samples, args.seed)  # fmt: skip
            print(f"{name}: {c['cpvs']} CPVs x {c['samples']} sampled views: CPV ÷ worst sampled view p50 "
                  f"{c['cpv_over_worst']['p50']:.2f} p95 {c['cpv_over_worst']['p95']:.2f}; worst ÷ median sampled view "
                  f"p50 {c['worst_over_median']['p50']:.2f} p95 {c['worst_over_median']['p95']:.2f}", flush=True)  # fmt: skip
            rows.append({"scene": name, "cpv": c})
        if "walk" not in args.parts:
            continue
        r = walk_split(scene, lo, hi, cpv, args.resolution, args.views, args.seed, model, args.depth_complexity,
                       args.vdi_deg, budget)  # fmt: skip
        r["scene"] = name

        def cell(s):
            return f"{s['p50']:5.2f} {s['p95']:6.2f} {100 * s['under_30pct']:4.0f}%"

        print(f"  {name} the estimate: direction-free pixels (before) ÷ measured {cell(r['estimate_free_over_measured'])}; "
              f"clipped (after) ÷ measured {cell(r['estimate_over_measured'])}; (a'') clipped, what was drawn ÷ measured "
              f"{cell(r['drawn_clipped_over_measured'])}; pixel term ÷ covered geometry pixels ({int(r['pixels_clipped_over_covered']['n'])} "
              f"frames): free {cell(r['pixels_free_over_covered'])}, clipped {cell(r['pixels_clipped_over_covered'])}", flush=True)  # fmt: skip
        print(f"{name:<9} {r['t_max']:6.3g} {r['impostors']:4d} {r['memory_bytes'] / 2**20:6.1f} {100 * r['within_t_max']:4.0f}% "
              f"{100 * r['estimate_within_t_max']:5.0f}% {r['frames_in_cpv']:6d}  {cell(r['estimate_over_measured']):>20} "
              f"{cell(r['drawn_covered_over_measured']):>20} {cell(r['drawn_discs_over_measured']):>20} "
              f"{cell(r['cpv_over_drawn_discs']):>20}", flush=True)  # fmt: skip
        rows.append(r)
        if args.json:
            Path(args.json).write_text(json.dumps(rows, indent=1, default=float))
    print("(cells: p50 p95 under-by->30% share; measured ms p50 / empty frame ms: "
          + ", ".join(f"{r['scene']} {r['measured_p50']:.2f} / {r['empty_ms']:.3f}" for r in rows if "frames" in r) + ")")  # fmt: skip


if __name__ == "__main__":
    main()
