"""What a placement leaves over t_max, and how near its impostors' geometry lies (issue 57, the
memory against the envmap grid, docs/placement/visibility.md "At the planner's 11.25° view-direction intervals").

Usage: ``.venv/bin/python benchmarks/bench_unsolved_cpvs.py --scene city --size 400 [--cpv-divisions 4] [--vdi-deg 11.25] [--visibility]``

Plans one placement as ``bench_placement.py``'s reference row (128 px, t_max half the worst view's
estimate, the builtin llvmpipe model) and prints:

* per unsolved CPV (means): its time after placement, the frame's constant, the geometry no impostor
  may replace (its leaf meets the region), the impostors drawn, and the geometry left that some
  impostor could replace, by its box distance to the CPV's region in CPV sides; of that geometry,
  the pixel term, and the part under a node with a candidate that serves the CPV (a candidate
  serves only CPVs where its impostor is faster than the node's geometry) or under none;
* per drawn impostor: its estimated memory by its node's box distance to the nearest region that
  draws it, in CPV sides, with the median of its estimated layers.

Model arithmetic only (the PVS, with ``--visibility``, is rendered on EGL); nothing is baked.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_placement as bp  # noqa: E402

from farfield.core.placement.cost_model import LLVMPIPE_MODEL  # noqa: E402
from farfield.core.placement.hierarchy import Elements  # noqa: E402
from farfield.core.placement.planner import PlacementSettings, place  # noqa: E402

BINS = (0.5, 1.0, 2.0, 4.0, math.inf)  # distance classes, CPV sides
RESOLUTION = 128


def box_distance(a_lo, a_hi, b_lo, b_hi) -> np.ndarray:
    """Euclidean distance between axis-aligned boxes (broadcast over leading axes)."""
    gap = np.maximum(0.0, np.maximum(np.asarray(b_lo) - a_hi, np.asarray(a_lo) - b_hi))
    return np.linalg.norm(gap, axis=-1)


def covered_by(positions: np.ndarray, hierarchy, nodes) -> np.ndarray:
    """(k,) bool: which hierarchy positions lie under one of ``nodes``."""
    out = np.zeros(positions.size, dtype=bool)
    for n in nodes:
        out |= (positions >= hierarchy.start[n]) & (positions < hierarchy.end[n])
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", choices=["city", "street", "downtown"], default="city")
    parser.add_argument("--size", type=int, default=None)
    parser.add_argument("--detail", type=int, default=None)
    parser.add_argument("--cpv-divisions", type=int, default=4)
    parser.add_argument("--vdi-deg", type=float, default=11.25)
    parser.add_argument("--visibility", action="store_true", help="plan with the sampled PVS (rendered here)")
    args = parser.parse_args()
    model = LLVMPIPE_MODEL
    build = {"city": bp.city_scene, "street": bp.street_scene, "downtown": bp.downtown_scene}[args.scene]
    scene, lo, hi = build(False, args.size, *([args.detail] if args.detail else []))
    t_max = 0.5 * bp._worst_view(scene, lo, hi, model, RESOLUTION)
    cpv = float(np.max(hi - lo)) / args.cpv_divisions
    visible = None
    if args.visibility:
        from farfield.core.visibility.pvs import RegionVisibility

        visible = RegionVisibility(scene, Elements.of(scene), lo, hi, cpv, RESOLUTION, math.radians(45.0))
    started = time.process_time()
    settings = PlacementSettings(
        t_max=t_max, model=model, options={"resolution": RESOLUTION}, cpv_size=cpv, vdi_deg=args.vdi_deg
    )
    try:
        placement = place(scene, lo, hi, settings, visible=visible, keep_state=True)
    finally:
        if visible is not None:
            visible.release()
    state = placement.state
    pv, h, greedy, cand = state.pv, state.hierarchy, state.greedy, state.cand
    bounds = Elements.of(scene).bounds
    s = placement.summary
    print(f"# {args.scene}: t_max {t_max:.4g} ms, CPV {cpv:.4g}, {args.vdi_deg:g}°; {s['cpvs']} CPVs, {s['cpvs_unsolved']} unsolved, "
          f"{s['cpvs_unsolvable']} unsolvable; {s['impostors']} impostors, {s['memory_bytes'] / 2**20:.2f} MiB; "
          f"candidates {s['candidates']} (refused: {s['candidates_refused_by_technique']} by the technique, "
          f"{s['candidates_refused_by_memory']} by memory); plan {time.process_time() - started:.1f} CPU s")  # fmt: skip

    row_node = np.repeat(cand.node, np.diff(cand.served_offsets))
    unsolved = [c["id"] for c in placement.cpvs if c["status"] == "unsolved"]
    left = np.zeros(len(BINS))
    sums = dict.fromkeys(("after", "fixed", "impostors", "pixels", "served", "not served"), 0.0)
    for q in unsolved:
        r = pv.cpv_region[q]
        a, b = pv.offsets[q], pv.offsets[q + 1]
        pos, et, fixed = pv.positions[a:b], pv.entry_time[a:b], pv.entry_fixed[a:b]
        drawn = [greedy.chosen[k] for k in greedy.drawn[q]]
        keep = ~covered_by(pos, h, [c.node for c in drawn])
        served = covered_by(pos, h, np.unique(row_node[cand.served == q]))
        e = h.order[pos]
        d = box_distance(pv.region_lo[r], pv.region_hi[r], bounds[e, 0], bounds[e, 1]) / cpv
        free = keep & ~fixed
        np.add.at(left, np.searchsorted(BINS, d[free], side="left"), et[free])
        sums["after"] += placement.cpvs[q]["time_after"]
        sums["fixed"] += float(et[keep & fixed].sum())
        sums["impostors"] += sum(c.cpvs[q][1] for c in drawn)
        sums["pixels"] += model.geometry[2] * float(pv.entry_pixels[a:b][keep].sum())
        sums["served"] += float(et[keep & served].sum())
        sums["not served"] += float(et[keep & ~served].sum())
    n = max(1, len(unsolved))
    print(f"unsolved CPVs ({len(unsolved)}), means in ms: after {sums['after'] / n:.3f} (over t_max by {sums['after'] / n - t_max:.3f}); "
          f"frame {model.frame_time:.3f}; geometry no impostor may replace {sums['fixed'] / n:.3f}; impostors drawn {sums['impostors'] / n:.3f}")  # fmt: skip
    print("  replaceable geometry left, by distance to the region (CPV sides): "
          + ", ".join(f"<= {BINS[i]:g}: {left[i] / n:.3f}" for i in range(len(BINS))))  # fmt: skip
    print(f"  geometry left (fixed included) {(sums['served'] + sums['not served']) / n:.3f}: its pixel term {sums['pixels'] / n:.3f}; "
          f"under a node with a candidate serving the CPV {sums['served'] / n:.3f}, under none {sums['not served'] / n:.3f}")  # fmt: skip

    regions_of: dict[int, list[int]] = {}
    for c in placement.cpvs:
        for i in c["impostors"]:
            regions_of.setdefault(i, []).append(int(pv.cpv_region[c["id"]]))
    memory, count, layers = np.zeros(len(BINS)), np.zeros(len(BINS), dtype=int), [[] for _ in BINS]
    for imp in placement.impostors:
        if not imp["cpvs"]:
            continue
        node, rs = imp["node"], np.array(regions_of[imp["id"]])
        d = float(np.min(box_distance(pv.region_lo[rs], pv.region_hi[rs], h.lo[node], h.hi[node]))) / cpv
        k = int(np.searchsorted(BINS, d, side="left"))
        memory[k] += imp["memory_bytes_estimated"]
        count[k] += 1
        layers[k].append(imp["layers_estimated"])
    total = max(1.0, float(memory.sum()))
    print("impostors by their node's distance to the nearest region drawing them (CPV sides): " + "; ".join(
        f"<= {BINS[i]:g}: {count[i]}, {memory[i] / 2**20:.1f} MiB ({100 * memory[i] / total:.0f} %), median layers "
        f"{np.median(layers[i]) if layers[i] else 0:.0f}" for i in range(len(BINS))))  # fmt: skip


if __name__ == "__main__":
    main()
