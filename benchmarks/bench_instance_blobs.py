"""What the service stores for the cells of N instances of one mesh (issue 56, item 1), against
what it stored when each instance's bundle held its own copy of the prototype's pages and GLB,
and what serving an instance's GLB (written on request from the shared pages) costs.

Usage: ``.venv/bin/python benchmarks/bench_instance_blobs.py [--count 8] [--grid 13] [--frame 64]
[--channels albedo+normal+depth]``

Scene: the tests' instanced box (``tests/gltf_files.instanced_scene``: one textured box drawn
``--count`` times by ``EXT_mesh_gpu_instancing``, turned about z and uniformly scaled).  One
octahedral job per instance (its cell: outside twice the instance's radius), run as a worker runs
it (``run_cell``, a real SQLite database and blob folder).  ``stored``: the bytes under
``impostors/``; ``whole``: the prototype's bundle plus each instance's bundle written whole (what
the service stored before); then the seconds of ``GET .../impostor.glb`` for one instance
(:func:`farfield.service.jobs.instances.bundle_file`) against reading a stored GLB.
"""

from __future__ import annotations

import argparse
import io
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # the tests' glTF builder


def folder_bytes(root: Path) -> tuple[int, int]:
    """(all bytes, page and GLB bytes) of the files under ``root``."""
    files = [f for f in root.rglob("*") if f.is_file()]
    heavy = [f for f in files if f.suffix in (".png", ".glb")]
    return sum(f.stat().st_size for f in files), sum(f.stat().st_size for f in heavy)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=8)
    parser.add_argument("--grid", type=int, default=13)
    parser.add_argument("--frame", type=int, default=64)
    parser.add_argument("--channels", default="albedo")
    args = parser.parse_args()

    from gltf_files import instanced_scene

    from farfield.core.impostor.bundle import GLB_NAME, read_bundle, write_bundle
    from farfield.core.techniques import get_technique
    from farfield.core.techniques.instances import instance_part
    from farfield.service.blobs import LocalBlobStore
    from farfield.service.db import CellRow, Database
    from farfield.service.jobs.admission import create_job
    from farfield.service.jobs.instances import bundle_file, prototype_prefix
    from farfield.service.jobs.runner import run_cell
    from farfield.service.jobs.schema import JobSpec
    from farfield.service.keys import tenant_named
    from farfield.service.scenes import ingest_scene, load_stored_scene

    options = {"grid": args.grid, "frame_resolution": args.frame, "channels": args.channels}
    with tempfile.TemporaryDirectory(prefix="farfield-bench-") as tmp:
        tmp = Path(tmp)
        db = Database(f"sqlite:///{tmp / 'farfield.db'}")
        db.migrate()
        blobs = LocalBlobStore(tmp / "blobs")
        tenant = tenant_named(db, "bench").id
        path = instanced_scene(tmp / "boxes.glb", count=args.count)
        stored = ingest_scene(db, blobs, tenant, "boxes.glb", io.BytesIO(path.read_bytes()), limit=2**24)
        scene = load_stored_scene(blobs, stored)
        keys = []
        start = time.perf_counter()
        for i in range(args.count):
            m = next(o for o in scene.objects if o.name == f"box@{i}").instance_matrix
            cell = {
                "kind": "outside-sphere",
                "centre": m[:3, 3].tolist(),
                "radius": 2.0 * float(np.linalg.norm(m[:3, 0])),
            }
            spec = JobSpec(scene_id=stored.id, technique="octahedral", viewcells=[cell], objects=[f"box@{i}"],
                           options=options, resolution=512, evaluate=False)  # fmt: skip
            job = create_job(db, tenant, stored, spec)
            with db.session() as s:
                cell_id = s.query(CellRow.id).filter(CellRow.job_id == job.id).scalar()
            assert run_cell(db, blobs, cell_id, 3) == "done"
            with db.session() as s:
                keys.append(s.get(CellRow, cell_id).result_key)
        jobs = time.perf_counter() - start
        prototype = prototype_prefix(blobs, keys[0])
        now, now_heavy = folder_bytes(tmp / "blobs" / "impostors")

        technique = get_technique("octahedral")
        impostor = read_bundle(blobs.copy_to_directory(prototype, tmp / "prototype"))
        whole, whole_heavy = folder_bytes(blobs.path(prototype))
        for i in range(args.count):
            _, matrix, objects = instance_part(scene, [f"box@{i}"])
            moved = technique.instancing.moved(impostor, matrix, list(objects), scene.content_hash)
            write_bundle(moved, tmp / "whole" / f"{i}")
        more, more_heavy = folder_bytes(tmp / "whole")
        whole, whole_heavy = whole + more, whole_heavy + more_heavy

        def best(call, repeat: int = 5) -> float:
            times = []
            for _ in range(repeat):
                t = time.perf_counter()
                call()
                times.append(time.perf_counter() - t)
            return min(times)

        served = best(lambda: bundle_file(blobs, keys[-1], GLB_NAME))
        read = best(lambda: blobs.read_bytes(f"{prototype}/{GLB_NAME}"))
        pages = len(impostor.pages) + sum(len(p) for p in impostor.channels.values())
        print(f"{args.count} instances of the textured box, octahedral grid {args.grid}, {args.frame} px frames, "
              f"{args.channels} ({pages} pages); {args.count} jobs in {jobs:.1f} s")  # fmt: skip
        print("| layout | bytes under impostors/ | of which pages and GLBs |")
        print("|---|---:|---:|")
        print(f"| whole bundle per instance (before) | {whole:,} | {whole_heavy:,} |")
        print(f"| pages shared (now) | {now:,} | {now_heavy:,} |")
        print(
            f"GET impostor.glb of an instance: {served * 1000:.1f} ms (best of 5); a stored GLB read: {read * 1000:.2f} ms"
        )


if __name__ == "__main__":
    main()
