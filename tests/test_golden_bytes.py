"""Golden bytes: every technique's bundle and each placement algorithm's result on fixed inputs, as
SHA-256 digests recorded before a structural change (``tests/fixtures/golden_bytes.json``).

A refactor that moves code must not move a byte.  The list changes only with a deliberate format
or algorithm change: rerun with ``FARFIELD_RECORD_GOLDEN=1`` and say why in the commit.  The
manifest is hashed without ``code_version`` (a version bump is not a format change); everything
else in a bundle (payload, atlas pages, GLB) is hashed as written.  The cases are computed in one
child process whose NumPy and OpenBLAS take the same kernels on every x86-64 machine
(``tests/golden_cases.py``: the digests depended on the CPU's AVX-512 before).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from golden_cases import PINNED

from farfield.core.techniques import TECHNIQUES

GOLDEN = Path(__file__).parent / "fixtures" / "golden_bytes.json"
RECORD = os.environ.get("FARFIELD_RECORD_GOLDEN") == "1"


@pytest.fixture(scope="module")
def computed(tmp_path_factory) -> dict:
    """{case key: digests}, from ``golden_cases.py`` run in a child process with :data:`PINNED`."""
    folder = tmp_path_factory.mktemp("golden")
    here = Path(__file__).parent
    env = {
        **os.environ,
        **PINNED,
        "PYTHONPATH": os.pathsep.join(filter(None, [str(here), os.environ.get("PYTHONPATH")])),
    }
    run = subprocess.run(
        [sys.executable, str(here / "golden_cases.py"), str(folder)], env=env, capture_output=True, text=True
    )
    assert run.returncode == 0, f"the golden cases failed:\n{run.stderr[-4000:]}"
    found = json.loads((folder / "digests.json").read_text())
    if "unavailable" in found:
        pytest.skip(found["unavailable"])
    return found


def _check(key: str, computed: dict) -> None:
    recorded = json.loads(GOLDEN.read_text()) if GOLDEN.exists() else {}
    if RECORD:
        recorded[key] = computed[key]
        GOLDEN.write_text(json.dumps(recorded, indent=1, sort_keys=True) + "\n")
        return
    assert key in recorded, f"no golden digests for {key!r}: record them with FARFIELD_RECORD_GOLDEN=1"
    assert computed[key] == recorded[key], f"{key}: the bytes changed"


@pytest.mark.parametrize("name", list(TECHNIQUES))
@pytest.mark.slow
def test_every_technique_bakes_the_recorded_bytes(name, computed):
    _check(f"technique/{name}", computed)


@pytest.mark.slow
def test_frame_time_placement_gives_the_recorded_bytes(computed):
    _check("placement/frame-time", computed)


@pytest.mark.slow
def test_primitive_budget_placement_gives_the_recorded_bytes(computed):
    _check("placement/primitive-budget", computed)
