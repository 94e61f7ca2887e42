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

``--many-objects 1000,4000,16000,64000`` measures instead OBJ files of that many small cubes (``o``,
eight ``v``, twelve ``f``; no ``vt`` or ``vn``), each loaded by ``load_scene`` in a fresh process,
``time.process_time()`` of the load: ``trimesh path`` with the faces given to trimesh as written
(farfield before ``core/exchange/obj_no_uv.py``; its reader is pieces x vertices there) and ``now``
(the corners paired ``i/i``: trimesh's linear branch), alternated, best of ``--repeats`` processes.
The node limit is raised past the largest count (the default admits 50,000 objects).
With ``--mixed`` every other cube's faces name a ``vt`` (``f a/1 b/2 c/3``; four ``vt`` lines
head the file) and the others none: ``now`` writes the latter's corners ``i/K``, K past the last
``vt`` (``obj_no_uv._past_the_uvs``), where before they kept trimesh's masks (the ``trimesh path``).

``--pieces 1x1000,100x71,1000x23,4000x11`` measures OBJ files of K objects, each an n x n grid of
vertices (2 (n-1)^2 triangles; no ``vt``/``vn``), three ways, each in a fresh process, alternated,
best of ``--repeats``: ``as written`` (trimesh's masks), ``paired`` (every corner ``i/i``),
``now`` (paired only where ``obj_no_uv.pays``), CPU seconds and peak resident MiB of the process.
The column pieces x vertices / faces is what ``obj_no_uv.PAIR_ABOVE`` is compared with.
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


CUBES_CHILD = r"""
import sys, time
import farfield.core.exchange.obj as obj
from farfield.core.exchange import load_scene
from farfield.core.exchange.limits import SceneLimits
if sys.argv[1] == "trimesh path":
    obj.paired_indices = lambda text: text  # the faces as written: what farfield gave trimesh before
start = time.process_time()
scene = load_scene(sys.argv[2], limits=SceneLimits(nodes=10**6))
print(time.process_time() - start, len(scene.objects), scene.content_hash)
"""


def cubes_obj(path: Path, count: int, mixed: bool = False) -> Path:
    """An OBJ of ``count`` unit-half cubes on a 100-wide grid, each ``o cubeK``, 8 ``v``, 12 ``f``;
    ``mixed``: every other cube's faces name ``vt`` 1, 2, 3 (four ``vt`` lines head the file)."""
    corners = [(x, y, z) for x in (0, 1) for y in (0, 1) for z in (0, 1)]
    triangles = [(0, 2, 3), (0, 3, 1), (4, 5, 7), (4, 7, 6), (0, 1, 5), (0, 5, 4),
                 (2, 6, 7), (2, 7, 3), (0, 4, 6), (0, 6, 2), (1, 3, 7), (1, 7, 5)]  # fmt: skip
    lines = ["vt 0 0", "vt 1 0", "vt 0 1", "vt 1 1"] if mixed else []
    for k in range(count):
        ox, oz = 2.0 * (k % 100), 2.0 * (k // 100)
        lines.append(f"o cube{k}")
        lines += [f"v {ox + 0.5 * x:g} {0.5 * y:g} {oz + 0.5 * z:g}" for x, y, z in corners]
        base = 8 * k + 1
        if mixed and k % 2:
            lines += [f"f {base + a}/1 {base + b}/2 {base + c}/3" for a, b, c in triangles]
        else:
            lines += [f"f {base + a} {base + b} {base + c}" for a, b, c in triangles]
    path.write_text("\n".join(lines) + "\n")
    return path


def many_objects(counts: list[int], repeats: int, mixed: bool = False) -> list[dict]:
    """The ``--many-objects`` table (module docstring)."""
    rows = []
    print(f"{'objects':>8} {'triangles':>10} {'trimesh path CPU s':>18} {'now CPU s':>9} {'ratio':>6}  same scene")
    with tempfile.TemporaryDirectory(prefix="farfield-bench-cubes-") as tmp:
        for count in counts:
            path = cubes_obj(Path(tmp) / f"cubes{count}.obj", count, mixed)
            best, hashes = {}, {}
            for _ in range(repeats):
                for which in ("trimesh path", "now"):
                    out = subprocess.run([sys.executable, "-c", CUBES_CHILD, which, str(path)],
                                         capture_output=True, text=True, check=True).stdout.split()  # fmt: skip
                    best[which] = min(best.get(which, float("inf")), float(out[0]))
                    hashes[which] = (int(out[1]), out[2])
            same = hashes["trimesh path"] == hashes["now"]
            rows.append({"objects": count, "triangles": 12 * count, **best, "same": same})
            print(f"{count:>8,} {12 * count:>10,} {best['trimesh path']:>18.2f} {best['now']:>9.2f} "
                  f"{best['trimesh path'] / best['now']:>5.1f}x  {'yes' if same else 'NO'}", flush=True)  # fmt: skip
    return rows


PIECES_CHILD = r"""
import resource, sys, time
import farfield.core.exchange.obj as obj
import farfield.core.exchange.obj_no_uv as no_uv
from farfield.core.exchange import load_scene
from farfield.core.exchange.limits import SceneLimits
if sys.argv[1] == "as written":
    obj.paired_indices = lambda text: text
elif sys.argv[1] == "paired":
    no_uv.PAIR_ABOVE = 0
start = time.process_time()
scene = load_scene(sys.argv[2], limits=SceneLimits(nodes=10**6))
print(time.process_time() - start, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, scene.content_hash)
"""


def grids_obj(path: Path, objects: int, n: int) -> Path:
    """``objects`` objects (``o partK``), each an n x n grid of vertices, two triangles a cell."""
    with path.open("w") as out:
        for k in range(objects):
            out.write(
                f"o part{k}\n" + "".join(f"v {i + n * k} {j} {(i * j) % 5}\n" for i in range(n) for j in range(n))
            )
            base = 1 + n * n * k
            out.write("".join(f"f {a} {a + n} {a + n + 1}\nf {a} {a + n + 1} {a + 1}\n"
                              for a in (base + i * n + j for i in range(n - 1) for j in range(n - 1))))  # fmt: skip
    return path


def pieces(shapes: list[tuple[int, int]], repeats: int) -> list[dict]:
    """The ``--pieces`` table (module docstring)."""
    rows, ways = [], ("as written", "paired", "now")
    print(
        f"{'objects':>8} {'triangles':>10} {'P*V/F':>7} "
        + " ".join(f"{w + ' s':>12} {w + ' MiB':>14}" for w in ways)
        + "  same"
    )
    with tempfile.TemporaryDirectory(prefix="farfield-bench-pieces-") as tmp:
        for objects, n in shapes:
            path = grids_obj(Path(tmp) / f"grids{objects}x{n}.obj", objects, n)
            faces, vertices = objects * 2 * (n - 1) ** 2, objects * n * n
            best, peak, hashes = {}, {}, set()
            for _ in range(repeats):
                for way in ways:
                    out = subprocess.run([sys.executable, "-c", PIECES_CHILD, way, str(path)],
                                         capture_output=True, text=True, check=True).stdout.split()  # fmt: skip
                    best[way] = min(best.get(way, float("inf")), float(out[0]))
                    peak[way] = min(peak.get(way, float("inf")), float(out[1]))
                    hashes.add(out[2])
            row = {
                "objects": objects,
                "triangles": faces,
                "pvf": objects * vertices / faces,
                "seconds": best,
                "peak_mib": peak,
            }
            rows.append({**row, "same": len(hashes) == 1})
            print(f"{objects:>8,} {faces:>10,} {row['pvf']:>7.0f} " + " ".join(f"{best[w]:>12.2f} {peak[w]:>14.0f}" for w in ways)
                  + f"  {'yes' if len(hashes) == 1 else 'NO'}", flush=True)  # fmt: skip
    return rows


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
    parser.add_argument(
        "--many-objects", default=None, help="comma-separated object counts: the many-object OBJ table instead"
    )
    parser.add_argument("--mixed", action="store_true", help="--many-objects: every other cube with vt")
    parser.add_argument(
        "--pieces", default=None, help="KxN,...: K objects of N x N vertices; the pairing table instead"
    )
    args = parser.parse_args()
    if args.pieces:
        rows = pieces([tuple(int(x) for x in shape.split("x")) for shape in args.pieces.split(",")], args.repeats)
        if args.json:
            Path(args.json).write_text(json.dumps(rows, indent=1))
        return
    if args.many_objects:
        rows = many_objects([int(n) for n in args.many_objects.split(",")], args.repeats, args.mixed)
        if args.json:
            Path(args.json).write_text(json.dumps(rows, indent=1))
        return
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
