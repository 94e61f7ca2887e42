"""Scene loading against ``trimesh.load`` on the same file, side by side in one run (issue 29, item 1).

Usage: ``.venv/bin/python benchmarks/bench_loading.py [--atlas 4096] [--json OUT]``

Scenes: every scene of ``../shared/scenes`` and a generated textured OBJ like the one issue 29
measured (225,000 triangles of an icosphere in 45 material groups, every material naming one
``--atlas`` x ``--atlas`` PNG of seeded noise; written to a temporary folder).  Each load runs in
a fresh Python process that has already imported both libraries, so neither pays the other's
imports: the seconds of the load call (best of ``--repeats``) and the peak resident memory above
what the process held before it (``VmHWM`` reset through ``/proc/self/clear_refs``).
``farfield`` is ``farfield.core.exchange.load_scene`` (what ``farfield inspect``, the service and every
worker call); ``trimesh`` is ``trimesh.load(path, process=False)``, which parses but leaves
textures undecoded; ``+decode`` is that plus decoding each distinct image its materials hold to
RGBA once, the least a loader that renders must do.  The ratios are farfield over ``+decode``.
Goal (issue 29): within 2x in time and peak memory.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "scenes"
SCENE_FILES = {
    "damaged_helmet": "DamagedHelmet.glb",
    "duck": "duck.obj",
    "scrub_pine": "scrubPine.obj",
    "stanford_bunny": "bun_zipper.ply",
}

CHILD = r"""
import json, sys, time
import numpy as np
import trimesh
from farfield.core.exchange import load_scene
def status_kb(key):
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith(key))
def decoded(scene):
    # trimesh and the images its materials hold, each distinct image decoded to RGBA once
    images = {}
    for mesh in getattr(scene, "geometry", {"": scene}).values():
        material = getattr(getattr(mesh, "visual", None), "material", None)
        for image in (getattr(material, "image", None), getattr(material, "baseColorTexture", None)):
            if image is not None and id(image) not in images:
                images[id(image)] = np.asarray(image.convert("RGBA"))
    return scene, images
which, path, repeats = sys.argv[1], sys.argv[2], int(sys.argv[3])
load = {"farfield": load_scene, "trimesh": lambda p: trimesh.load(p, process=False),
        "trimesh+decode": lambda p: decoded(trimesh.load(p, process=False))}[which]
best, peak = float("inf"), 0
for _ in range(repeats):
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")  # reset the peak resident set (VmHWM) to the current one
    before = status_kb("VmRSS:")
    t = time.perf_counter()
    out = load(path)
    best = min(best, time.perf_counter() - t)
    peak = max(peak, status_kb("VmHWM:") - before)
    del out
print(json.dumps({"seconds": best, "peak_mib": peak / 1024}))
"""


def atlas_obj(folder: Path, size: int, triangles: int = 225_000, materials: int = 45) -> Path:
    """The generated OBJ (see the module docstring)."""
    import trimesh
    from PIL import Image

    rng = np.random.default_rng(0)
    Image.fromarray((rng.random((size, size, 3)) * 255).astype(np.uint8)).save(folder / "atlas.png")
    sphere = trimesh.creation.icosphere(subdivisions=7)
    faces, v = sphere.faces[:triangles] + 1, sphere.vertices
    uv = 0.5 * v[:, :2] + 0.5
    lines = ["mtllib atlas.mtl"]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in v]
    lines += [f"vt {a:.6f} {b:.6f}" for a, b in uv]
    for k, group in enumerate(np.array_split(np.arange(len(faces)), materials)):
        lines.append(f"usemtl mat{k}")
        lines += [f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in faces[group]]
    (folder / "atlas.mtl").write_text(
        "".join(f"newmtl mat{k}\nKd 1 1 1\nmap_Kd atlas.png\n\n" for k in range(materials))
    )
    path = folder / "atlas_45_materials.obj"
    path.write_text("\n".join(lines) + "\n")
    return path


def measure(which: str, path: Path, repeats: int) -> dict:
    code = CHILD
    done = subprocess.run(
        [sys.executable, "-c", code, which, str(path), str(repeats)], capture_output=True, text=True, check=False
    )
    if done.returncode != 0:
        return {"error": done.stderr.strip().splitlines()[-1] if done.stderr.strip() else f"exit {done.returncode}"}
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--atlas", type=int, default=4096, help="side of the generated OBJ's shared texture, texels")
    parser.add_argument("--repeats", type=int, default=2, help="loads per process (best time)")
    parser.add_argument("--json", default=None, help="write the rows here")
    args = parser.parse_args()
    rows = []
    kinds = ("farfield", "trimesh", "trimesh+decode")
    print(
        f"{'scene':<30} {'farfield s':>10} {'trimesh s':>9} {'+decode s':>9} {'ratio':>6} {'farfield MiB':>12} {'trimesh MiB':>11} {'+decode MiB':>11} {'ratio':>6}"
    )
    with tempfile.TemporaryDirectory(prefix="farfield-bench-loading-") as tmp:
        paths = {name: SHARED / name / file for name, file in SCENE_FILES.items() if (SHARED / name / file).exists()}
        paths[f"OBJ, 45 materials, {args.atlas}² atlas"] = atlas_obj(Path(tmp), args.atlas)
        for name, path in paths.items():
            got = {kind: measure(kind, path, args.repeats) for kind in kinds}
            rows.append({"scene": name, "file": path.name, **got})
            if any("error" in g for g in got.values()):
                print(f"{name:<30} " + "; ".join(f"{k}: {g.get('error', 'ok')}" for k, g in got.items()))
                continue
            ff, tm, td = (got[k] for k in kinds)
            t_ratio = ff["seconds"] / td["seconds"]
            m_ratio = ff["peak_mib"] / td["peak_mib"] if td["peak_mib"] >= 1 else float("nan")
            print(f"{name:<30} {ff['seconds']:>10.2f} {tm['seconds']:>9.2f} {td['seconds']:>9.2f} {t_ratio:>5.1f}x {ff['peak_mib']:>12.0f} "
                  f"{tm['peak_mib']:>11.0f} {td['peak_mib']:>11.0f} {m_ratio:>5.1f}x", flush=True)  # fmt: skip
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
