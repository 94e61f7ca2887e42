"""The envmap grid of ``bench_placement.py`` (test 15g) with its near field counted over the worst
enclosing frustum of its cell, as the placement's problem views are, beside the table's count of
every element from every direction (docs/placement/visibility.md, "Is the comparison fair to both sides?").

Usage: ``.venv/bin/python benchmarks/bench_grid_frustum.py --scene street --size 400 --cells 37.5,18.75 [--vdi-deg 11.25]``

Per grid side: the grid's memory by the model, how many cells are over t_max at their smallest near
field, and the median near field, both ways.  The table's count is
:func:`bench_placement._envmap_near_field` (every element whose bounds meet the near field's cube,
from every direction: what the envmap reference runtime draws, as it draws its whole near field).
The frustum count takes the largest near field whose frame fits t_max where the near field's
geometry is the worst smallest view-direction interval's enclosing-frustum estimate from the cell
(:func:`farfield.core.placement.view_space.problem_view_space` over the cell, every interval a
problem view, the near field's elements only): what a runtime culling its near field to the frustum
would draw.  The layers and their terms are the table's.  No PVS (the table's grids are the same
with and without it).  Model arithmetic only, on CPU.
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

from farfield.core.placement.cost_model import LLVMPIPE_MODEL, primitive_model  # noqa: E402
from farfield.core.placement.hierarchy import Elements, Hierarchy  # noqa: E402
from farfield.core.placement.view_space import problem_view_space  # noqa: E402
from farfield.core.techniques.envmap.arrangement import layers_for_near_field  # noqa: E402
from farfield.core.techniques.envmap.technique import EnvmapOptions  # noqa: E402
from farfield.core.viewcells import grid_boxes  # noqa: E402

RESOLUTION = 128
FOV = math.radians(45.0)


class FrustumNearField:
    """Near fields of envmap cells counted over the worst enclosing frustum (see the module docstring)."""

    def __init__(self, scene, t_max: float, model, vdi_deg: float) -> None:
        self.elements = Elements.of(scene)
        self.hierarchy = Hierarchy.build(self.elements)
        self.t_max, self.model, self.vdi_deg = t_max, model, vdi_deg
        self.options = EnvmapOptions(resolution=RESOLUTION, fov_deg=45.0)

    def geometry(self, c_lo, c_hi, ids: np.ndarray) -> float:
        """The worst interval's estimate from the cell over elements ``ids`` (the frame's constant when none)."""
        keep = np.zeros(self.elements.count, dtype=bool)
        keep[ids] = True
        pv = problem_view_space(
            self.elements, self.hierarchy, c_lo, c_hi, self.model, 1e-12, FOV, RESOLUTION,
            float(np.max(c_hi - c_lo)), self.vdi_deg, visible=lambda r_lo, r_hi, idx: idx[keep[idx]],
        )  # fmt: skip
        return float(pv.time.max()) if pv.count else self.model.frame_time

    def layers_time(self, cell: float, near: float) -> float:
        face = self.options.texels_per_face
        layers = layers_for_near_field(cell, face, near, self.options.alpha, 3)
        e, f, g = self.model.impostor
        return bp.ENVMAP_FACES_IN_VIEW * (g + f * float(self.model.quads(layers, face * face))) + e * RESOLUTION**2

    def near_field(self, c_lo, c_hi) -> tuple[float, bool]:
        """(near field, fits): inf when every element fits with no layer; the smallest near field
        (just outside the cell) and False when nothing fits."""
        centre, cell = 0.5 * (c_lo + c_hi), float(np.max(c_hi - c_lo))
        b = self.elements.bounds
        dist = np.max(np.maximum(0.0, np.maximum(b[:, 0] - centre, centre - b[:, 1])), axis=1)
        order = np.argsort(dist)
        if self.geometry(c_lo, c_hi, order) <= self.t_max:
            return math.inf, True
        least = 0.51 * cell
        inside = int(np.searchsorted(dist[order], least))
        if self.geometry(c_lo, c_hi, order[:inside]) > self.t_max:
            return least, False
        lo_k, hi_k = inside, order.size  # the geometry grows with k: bisect on it alone
        while hi_k - lo_k > 1:
            mid = (lo_k + hi_k) // 2
            lo_k, hi_k = (mid, hi_k) if self.geometry(c_lo, c_hi, order[:mid]) <= self.t_max else (lo_k, mid)
        for k in range(lo_k, inside, -1):  # then the largest near field whose layers fit too
            near = float(dist[order[min(k, order.size - 1)]])
            if self.geometry(c_lo, c_hi, order[:k]) + self.layers_time(cell, near) <= self.t_max:
                return near, True
        return least, False


def grid(
    scene, lo, hi, cell: float, t_max: float, model, frustum: FrustumNearField | None
) -> tuple[int, float, int, float]:
    """(cells, MiB, cells over t_max, median near field) of the grid of side ``cell``."""
    elements = Elements.of(scene)
    options = EnvmapOptions(resolution=RESOLUTION, fov_deg=45.0)
    face = options.texels_per_face
    counts = bp._grid_counts(lo, hi, cell)
    total, over, nears = 0.0, 0, []
    for _, box in grid_boxes(lo, lo + counts * cell, counts):
        if frustum is None:
            near, estimate = bp._envmap_near_field(elements, box.lo, box.hi, t_max, model, RESOLUTION)
            over += estimate > t_max
        else:
            near, fits = frustum.near_field(box.lo, box.hi)
            over += not fits
        if math.isinf(near):
            continue
        layers = layers_for_near_field(cell, face, near, options.alpha, 3)
        total += 6.0 * float(model.memory_bytes(layers, face * face))
        nears.append(near)
    return int(np.prod(counts)), total / 2**20, int(over), float(np.median(nears)) if nears else 0.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", choices=["city", "street", "downtown"], default="street")
    parser.add_argument("--size", type=int, default=None)
    parser.add_argument("--detail", type=int, default=None)
    parser.add_argument("--cells", default="", help="grid sides, comma-separated (default: side / 2^k, k = 0..5)")
    parser.add_argument("--vdi-deg", type=float, default=11.25)
    parser.add_argument("--cost-model", choices=["llvmpipe", "primitives"], default="llvmpipe")
    args = parser.parse_args()
    model = LLVMPIPE_MODEL if args.cost_model == "llvmpipe" else primitive_model()
    build = {"city": bp.city_scene, "street": bp.street_scene, "downtown": bp.downtown_scene}[args.scene]
    scene, lo, hi = build(False, args.size, *([args.detail] if args.detail else []))
    t_max = 0.5 * bp._worst_view(scene, lo, hi, model, RESOLUTION)
    side = float(np.max(hi - lo))
    cells = [float(c) for c in args.cells.split(",") if c.strip()] or [side / 2**k for k in range(6)]
    frustum = FrustumNearField(scene, t_max, model, args.vdi_deg)
    print(f"# {args.scene}: t_max {t_max:.4g} {model.unit}; the frustum count over {args.vdi_deg:g}° intervals")
    print(
        f"{'cells':>14} {'every direction: MiB':>21} {'over':>5} {'near':>6} {'worst frustum: MiB':>19} {'over':>5} {'near':>6} {'CPU s':>6}"
    )
    for cell in cells:
        started = time.process_time()
        n, mib_all, over_all, near_all = grid(scene, lo, hi, cell, t_max, model, None)
        _, mib_f, over_f, near_f = grid(scene, lo, hi, cell, t_max, model, frustum)
        print(f"{f'{n} x {cell:.4g}':>14} {mib_all:>21.2f} {over_all:>5} {near_all:>6.1f} {mib_f:>19.2f} {over_f:>5} {near_f:>6.1f} "
              f"{time.process_time() - started:>6.1f}", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
