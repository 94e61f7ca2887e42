"""Instancing kept from the file (issue 56, item 1): the memory a loaded instanced scene holds and
what baking its instances costs with the prototype baked once against every instance baked alone.

Usage: ``.venv/bin/python benchmarks/bench_instancing.py [--counts 1000,10000] [--texture 1024]``

Scene: a GLB of one textured icosphere of 5,120 triangles (2,562 vertices with normals and uv,
one ``--texture`` x ``--texture`` RGBA texture) drawn ``count`` times by ``EXT_mesh_gpu_instancing``
(turned about z, uniformly scaled; loaded with a triangle limit above the default 50 million), written to a temporary folder with the tests' glTF builder.
Per count: the load's seconds and tracemalloc peak; the bytes the scene's objects hold, each array
counted once however many objects share it (``held``), and what copying every array per instance
would hold (``flat``); how many distinct texture arrays the objects hold.  Then the octahedral bake
(default options) of ``--baked`` instances two ways: each instance's part baked alone, and through
:class:`farfield.core.techniques.instances.InstanceBakes` (the prototype baked once, then moved).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # the tests' glTF builder


def instanced_file(path: Path, count: int, texture: int) -> Path:
    import trimesh
    from gltf_files import ELEMENT_ARRAY_BUFFER, UINT, GltfBuilder

    b = GltfBuilder()
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    v = np.asarray(sphere.vertices)
    uv = np.column_stack([0.5 + np.arctan2(v[:, 1], v[:, 0]) / (2 * np.pi), 0.5 + np.arcsin(v[:, 2]) / np.pi])
    rng = np.random.default_rng(1)
    image = rng.integers(0, 256, (texture, texture, 4), dtype=np.uint8)
    image[..., 3] = 255
    material = b.material(texture=b.texture(b.image(image)))
    attributes = {"POSITION": b.accessor(v, bounds=True), "NORMAL": b.accessor(np.asarray(sphere.vertex_normals)),
                  "TEXCOORD_0": b.accessor(uv)}  # fmt: skip
    indices = b.accessor(np.asarray(sphere.faces).reshape(-1), UINT, target=ELEMENT_ARRAY_BUFFER)
    mesh = b.mesh([{"attributes": attributes, "indices": indices, "material": material}], name="rock")
    k = np.arange(count, dtype=np.float64)
    side = int(np.ceil(np.sqrt(count)))
    translation = np.column_stack([5.0 * (k % side), 5.0 * (k // side), np.zeros(count)])
    rotation = np.column_stack([np.zeros(count), np.zeros(count), np.sin(0.15 * k), np.cos(0.15 * k)])
    scale = np.repeat((1.0 + 0.1 * (k % 5))[:, None], 3, axis=1)
    spec = {"TRANSLATION": b.accessor(translation), "ROTATION": b.accessor(rotation), "SCALE": b.accessor(scale)}
    b.node(name="rock", mesh=mesh, extensions={"EXT_mesh_gpu_instancing": {"attributes": spec}})
    b.used.add("EXT_mesh_gpu_instancing")
    return b.write(path)


def held_bytes(scene) -> tuple[int, int, int]:
    """(bytes of distinct arrays, bytes were every array per object, distinct texture arrays)."""
    seen: dict[int, int] = {}
    flat = 0
    textures = set()
    for obj in scene.objects:
        for name in ("vertices", "faces", "uv", "normals", "texture", "vertex_colors", "tangents", "material_uv"):
            array = getattr(obj, name)
            if array is not None:
                seen[id(array)] = array.nbytes
                flat += array.nbytes
        if obj.texture is not None:
            textures.add(id(obj.texture))
    return sum(seen.values()), flat, len(textures)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--counts", default="1000,10000")
    parser.add_argument("--texture", type=int, default=1024)
    parser.add_argument("--baked", type=int, default=4, help="instances baked both ways")
    args = parser.parse_args()
    from farfield.core.exchange import load_scene
    from farfield.core.exchange.limits import SceneLimits
    from farfield.core.techniques import get_technique
    from farfield.core.techniques.instances import InstanceBakes
    from farfield.core.viewcells import SphereOutsideCell

    print("machine: 2-core CPU, Mesa llvmpipe; one run each")
    print(
        f"{'instances':>9} {'triangles':>11} {'load s':>7} {'peak MiB':>9} {'held MiB':>9} {'flat MiB':>9} {'textures':>8}"
    )
    with tempfile.TemporaryDirectory() as tmp:
        scene = None
        for count in (int(c) for c in args.counts.split(",")):
            path = instanced_file(Path(tmp) / f"rocks{count}.glb", count, args.texture)
            tracemalloc.start()
            start = time.perf_counter()
            scene = load_scene(path, limits=SceneLimits(triangles=10**8))  # 10,000 x 5,120 is past the default
            seconds = time.perf_counter() - start
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
            held, flat, textures = held_bytes(scene)
            print(f"{count:>9} {scene.triangle_count:>11,} {seconds:>7.2f} {peak / 2**20:>9.0f} {held / 2**20:>9.0f} "
                  f"{flat / 2**20:>9.0f} {textures:>8}")  # fmt: skip
        octahedral = get_technique("octahedral")
        options = octahedral.options({})
        cells = []
        for obj in scene.objects[: args.baked]:
            m = obj.instance_matrix
            cells.append((obj.name, SphereOutsideCell(m[:3, 3], 3.0 * np.linalg.norm(m[:3, 0]))))
        start = time.perf_counter()
        for name, cell in cells:
            octahedral.bake(scene, cell, options, [name], None)
        alone = time.perf_counter() - start
        bakes = InstanceBakes(octahedral)
        start = time.perf_counter()
        for name, cell in cells:
            bakes.bake(scene, cell, options, [name])
        shared = time.perf_counter() - start
        print(
            f"\noctahedral (grid {options.grid}, {options.frame_resolution} texels a frame) of {len(cells)} instances:"
        )
        print(f"  each baked alone:        {alone:7.2f} s  ({len(cells)} bakes)")
        print(f"  prototype baked once:    {shared:7.2f} s  ({bakes.bakes} bake)")


if __name__ == "__main__":
    main()
