"""The depth channel on real scenes: how far each decoded texel lies from the source surface.

Usage: ``.venv/bin/python benchmarks/bench_depth.py [--resolution R] [--json]``

For each scene (the shared helmet and duck, the procedural house; the view cell of
``bench_lit.py``: a cube a fifth of the part's size, three part sizes in front of it along +z) a
layered bake with ``channels=albedo+normal+depth``; every kept texel's ray from the reference
viewpoint V through its point P on the quad is cast against the source's triangles
(Moller-Trumbore, numpy, no farfield renderer), and its first hit inside the quad's slab is the
truth.  Reported: the texels with such a hit (the others are rim texels kept by the conservative
rule, whose ray meets nothing in the slab), the error along the ray of the decoded point (median,
99th percentile, largest) against half a quantisation step, the share within it (plus 1e-6 of
the distance), and the flat quad's error (what a texel without depth shows).  Also the bake
seconds with and without depth.  The renderer is printed.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from farfield.core import procedural  # noqa: E402
from farfield.core.exchange import load_scene  # noqa: E402
from farfield.core.impostor.depth import quad_texels  # noqa: E402
from farfield.core.render.context import renderer_info  # noqa: E402
from farfield.core.sidedness import seen_from_cell  # noqa: E402
from farfield.core.techniques.layered import BakeOptions, bake_layered  # noqa: E402
from farfield.core.viewcells import BoxCell  # noqa: E402

SCENES = Path(__file__).resolve().parents[2] / "shared" / "scenes"


def scenes() -> dict:
    found = {
        "helmet": SCENES / "damaged_helmet" / "DamagedHelmet.glb",
        "duck": next(iter(sorted((SCENES / "duck").glob("*.obj"))), None),
    }
    out = {name: (lambda p=path: load_scene(p)) for name, path in found.items() if path is not None and path.is_file()}
    out["house"] = procedural.house
    return out


def first_hits(
    origin: np.ndarray, rays: np.ndarray, triangles: np.ndarray, lo: np.ndarray, hi: np.ndarray
) -> np.ndarray:
    """(n,) the smallest t in [lo, hi] at which origin + t rays (n, 3) meets a triangle (m, 3, 3); nan for none."""
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    e1, e2 = b - a, c - a
    best = np.full(rays.shape[0], np.nan)
    s = origin - a  # (m, 3)
    q = np.cross(s, e1)  # (m, 3)
    qe2 = np.einsum("mi,mi->m", q, e2)
    for start in range(0, rays.shape[0], 64):
        d = rays[start : start + 64]  # (k, 3)
        p = np.cross(d[:, None, :], e2[None])  # (k, m, 3)
        det = np.einsum("kmi,mi->km", p, e1)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            u = np.einsum("kmi,mi->km", p, s) * inv
            v = (d @ q.T) * inv
            t = qe2[None] * inv
        ok = (np.abs(det) > 1e-18) & (u >= 0) & (v >= 0) & (u + v <= 1)
        ok &= (t >= lo[start : start + 64, None]) & (t <= hi[start : start + 64, None])
        t = np.where(ok, t, np.inf).min(axis=1)
        best[start : start + 64] = np.where(np.isfinite(t), t, np.nan)
    return best


def measure(name: str, scene, resolution: int) -> dict:
    lo, hi = scene.bounds
    size = float(np.max(hi - lo))
    centre = 0.5 * (lo + hi)
    cell = BoxCell.from_center(centre + np.array([0.0, 0.0, 3.0 * size]), 0.2 * size)
    seconds = {}
    for channels in ("albedo+normal", "albedo+normal+depth"):
        start = time.perf_counter()
        impostor = bake_layered(scene, cell, BakeOptions(resolution=resolution, channels=channels))
        seconds[channels] = time.perf_counter() - start
    payload, viewpoint = impostor.payload, impostor.reference_viewpoint
    # The triangles the bake records: a one-sided triangle whose back faces the whole cell is not.
    triangles = np.concatenate([obj.vertices[obj.faces] for obj in seen_from_cell(scene.objects, cell)])
    rays, scale, s0, s1 = [], [], [], []
    for q in range(payload.count):
        rows, cols, on_quad = quad_texels(impostor, q)
        page = int(payload.page[q])
        keep = impostor.pages[page][rows, cols, 3] > 0
        code = impostor.channels["normal"][page][rows[keep], cols[keep], 3] / 255.0
        a, b = payload.depth_range[q]
        rays.append(on_quad[keep] - viewpoint)
        scale.append(a + code * (b - a))
        s0.append(np.full(code.size, a))
        s1.append(np.full(code.size, b))
    rays, scale, s0, s1 = (np.concatenate(x) for x in (rays, scale, s0, s1))
    truth = first_hits(viewpoint, rays, triangles, s0, s1)
    hit = np.isfinite(truth)
    length = np.linalg.norm(rays, axis=1)[hit]
    error = np.abs(scale[hit] - truth[hit]) * length
    half = (s1 - s0)[hit] / 510.0 * length
    flat = np.abs(1.0 - truth[hit]) * length
    return {
        "scene": name,
        "size": size,
        "texels": int(rays.shape[0]),
        "hit_share": float(hit.mean()),
        "error_median": float(np.median(error)),
        "error_p99": float(np.percentile(error, 99)),
        "error_max": float(error.max()),
        "half_step_median": float(np.median(half)),
        "within_half_step": float(np.mean(error <= half + 1e-6 * length)),
        "flat_median": float(np.median(flat)),
        "flat_p99": float(np.percentile(flat, 99)),
        "bake_seconds": seconds,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    rows = [measure(name, make(), args.resolution) for name, make in scenes().items()]
    if args.json:
        print(json.dumps({"renderer": renderer_info(), "rows": rows}, indent=1))
        return
    print(renderer_info())
    print(
        "scene   size  texels  hit   err med / p99 / max (size)      half step  within  flat med / p99   bake s (normal, +depth)"
    )
    for r in rows:
        s = r["size"]
        print(
            f"{r['scene']:7s} {s:5.2f} {r['texels']:6d} {r['hit_share']:5.3f}  "
            f"{r['error_median'] / s:.1e} / {r['error_p99'] / s:.1e} / {r['error_max'] / s:.1e}   "
            f"{r['half_step_median'] / s:.1e}    {r['within_half_step']:.3f}   "
            f"{r['flat_median'] / s:.1e} / {r['flat_p99'] / s:.1e}   "
            f"{r['bake_seconds']['albedo+normal']:.2f}, {r['bake_seconds']['albedo+normal+depth']:.2f}"
        )


if __name__ == "__main__":
    main()
