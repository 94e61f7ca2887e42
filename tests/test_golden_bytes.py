"""Golden bytes: every technique's bundle and each placement algorithm's result on fixed inputs, as
SHA-256 digests recorded before a structural change (``tests/fixtures/golden_bytes.json``).

A refactor that moves code must not move a byte.  The list changes only with a deliberate format
or algorithm change: rerun with ``FARFIELD_RECORD_GOLDEN=1`` and say why in the commit.  The
manifest is hashed without ``code_version`` (a version bump is not a format change); everything
else in a bundle (payload, atlas pages, GLB) is hashed as written.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np
import pytest
from scenes import box_object, city

from farfield.core import procedural
from farfield.core.impostor.bundle import write_bundle
from farfield.core.placement.cost_model import primitive_model
from farfield.core.placement.planner import PlacementSettings, place
from farfield.core.placement.solution_grid import BudgetSettings, place_primitives
from farfield.core.scene import Scene
from farfield.core.techniques import TECHNIQUES
from farfield.core.viewcells import BoxCell

pytestmark = pytest.mark.filterwarnings("ignore::farfield.core.scene.SceneWarning")

GOLDEN = Path(__file__).parent / "fixtures" / "golden_bytes.json"
RECORD = os.environ.get("FARFIELD_RECORD_GOLDEN") == "1"


def _part_scene() -> Scene:
    return Scene.from_objects(
        [
            box_object("block", (-5.0, 0.0, -5.0), (5.0, 8.0, 5.0), (0.8, 0.35, 0.2, 1.0)),
            box_object("tower", (-1.5, 8.0, -1.5), (1.5, 14.0, 1.5), (0.3, 0.4, 0.85, 1.0)),
        ],
        source="golden-block",
    )


CASES = {
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


def _check(key: str, digests) -> None:
    recorded = json.loads(GOLDEN.read_text()) if GOLDEN.exists() else {}
    if RECORD:
        recorded[key] = digests
        GOLDEN.write_text(json.dumps(recorded, indent=1, sort_keys=True) + "\n")
        return
    assert key in recorded, f"no golden digests for {key!r}: record them with FARFIELD_RECORD_GOLDEN=1"
    assert digests == recorded[key], f"{key}: the bytes changed"


@pytest.mark.parametrize("name", list(TECHNIQUES))
@pytest.mark.slow
def test_every_technique_bakes_the_recorded_bytes(name, tmp_path):
    technique = TECHNIQUES[name]
    make, cell = CASES[technique.scope]
    impostor = technique.bake(make(), cell, technique.options(resolution=96), None, None)
    _check(f"technique/{name}", _bundle_digests(write_bundle(impostor, tmp_path / name).directory))


@pytest.mark.slow
def test_frame_time_placement_gives_the_recorded_bytes():
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
    _check("placement/frame-time", _sha(json.dumps(result.to_dict(), sort_keys=True).encode()))


@pytest.mark.slow
def test_primitive_budget_placement_gives_the_recorded_bytes():
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
    _check("placement/primitive-budget", _sha(json.dumps(document, sort_keys=True).encode()))
