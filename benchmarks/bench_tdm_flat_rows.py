"""The flat rows merged before the simplification (``core/techniques/tdm/flat_rows.py``), on the scan's field.

Usage: ``.venv/bin/python benchmarks/bench_tdm_flat_rows.py EVERY [mesh|charts|all]``: records the field of
``bench_tdm_scale.py --scene scan`` once (kept in ``$TMPDIR/farfield_scan_field.pkl``), then its initial mesh with
``merge_every=EVERY`` (-1: not merged), the cascade at f = 2, the charts and the packing, printing CPU and wall
seconds, triangles, outcome counts, uncovered voxels and the page.  Run each setting in its own process.
"""

import math
import pickle
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from farfield.core.techniques.tdm.mask_atlas import pack_masks  # noqa: E402
from farfield.core.techniques.tdm.mesh import initial_mesh  # noqa: E402
from farfield.core.techniques.tdm.technique import TdmOptions, simplify_mesh, uncovered_voxels, warm_kernels  # noqa: E402
from farfield.core.techniques.tdm.texture import build_charts, chart_masks  # noqa: E402


def field_of_scan():
    path = Path(tempfile.gettempdir()) / "farfield_scan_field.pkl"
    if path.exists():
        return pickle.loads(path.read_bytes())
    from bench_tdm_scale import scene_and_cell

    from farfield.core.layering.plan import plan_layers
    from farfield.core.render.context import gl_context
    from farfield.core.sidedness import seen_from_cell
    from farfield.core.stage_clock import StageClock
    from farfield.core.techniques.part import layer_budget
    from farfield.core.techniques.tdm.voxel_field import record_voxel_field

    scene, cell = scene_and_cell("scan")
    o = TdmOptions()
    plan = plan_layers(cell, scene.bounds, math.radians(o.fov_deg), o.resolution, **layer_budget(o))
    with gl_context():
        field = record_voxel_field(seen_from_cell(scene.objects, cell), plan, o.culling, StageClock(()))
    path.write_bytes(pickle.dumps(field))
    return field


def main() -> None:
    every, stop = int(sys.argv[1]), sys.argv[2] if len(sys.argv) > 2 else "all"
    warm_kernels()
    field = field_of_scan()

    def clock():
        return time.process_time(), time.perf_counter()

    t = clock()
    mesh = initial_mesh(field, every)
    m = clock()
    print(f"every={every} mesh cpu {m[0] - t[0]:.1f} wall {m[1] - t[1]:.1f} triangles {mesh.triangle_count:,} "
          f"quads merged {mesh.stats['flat_quads_merged']:,} max valence {np.bincount(mesh.triangles.ravel()).max()}", flush=True)  # fmt: skip
    if stop == "mesh":
        return
    sil = field.silhouette
    tri, off, vox, counts = simplify_mesh(mesh, field, 2.0, sil)
    s = clock()
    print(f"simplify cpu {s[0] - m[0]:.1f} wall {s[1] - m[1]:.1f} kept {tri.shape[0]:,} attempts {sum(counts.values()):,} {counts}", flush=True)  # fmt: skip
    edges = np.sort(tri[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    use = np.unique(edges, axis=0, return_counts=True)[1]
    print("uncovered", uncovered_voxels(mesh.vertices, tri, off, vox, field, 2.0, sil), "edges>2", int((use > 2).sum()),
          "boundary", int((use == 1).sum()), flush=True)  # fmt: skip
    used, compact = np.unique(tri, return_inverse=True)
    charts = build_charts(mesh.vertices[used], compact.reshape(-1, 3), 1)
    masks = chart_masks(charts)
    c = clock()
    print(f"charts cpu {c[0] - s[0]:.1f} count {charts.count:,}", flush=True)
    if stop == "charts":
        return
    layout = pack_masks(masks, 2, 16384)
    p = clock()
    print(
        f"pack cpu {p[0] - c[0]:.1f} wall {p[1] - c[1]:.1f} area {layout.page_area:,} pages {layout.page_sizes.tolist()}"
    )


if __name__ == "__main__":
    main()
