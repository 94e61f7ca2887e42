"""A forest of 10,000 instances of 5 tree prototypes, loaded from a GLB and baked as octahedral
impostors with instancing against without (issue 56, Measure).

Usage: ``.venv/bin/python benchmarks/bench_forest_bake.py [--trees 10000] [--prototypes 5] [--alone 50]
[--baseline PATH]``

Scene: :func:`farfield.core.procedural.tree_forest` (``--trees`` trees of ``--prototypes`` tree
meshes, 60-180 triangles each, turned about +y, scaled 0.8-1.2, on a 1 km ground quad), written
with the tests' glTF builder two ways: ``instanced``, one node per prototype drawing its trees by
``EXT_mesh_gpu_instancing`` (TRANSLATION, ROTATION, SCALE); ``nodes``, one node per tree sharing
its prototype's mesh.  COLOR_0 is the trees' vertex colours.  ``rocks``: ``--rocks`` instances of
benchmarks/bench_instancing.py's textured 5,120-triangle icosphere (1024 x 1024 texture), loaded
only.

Each measurement runs in a process of its own (``--phase``), so its peak resident memory
(``ru_maxrss``) is its own:

* load: ``load_scene`` of each file; seconds, peak RSS and the RSS the process had before it (after
  its imports), and the peak of a second load's allocations under ``tracemalloc``.
  ``--baseline PATH``: the same load with the ``farfield`` package found under ``PATH`` (a copy of
  an older commit, ``git archive``), in the same run, for a ratio.
* bake with instancing: every tree's octahedral impostor (default options; its cell the space
  outside a sphere of 3 times its bounding radius about its foot) through
  :class:`farfield.core.techniques.instances.InstanceBakes`: each prototype baked once in its own
  space, each tree its prototype's impostor moved.
* bake without: ``--alone`` trees (the first of each prototype in turn) each baked as a part of its
  own, and that time and those bytes times ``trees / alone`` as the 10,000's (extrapolated).

Bytes stored: the atlas pages' texels (colour pages and every channel's), each array counted once
however many impostors share it.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # the tests' glTF builder


def forest_files(folder: Path, trees: int, prototypes: int) -> dict[str, Path]:
    """The forest as ``instanced.glb`` (EXT_mesh_gpu_instancing) and ``nodes.glb`` (a node per tree)."""
    from gltf_files import ELEMENT_ARRAY_BUFFER, UINT, GltfBuilder
    from scipy.spatial.transform import Rotation

    from farfield.core.colour_space import srgb_to_linear
    from farfield.core.procedural import tree_forest

    scene = tree_forest(trees, prototypes)
    out = {}
    for kind in ("instanced", "nodes"):
        b = GltfBuilder()
        ground = scene.objects[0]
        material = b.material(color=tuple(ground.base_color), double_sided=True)
        indices = b.accessor(ground.faces.reshape(-1), UINT, target=ELEMENT_ARRAY_BUFFER)
        attributes = {"POSITION": b.accessor(ground.vertices, bounds=True)}
        b.node(name="ground", mesh=b.mesh([{"attributes": attributes, "indices": indices, "material": material}]))
        white = b.material(double_sided=True)
        for key, instances in scene.instances().items():
            (local,) = scene.prototype_objects(key)
            colours = local.vertex_colors / 255.0
            colours[:, :3] = srgb_to_linear(colours[:, :3])
            attributes = {"POSITION": b.accessor(local.vertices, bounds=True), "COLOR_0": b.accessor(colours)}
            indices = b.accessor(local.faces.reshape(-1), UINT, target=ELEMENT_ARRAY_BUFFER)
            name = local.name
            mesh = b.mesh([{"attributes": attributes, "indices": indices, "material": white}], name=name)
            by_name = {obj.name: obj for obj in scene.objects}
            matrices = np.stack([by_name[names[0]].instance_matrix for names in instances])
            scale = np.linalg.norm(matrices[:, :3, 0], axis=1)
            quaternions = Rotation.from_matrix(matrices[:, :3, :3] / scale[:, None, None]).as_quat()  # x, y, z, w
            if kind == "instanced":
                spec = {
                    "TRANSLATION": b.accessor(matrices[:, :3, 3]),
                    "ROTATION": b.accessor(quaternions),
                    "SCALE": b.accessor(np.repeat(scale[:, None], 3, axis=1)),
                }
                b.node(name=name, mesh=mesh, extensions={"EXT_mesh_gpu_instancing": {"attributes": spec}})
                b.used.add("EXT_mesh_gpu_instancing")
            else:
                for names, matrix, q, s in zip(instances, matrices, quaternions, scale):
                    b.node(name=names[0], mesh=mesh, translation=matrix[:3, 3].tolist(), rotation=q.tolist(),
                           scale=[float(s)] * 3)  # fmt: skip
        out[kind] = b.write(folder / f"{kind}.glb")
    return out


def _rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


def _trees(scene) -> list[tuple[str, object]]:
    """(name, outside-sphere cell) of every tree: 3 x its bounding radius about its foot."""
    from farfield.core.viewcells import SphereOutsideCell

    out = []
    for obj in scene.objects:
        if obj.prototype is None:
            continue
        m = obj.instance_matrix
        s = float(np.linalg.norm(m[:3, :3], axis=0).mean())  # the similarity's scale
        radius = float(np.linalg.norm(obj.local.vertices, axis=1).max())
        out.append((obj.name, SphereOutsideCell(m[:3, 3], 3.0 * s * radius)))
    return out


def _page_bytes(impostors) -> int:
    """Texels the impostors store, each page array counted once (shared pages once)."""
    seen: dict[int, int] = {}
    for impostor in impostors:
        for page in impostor.pages:
            seen[id(page)] = page.nbytes
        for pages in impostor.channels.values():
            for page in pages:
                seen[id(page)] = page.nbytes
    return sum(seen.values())


def phase(args) -> dict:
    """One measurement in this process (see the module docstring)."""
    from farfield.core.exchange import load_scene  # imported before the clock starts
    from farfield.core.exchange.limits import SceneLimits

    limits = SceneLimits(triangles=10**8)  # the rocks' 51 million are past the default
    before = _rss_mib()
    start = time.perf_counter()
    scene = load_scene(args.file, limits=limits)
    loaded = time.perf_counter() - start
    out = {"load_s": loaded, "rss_before_mib": before, "objects": scene.object_count}
    if args.phase == "load":
        out["peak_mib"] = _rss_mib()
        del scene
        tracemalloc.start()  # a second load, traced: the most its allocations held at once
        load_scene(args.file, limits=limits)
        out["traced_mib"] = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
        return out
    from farfield.core.techniques import get_technique
    from farfield.core.techniques.instances import InstanceBakes

    octahedral = get_technique("octahedral")
    options = octahedral.options({})
    trees = _trees(scene)
    out["trees"] = len(trees)
    out["options"] = {"grid": options.grid, "frame_resolution": options.frame_resolution}
    start = time.perf_counter()
    if args.phase == "shared":
        bakes = InstanceBakes(octahedral)
        impostors = [bakes.bake(scene, cell, options, [name]) for name, cell in trees]
        out["bakes"] = bakes.bakes
    else:  # alone: a sample of trees, each prototype's in turn
        by_prototype: dict[str, list] = {}
        for (name, cell), obj in zip(trees, (o for o in scene.objects if o.prototype is not None)):
            by_prototype.setdefault(obj.prototype, []).append((name, cell))
        order = [tree for group in zip(*by_prototype.values()) for tree in group][: args.alone]
        impostors = [octahedral.bake(scene, cell, options, [name], None) for name, cell in order]
        out["bakes"] = len(impostors)
    out["bake_s"] = time.perf_counter() - start
    out["page_bytes"] = _page_bytes(impostors)
    out["impostors"] = len(impostors)
    out["peak_mib"] = _rss_mib()
    return out


def run(file: Path, name: str, extra: list[str], pythonpath: str | None = None) -> dict:
    env = dict(os.environ)
    if pythonpath:
        env["PYTHONPATH"] = pythonpath
    cwd = "/" if pythonpath else str(ROOT)  # a baseline copy must not be shadowed by this checkout
    done = subprocess.run(
        [sys.executable, str(Path(__file__).resolve()), "--phase", name, "--file", str(file), *extra],
        capture_output=True,
        text=True,
        env=env,
        cwd=cwd,
        check=True,
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trees", type=int, default=10_000)
    parser.add_argument("--prototypes", type=int, default=5)
    parser.add_argument("--alone", type=int, default=50, help="trees baked alone (the rest extrapolated)")
    parser.add_argument("--baseline", default=None, help="a folder holding an older farfield package, to load with")
    parser.add_argument(
        "--rocks", type=int, default=10_000, help="instances of bench_instancing's icosphere to load too"
    )
    parser.add_argument("--phase", choices=("load", "shared", "alone"), help=argparse.SUPPRESS)
    parser.add_argument("--file", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.phase:
        print(json.dumps(phase(args)))
        return
    print(f"machine: 2-core CPU, Mesa llvmpipe; load average {os.getloadavg()[0]:.1f} at the start; one run each")
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        files = forest_files(Path(tmp), args.trees, args.prototypes)
        if args.rocks:
            from bench_instancing import instanced_file

            files["rocks"] = instanced_file(Path(tmp) / "rocks.glb", args.rocks, 1024)
        print(f"forest of {args.trees} trees, {args.prototypes} prototypes written in {time.perf_counter() - start:.1f} s: "
              + ", ".join(f"{k} {p.stat().st_size / 2**20:.1f} MiB" for k, p in files.items()))  # fmt: skip
        print(f"\n{'file':<10} {'code':<9} {'objects':>7} {'load s':>7} {'traced peak MiB':>15} {'RSS before MiB':>14} "
              f"{'peak RSS MiB':>12}")  # fmt: skip
        for kind, path in files.items():  # each load twice: timed, then traced
            rows = [("this", None)] + ([("baseline", args.baseline)] if args.baseline else [])
            for code, where in rows:
                r = run(path, "load", [], where)
                print(f"{kind:<10} {code:<9} {r['objects']:>7} {r['load_s']:>7.2f} {r['traced_mib']:>15.1f} {r['rss_before_mib']:>14.0f} "
                      f"{r['peak_mib']:>12.0f}")  # fmt: skip
        shared = run(files["instanced"], "shared", [])
        alone = run(files["instanced"], "alone", ["--alone", str(args.alone)])
    n = shared["trees"]
    factor = n / alone["impostors"]
    print(f"\noctahedral, default options (grid {shared['options']['grid']}, {shared['options']['frame_resolution']} "
          f"texels a frame), every one of the {n} trees of instanced.glb:")  # fmt: skip
    print(f"{'':<38} {'bakes':>6} {'bake s':>9} {'pages MiB':>10} {'peak RSS MiB':>12}")
    print(f"{'with instancing (InstanceBakes)':<38} {shared['bakes']:>6} {shared['bake_s']:>9.1f} "
          f"{shared['page_bytes'] / 2**20:>10.1f} {shared['peak_mib']:>12.0f}")  # fmt: skip
    label = f"without: {alone['impostors']} trees each alone"
    print(f"{label:<38} {alone['bakes']:>6} {alone['bake_s']:>9.1f} "
          f"{alone['page_bytes'] / 2**20:>10.1f} {alone['peak_mib']:>12.0f}")  # fmt: skip
    label = f"without: {n} trees (extrapolated x{factor:.0f})"
    print(f"{label:<38} {n:>6} {alone['bake_s'] * factor:>9.0f} "
          f"{alone['page_bytes'] * factor / 2**20:>10.0f} {'':>12}")  # fmt: skip
    print(f"\nratio without / with: bake time x{alone['bake_s'] * factor / shared['bake_s']:.0f}, "
          f"pages x{alone['page_bytes'] * factor / shared['page_bytes']:.0f}")  # fmt: skip


if __name__ == "__main__":
    main()
