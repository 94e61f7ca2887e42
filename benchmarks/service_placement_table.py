"""The table of ``benchmarks/service_placement_walk.sh``: a placement job through the service and its walkthrough, per scene.

Usage: ``.venv/bin/python benchmarks/service_placement_table.py WORK SCENE [SCENE ...]``

Reads ``WORK/SCENE/{record,placement,walk}.json`` and ``WORK/SCENE/db/index.json`` (the job's record from ``GET /v1/jobs/{id}``, its
database's summary from ``GET /v1/jobs/{id}/placement``, ``farfield walkthrough --json``) and prints
one Markdown table: impostors (the plan's, and drawn by some CPV after the check-and-repair
rounds, which bake, measure and add impostors where the baked figures put a CPV over t_max), memory (baked texture bytes of the impostors some CPV draws,
and the cost model's estimate), CPVs (solved / unsolved / unsolvable), the job's time broken down
(its ``timing``: wall, planning, checking, cells busy, overhead; the bake's seconds; the PVS's
seconds and lattice points from the downloaded database's ``parameters.visibility``), the walk's hole pixels and the
PVS-dropped pixels among them, the share of views within t_max measured and by the estimate, and
estimate ÷ measured frame (p50, p95, share under by more than 30 %), each view's estimate over its
measured runtime frame.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np


def row(folder: Path, name: str) -> str:
    record = json.loads((folder / "record.json").read_text())
    totals = json.loads((folder / "placement.json").read_text())["totals"]
    walk = json.loads((folder / "walk.json").read_text())
    s, t = walk["summary"], record["timing"]
    index = json.loads((folder / "db" / "index.json").read_text())  # the downloaded database
    vis = index["placement"]["parameters"].get("visibility")
    pvs = f"{vis['seconds']:.0f} ({vis['points_rendered']})" if isinstance(vis, dict) else "-"
    ratio = np.array([f["estimate"] / f["runtime_ms"] for f in walk["frames"] if f["runtime_ms"] > 0])
    rounds = (record.get("placement") or {}).get("rounds") or []
    added = [r["added"] for r in rounds if r.get("added")]
    planned = min(added[0]) if added else totals["impostors_listed"]  # the plan's, before the check rounds added any
    by = totals["cpvs_by_status"]
    cpvs = f"{totals['cpvs']} ({by.get('solved', 0)} / {by.get('unsolved', 0)} / {by.get('unsolvable', 0)})"
    memory = f"{totals['memory_bytes_baked'] / 2**20:.2f} ({totals['memory_bytes_estimated'] / 2**20:.2f})"
    timing = (
        f"{t['wall_s']:.0f} = {t['planning_s']:.0f} + {t['checking_s']:.0f} + {t['cells_busy_s']:.0f} + {t['overhead_s']:.0f} "
        f"({t['cells']} cells, bake {t['bake_s']:.0f}; PVS {pvs})"
    )
    within = f"{100 * s['share_within_t_max']:.0f} % / {100 * s['share_estimate_within_t_max']:.0f} %"
    ratios = f"{np.percentile(ratio, 50):.2f} / {np.percentile(ratio, 95):.2f} / {100 * np.mean(ratio < 1 / 1.3):.0f} %"
    holes = f"{s.get('hole_pixels', '-')} ({s.get('pvs_dropped_pixels', '-')})"
    return (
        f"| {name} | {s['t_max']:.4g} | {planned} → {totals['impostors']} ({len(rounds)}) | {memory} | {cpvs} | {timing} | {s['frames']} | {holes} | "
        f"{within} | {s['runtime_ms_p50']:.2f} / {s['runtime_ms_p99']:.2f} ({s['plain_ms_p99']:.2f}) | {ratios} |"
    )


def main() -> None:
    if len(sys.argv) < 3:
        raise SystemExit("usage: service_placement_table.py WORK SCENE [SCENE ...]")
    work = Path(sys.argv[1])
    print(
        "| scene | t_max ms | impostors: planned → drawn (check rounds) | MiB baked (estimated) | CPVs (solved / unsolved / unsolvable) "
        "| job s: wall = planning + checking + cells busy + overhead (cells; bake s; PVS s (lattice points)) | views | hole pixels (PVS-dropped) "
        "| within t_max: measured / by the estimate | runtime ms p50 / p99 (plain p99) | estimate ÷ measured p50 / p95 / under > 30 % |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name in sys.argv[2:]:
        print(row(work / name, name))


if __name__ == "__main__":
    main()
