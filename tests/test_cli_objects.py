"""``--objects`` that names no object is bad input (exit code 2), not the whole scene: ``--objects ""``
or ``--objects ,`` (a shell variable left empty) baked every object, silently (a real subprocess)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest


@pytest.mark.parametrize("objects", ["", ",", " , "])
@pytest.mark.parametrize(
    "command",
    [
        ["bake", "tri.obj", "--viewcell", "box:0,0,30,1,1,31", "--out", "out"],
        ["layers", "part", "tri.obj", "--viewcell", "box:0,0,30,1,1,31"],
        ["submit", "tri.obj", "--viewcell", "box:0,0,30,1,1,31"],
    ],
)
def test_objects_naming_no_object_is_a_usage_error(tmp_path, command, objects):
    (tmp_path / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    result = subprocess.run(
        [sys.executable, "-m", "farfield.cli.main", *command, "--objects", objects],
        capture_output=True, text=True, timeout=120, cwd=tmp_path,
        env={**os.environ, "FARFIELD_URL": "http://127.0.0.1:1", "FARFIELD_API_KEY": "x"},
    )  # fmt: skip
    assert result.returncode == 2, (result.returncode, result.stderr)
    assert "--objects" in result.stderr and "no object" in result.stderr, result.stderr
    assert result.stderr.count("\n") == 1  # one line
    assert not (tmp_path / "out").exists()
