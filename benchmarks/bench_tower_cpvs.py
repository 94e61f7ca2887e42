"""Why downtown's problem views stay unsolved (issue 57): per unsolved CPV, what its estimate is
made of, by object kind (towers, houses, ground), term (draw calls, triangles, pixels) and distance
of the element to the CPV's region, which candidates serve its towers, and whether t_max is
reachable at all if every element that may be replaced were replaced by its cheapest conceivable
stand-in.

Usage: ``.venv/bin/python benchmarks/bench_tower_cpvs.py [--cpv-divisions 8] [--vdi-deg 11.25] [--lod]``

Plans ``bench_placement.py``'s downtown at the reference settings (128 px, t_max half the worst
view's estimate, the builtin llvmpipe model, no visibility: the service's PVS culls next to nothing
there, docs/placement/visibility.md), keeps the planner's state and prints tables.  Model only.
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
from bench_unsolved_cpvs import box_distance, covered_by  # noqa: E402

from farfield.core.placement.candidates import KIND_NAMES  # noqa: E402
from farfield.core.placement.cost_model import LLVMPIPE_MODEL  # noqa: E402
from farfield.core.placement.planner import PlacementSettings, place  # noqa: E402

RESOLUTION = 128
DIST = (0.0, 25.0, 50.0, 100.0, math.inf)  # element box distance to the region, metres ("0": touching or inside)


def kind_of(name: str) -> str:
    return name.split("_")[0]  # tower, house, ground


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", choices=["downtown", "street"], default="downtown")
    parser.add_argument("--cpv-divisions", type=int, default=8)
    parser.add_argument("--vdi-deg", type=float, default=11.25)
    parser.add_argument("--lod", action="store_true")
    args = parser.parse_args()
    model = LLVMPIPE_MODEL
    build = {"downtown": bp.downtown_scene, "street": bp.street_scene}[args.scene]
    scene, lo, hi = build(False, None)
    t_max = 0.5 * bp._worst_view(scene, lo, hi, model, RESOLUTION)
    cpv = float(np.max(hi - lo)) / args.cpv_divisions
    settings = PlacementSettings(t_max=t_max, model=model, options={"resolution": RESOLUTION}, cpv_size=cpv,
                                 vdi_deg=args.vdi_deg, lod=args.lod)  # fmt: skip
    started = time.process_time()
    placement = place(scene, lo, hi, settings, keep_state=True)
    cpu = time.process_time() - started
    st = placement.state
    pv, h, greedy, cand, el = st.pv, st.hierarchy, st.greedy, st.cand, st.elements
    s = placement.summary
    print(f"# {args.scene}{' --lod' if args.lod else ''}: t_max {t_max:.4g} ms, CPV {cpv:g} m, {args.vdi_deg:g}°; {s['cpvs']} CPVs, "
          f"{s['cpvs_unsolved']} unsolved; {s['impostors']} impostors, {s['memory_bytes'] / 2**20:.2f} MiB; {s['candidates']} candidates; {cpu:.1f} CPU s")  # fmt: skip
    a_draw, b_tri, c_pix, d_frame = model.geometry
    p_pix, q_quad, r_imp = model.impostor
    kinds = np.array([kind_of(scene.objects[int(o)].name) for o in el.object_index])
    row_node = np.repeat(cand.node, np.diff(cand.served_offsets))
    unsolved = [c["id"] for c in placement.cpvs if c["status"] == "unsolved"]
    n = max(1, len(unsolved))
    acc: dict[str, float] = {}

    def add(key, value):
        acc[key] = acc.get(key, 0.0) + float(value)

    reach = {"impostor": 0, "lod12": 0}
    touching = 0
    for q in unsolved:
        r = pv.cpv_region[q]
        a, b = pv.offsets[q], pv.offsets[q + 1]
        pos, et, fixed, px = pv.positions[a:b], pv.entry_time[a:b], pv.entry_fixed[a:b], pv.entry_pixels[a:b]
        e = h.order[pos]
        drawn = [greedy.chosen[k] for k in greedy.drawn[q]]
        left = ~covered_by(pos, h, [c.node for c in drawn])
        served = covered_by(pos, h, np.unique(row_node[cand.served == q]))
        d = box_distance(pv.region_lo[r], pv.region_hi[r], el.bounds[e, 0], el.bounds[e, 1])
        add("before", pv.time[q])
        add("after", placement.cpvs[q]["time_after"])
        add("impostors", sum(c.cpvs[q][1] for c in drawn))
        for k in ("tower", "house", "ground"):
            m = left & (kinds[e] == k)
            add(f"{k} time", et[m].sum())
            add(f"{k} draw", a_draw * el.draw_calls[e[m]].sum())
            add(f"{k} tri", b_tri * el.triangles[e[m]].sum())
            add(f"{k} pix", c_pix * px[m].sum())
            add(f"{k} fixed", et[m & fixed].sum())
            add(f"{k} served", et[m & served].sum())
            for i in range(len(DIST)):
                lo_d = -1.0 if i == 0 else DIST[i - 1]
                add(f"{k} d{i}", et[m & (d > lo_d) & (d <= DIST[i])].sum())
        tw = kinds[e] == "tower"
        objs = el.object_index[e[tw]]
        touching += bool(np.any(fixed[tw]))
        add("towers seen", np.unique(objs).size)
        add("towers touching", np.unique(objs[fixed[tw]]).size)
        # reachable? every element no impostor may replace kept; the rest (a) one impostor each tower
        # and one for everything else, quads 0 (pixels only); (b) each tower as a 12-triangle box.
        free = left & ~fixed
        base = model.frame_time + et[fixed].sum() + sum(c.cpvs[q][1] for c in drawn)
        ftw = free & tw
        towers_free = np.unique(el.object_index[e[ftw]])
        pix_t = px[ftw].sum()
        imp = base + p_pix * px[free].sum() + r_imp * (towers_free.size + 1)
        lod = base + et[free & ~tw].sum() + a_draw * towers_free.size + b_tri * 12 * towers_free.size + c_pix * pix_t
        reach["impostor"] += imp <= t_max
        reach["lod12"] += lod <= t_max
        add("bound impostor", imp)
        add("bound lod12", lod)
    lods = [imp for imp in placement.impostors if imp["cpvs"] and imp["technique"] == "lod"]
    if lods:
        print(f"chosen levels of detail: {len(lods)}, {sum(i['memory_bytes_estimated'] for i in lods) / 2**20:.2f} MiB; "
              f"built for {st.seconds.get('lod_nodes', '?')} nodes")  # fmt: skip
    if not unsolved:
        return
    print(f"\nunsolved CPVs: {len(unsolved)}; means, ms: before {acc['before'] / n:.3f}, after {acc['after'] / n:.3f} (t_max {t_max:.3f}), "
          f"impostors drawn {acc['impostors'] / n:.3f}, frame {model.frame_time:.3f}; towers seen {acc['towers seen'] / n:.1f}, "
          f"touching the region (leaf meets it) {acc['towers touching'] / n:.2f}; CPVs with a touching tower {touching}")  # fmt: skip
    print("\n| geometry left, mean ms | total | draw calls | triangles | pixels | no impostor may replace | under a node serving the CPV | "
          + " | ".join(("touching" if i == 0 else f"<= {DIST[i]:g} m") for i in range(len(DIST))) + " |")  # fmt: skip
    print("|---" * (7 + len(DIST)) + "|")
    for k in ("tower", "house", "ground"):
        print(f"| {k} | " + " | ".join(f"{acc[f'{k} {t}'] / n:.3f}" for t in ("time", "draw", "tri", "pix", "fixed", "served"))
              + " | " + " | ".join(f"{acc[f'{k} d{i}'] / n:.3f}" for i in range(len(DIST))) + " |")  # fmt: skip
    print(f"\nreachable if every replaceable element were replaced (fixed and drawn impostors kept): one pixel-only "
          f"impostor per tower + one for the rest: {reach['impostor']} of {len(unsolved)} (mean {acc['bound impostor'] / n:.3f} ms); "
          f"each tower as a 12-triangle box, the rest as is: {reach['lod12']} (mean {acc['bound lod12'] / n:.3f} ms)")  # fmt: skip
    # candidates of tower nodes: which kinds, how many CPVs each serves, their distances
    tower_nodes = [k for k in range(h.count) if np.all(kinds[h.order[h.start[k] : h.end[k]]] == "tower")]
    tn = np.isin(cand.node, tower_nodes)
    print(f"\ncandidates of tower-only nodes ({len(tower_nodes)} nodes): " + ", ".join(
        f"{KIND_NAMES[kk]} {int(np.sum(tn & (cand.kind == kk)))}" for kk in range(len(KIND_NAMES))))  # fmt: skip
    print(f"stats: {cand.stats}")
    if unsolved:
        why_not(scene, st, model, unsolved, kinds)


def why_not(scene, st, model, unsolved, kinds, sample: int = 60) -> None:
    """Per (unsolved CPV, tower-only node of its entries that is a whole leaf or more): would a box
    cell of the CPV's own leaf region serve it?  Refused by the estimate (the cell meets the node or
    needs a texture no renderer draws), or estimated and slower than the node's geometry there (a
    candidate serves a CPV only where it is faster); shafts start one node diagonal away."""
    from farfield.core.errors import FarfieldError
    from farfield.core.placement.view_space import CpvGeometry
    from farfield.core.techniques.part import estimate_part_cell
    from farfield.core.viewcells import BoxCell

    pv, h = st.pv, st.hierarchy
    geometry = CpvGeometry(pv, h)
    tower_leafy = [k for k in range(h.count) if np.all(kinds[h.order[h.start[k] : h.end[k]]] == "tower")]
    counts = {"meets": 0, "refused": 0, "slower": 0, "faster": 0, "shaft reach": 0}
    ratio, layers_seen = [], []
    rng = np.random.default_rng(0)
    for q in rng.choice(unsolved, size=min(sample, len(unsolved)), replace=False):
        r = pv.cpv_region[q]
        rlo, rhi = pv.region_lo[r], pv.region_hi[r]
        for n in tower_leafy:
            g, pixels = geometry.of(np.array([n]), np.array([q]))
            if g[0] <= 0.0:
                continue
            gap = float(box_distance(rlo, rhi, h.lo[n], h.hi[n]))
            counts["shaft reach"] += gap >= h.diagonal[n]
            if gap <= 0.0:
                counts["meets"] += 1
                continue
            try:
                layers, texels = estimate_part_cell(BoxCell(rlo, rhi), st.options, np.stack([h.lo[n], h.hi[n]]))
            except FarfieldError:
                counts["refused"] += 1
                continue
            ti = float(np.asarray(model.impostor_time(pixels[0], model.quads(layers, texels))).reshape(-1)[0])
            counts["faster" if g[0] > ti else "slower"] += 1
            ratio.append(ti / g[0])
            layers_seen.append(layers)
    total = max(1, sum(v for k, v in counts.items() if k != "shaft reach"))
    print(f"\nwhy no layered candidate ({min(sample, len(unsolved))} unsolved CPVs sampled; each tower-only node the CPV sees, "
          f"a box cell of the CPV's own region): {counts['meets']} meet the region ({100 * counts['meets'] / total:.0f} %), "
          f"{counts['refused']} refused by the estimate ({100 * counts['refused'] / total:.0f} %), {counts['slower']} slower than "
          f"the node's geometry ({100 * counts['slower'] / total:.0f} %), {counts['faster']} faster; impostor ÷ geometry time "
          f"median {np.median(ratio) if ratio else float('nan'):.2f}, layers median {np.median(layers_seen) if layers_seen else 0:.0f}; "
          f"pairs a node diagonal away or more (where its shafts start): {counts['shaft reach']}")  # fmt: skip


if __name__ == "__main__":
    main()
