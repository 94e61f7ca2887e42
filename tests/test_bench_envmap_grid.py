"""The envmap grid that ``benchmarks/bench_placement.py`` compares a placement with (Table 5.1 test
15), with visibility: each cell's near field counts only its potentially visible set, as the
thesis culled each cell (seed 000 §5.8.2; issue 57, Measure).  Real EGL for the PVS."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

from farfield.core import procedural
from farfield.core.placement.cost_model import primitive_model
from farfield.core.placement.hierarchy import Elements
from farfield.core.scene import Scene, SceneObject
from farfield.core.visibility.pvs import RegionVisibility

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import bench_placement as bench  # noqa: E402

FOV = math.radians(45.0)


def _walled() -> Scene:
    """A wall (x = 10..11) between the view space (x < 0) and a dense block behind it (x = 20..24,
    6,912 triangles), a small box beside the view space that nothing hides, and a box closed in a
    shell just past the view space's corner at z = 10 (hidden from every point, within 3 of the
    region z = 0..10 only)."""

    def box(name, low, high, n=1):
        v, f = procedural.subdivided_box(low, high, n)
        return SceneObject(name, v, f)

    return Scene.from_objects(
        [
            box("wall", (10, -50, -50), (11, 50, 50)),
            box("hidden", (20, -2, -2), (24, 2, 2), 24),
            box("beside", (-5, 0, 30), (-4, 1, 31)),
            box("shell", (1.5, -1, 11.5), (3.5, 1, 13.5)),
            box("tucked", (2, -0.5, 12), (3, 0.5, 13)),
        ],
        "walled",
    )


def test_the_envmap_grid_with_visibility_counts_only_what_its_cells_may_see():
    scene = _walled()
    elements = Elements.of(scene)
    lo, hi = np.array([-10.0, -2.0, -10.0]), np.array([0.0, 2.0, 10.0])
    model = primitive_model()
    t_max = 100.0  # triangles: the wall and the box beside fit, the hidden block does not
    hidden = np.array([n.startswith("hidden") for n in elements.names])
    # Point sampling and a margin of 3: the tucked box is in the PVS of the region z = 0..10 alone.
    vis = RegionVisibility(scene, elements, lo, hi, 10.0, 64, FOV, margin=3.0, erosion=0.0)
    try:
        pvs = bench.cell_pvs(vis, elements.count, lo, hi, 10.0)
        keep = pvs(lo, hi)
        assert keep[elements.names.index("wall")] and keep[elements.names.index("beside")]
        assert hidden.any() and not keep[hidden].any()
        # A cell is the union of the PVS of the smallest regions it meets, and only those.
        regions = bench.leaf_regions(lo, hi, 10.0)
        assert [r[0][2] for r in regions] == [-10.0, 0.0]
        tucked = elements.names.index("tucked")
        assert tucked not in vis.pvs(*regions[0]) and tucked in vis.pvs(*regions[1])
        first = np.zeros(elements.count, dtype=bool)
        first[vis.pvs(*regions[0])] = True
        assert np.array_equal(pvs([-10, -2, -10], [0, 2, -5]), first)  # a cell within the first region
        assert keep[tucked] and not first[tucked]

        without = bench.envmap_grid_memory(scene, lo, hi, 20.0, t_max, model, 64)
        culled = bench.envmap_grid_memory(scene, lo, hi, 20.0, t_max, model, 64, pvs=pvs)
        assert without["cells"] == 1 and without["memory_bytes"] > 0  # layers for the block
        assert culled["cells"] == 0 and culled["memory_bytes"] == 0.0  # it is hidden: no layer needed
        near, estimate = bench._envmap_near_field(elements, lo, lo + 20.0, t_max, model, 64, keep=keep)
        assert math.isinf(near) and estimate <= t_max
        assert bench.coarsest_envmap_cell(elements, lo, hi, t_max, model, 64, pvs=pvs) == (20.0, 0)
    finally:
        vis.release()
