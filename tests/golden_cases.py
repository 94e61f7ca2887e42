"""The cases of ``tests/test_golden_bytes.py``, computed in a process of their own whose numerical
libraries take the same code paths on every x86-64 machine (:data:`PINNED`).

NumPy picks its SIMD kernels (AVX2, AVX-512, ...) and OpenBLAS its kernels by the CPU it finds, and
their float64 results may differ in the last bit between those paths (a transcendental function's
rounding, a matrix product's order of additions): the digests recorded on an AVX2 machine failed on
an AVX-512 one (an EPYC) for five of eight cases, with the same packages.  The child process is
given NumPy's dispatch at the x86-64-v3 level (AVX2) and OpenBLAS's Haswell kernels, the machine the
digests were recorded on; both are read when the libraries load, hence the child.  The GL
(llvmpipe) and numba code paths gave the same bytes on both machines.

Run as a script (``python golden_cases.py FOLDER``), it writes every case's digests to
``FOLDER/digests.json`` (or why it cannot: a CPU without AVX2).
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

# NumPy's runtime dispatch capped at x86-64-v3 (AVX2, FMA3), OpenBLAS's kernels at Haswell's.
PINNED = {"NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR", "OPENBLAS_CORETYPE": "Haswell"}


def _part_scene():
    from scenes import box_object

    from farfield.core.scene import Scene

    return Scene.from_objects(
        [
            box_object("block", (-5.0, 0.0, -5.0), (5.0, 8.0, 5.0), (0.8, 0.35, 0.2, 1.0)),
            box_object("tower", (-1.5, 8.0, -1.5), (1.5, 14.0, 1.5), (0.3, 0.4, 0.85, 1.0)),
        ],
        source="golden-block",
    )


def cases() -> dict:
    """{scope: (scene maker, view cell)}: the technique cases' inputs."""
    import numpy as np
    from scenes import city

    from farfield.core.viewcells import BoxCell

    return {
        "part": (_part_scene, BoxCell(np.array([-2.0, 3.0, -27.0]), np.array([2.0, 7.0, -23.0]))),
        "scene": (lambda: city(100), BoxCell.from_center([170.0, 5.0, 170.0], 10.0)),
    }


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _bundle_digests(directory: Path) -> dict[str, str]:
    digests = {}
    for path in sorted(directory.iterdir()):
        data = path.read_bytes()
        if path.name == "manifest.json":
            manifest = json.loads(data)
            manifest.pop("code_version", None)
            data = json.dumps(manifest, sort_keys=True).encode()
        digests[path.name] = _sha(data)
    return digests


def technique_digests(name: str, folder: Path) -> dict[str, str]:
    """The bundle of technique ``name`` baked at 96 px for its case, file by file (the manifest
    without ``code_version``: a version bump is not a format change)."""
    from farfield.core.impostor.bundle import write_bundle
    from farfield.core.techniques import TECHNIQUES

    technique = TECHNIQUES[name]
    make, cell = cases()[technique.scope]
    impostor = technique.bake(make(), cell, technique.options(resolution=96), None, None)
    return _bundle_digests(write_bundle(impostor, folder / name).directory)


def frame_time_digest() -> str:
    from farfield.core import procedural
    from farfield.core.placement.cost_model import primitive_model
    from farfield.core.placement.planner import PlacementSettings, place

    scene = procedural.city(36, seed=5, detail=6)
    settings = PlacementSettings(
        t_max=0.5 * scene.triangle_count,
        model=primitive_model(),
        vdi_deg=45.0,
        options={"resolution": 128},
        cpv_size=20.0,
        cells="both",
    )
    result = place(scene, [20.0, 110.0, 20.0], [100.0, 115.0, 100.0], settings)
    assert result.summary["impostors"] > 0
    return _sha(json.dumps(result.to_dict(), sort_keys=True).encode())


def primitive_budget_digest() -> str:
    import numpy as np

    from farfield.core import procedural
    from farfield.core.placement.solution_grid import BudgetSettings, place_primitives

    scene = procedural.city(64, seed=1, detail=8)
    lo, hi = scene.bounds
    a, b = 0.75 * lo + 0.25 * hi, 0.25 * lo + 0.75 * hi
    grid = place_primitives(
        scene,
        np.array([a[0], 3.0, a[2]]),
        np.array([b[0], 7.0, b[2]]),
        BudgetSettings(primitives=0.3 * scene.triangle_count, max_level=3),
    )
    document = grid.to_dict()
    document.pop("seconds")  # run-dependent
    return _sha(json.dumps(document, sort_keys=True).encode())


def all_digests(folder: Path) -> dict:
    """{case key: digests} for every technique and both placement algorithms."""
    import warnings

    from farfield.core.scene import SceneWarning
    from farfield.core.techniques import TECHNIQUES

    warnings.simplefilter("ignore", SceneWarning)
    found = {f"technique/{name}": technique_digests(name, folder) for name in TECHNIQUES}
    found["placement/frame-time"] = frame_time_digest()
    found["placement/primitive-budget"] = primitive_budget_digest()
    return found


def _unpinned() -> str | None:
    """Why this process's kernels are not the recorded ones (None: they are): NumPy's dispatch must
    find AVX2 and FMA3 and nothing of AVX-512's, every OpenBLAS loaded must run Haswell's kernels."""
    import numpy as np
    import scipy.linalg  # noqa: F401 - loads SciPy's own OpenBLAS
    from threadpoolctl import threadpool_info

    core = getattr(np, "_core", None) or np.core  # NumPy 2 / 1.26
    features = dict(getattr(core._multiarray_umath, "__cpu_features__", {}))
    if not (features.get("AVX2") and features.get("FMA3")):
        return "this CPU lacks AVX2 and FMA3 (NumPy's x86-64-v3 kernels, which the digests were recorded with)"
    if features.get("X86_V4", features.get("AVX512_SKX")):
        return f"NumPy {np.__version__} did not take NPY_DISABLE_CPU_FEATURES={PINNED['NPY_DISABLE_CPU_FEATURES']!r}"
    kernels = {info.get("architecture") for info in threadpool_info() if info.get("internal_api") == "openblas"}
    if kernels - {"Haswell"}:
        return f"OpenBLAS runs {sorted(kernels)} kernels, not Haswell's, under OPENBLAS_CORETYPE"
    return None


if __name__ == "__main__":
    folder = Path(sys.argv[1])
    why = _unpinned()
    found = {"unavailable": why} if why else all_digests(folder)
    (folder / "digests.json").write_text(json.dumps(found))
