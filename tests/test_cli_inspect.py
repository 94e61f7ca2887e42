"""``farfield inspect``: the table, ``--json``, and one-line errors through the real entry point."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import scenes  # tests/ is on sys.path under pytest's default (prepend) import mode
from click.testing import CliRunner

from farfield.cli.inspect_cmd import inspect
from farfield.cli.main import cli

REPO = Path(__file__).resolve().parents[1]


def _run(*args: str):
    """Invoke the real click group with only ``inspect`` registered (independent of other commands)."""
    cli.add_command(inspect)
    return CliRunner().invoke(cli, ["inspect", *args])


@pytest.mark.parametrize("real", scenes.REAL_SCENES, ids=lambda r: r.path.split("/")[-1])
@pytest.mark.slow
def test_table_lists_objects_triangles_and_colour_sources(real):
    result = _run(str(scenes.SHARED_SCENES / real.path))
    assert result.exit_code == 0, result.output
    scene = scenes.real_scene(real.path)
    assert f"triangles  {real.triangles:,}" in result.stdout
    assert scene.content_hash in result.stdout
    for obj in scene.objects:
        row = next(line for line in result.stdout.splitlines() if line.startswith(obj.name + " "))
        assert f"{obj.triangle_count:,}" in row and obj.colour_source in row
    assert "warnings   none" in result.stdout
    assert result.stderr == ""


@pytest.mark.parametrize("real", scenes.REAL_SCENES, ids=lambda r: r.path.split("/")[-1])
def test_json_is_the_scene_summary(real):
    result = _run(str(scenes.SHARED_SCENES / real.path), "--json")
    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout)
    assert summary == json.loads(json.dumps(scenes.real_scene(real.path).summary()))
    assert summary["triangle_count"] == real.triangles


def test_pine_json_marks_the_leaf_cards_alpha_cut():
    result = _run(str(scenes.SHARED_SCENES / "scrub_pine" / "scrubPine.obj"), "--json")
    cutoffs = {obj["name"]: obj["alpha_cutoff"] for obj in json.loads(result.stdout)["objects"]}
    assert cutoffs == {"SoftPine2": 0.5, "SoftPineBark": None}


def test_warnings_are_reported_in_the_output_not_on_stderr(tmp_path):
    path = scenes.write_obj(scenes.textured_quad(), tmp_path / "quad.obj", skip_textures=True)
    table = _run(str(path))
    assert table.exit_code == 0
    assert "warnings (1):" in table.stdout and "quad.png" in table.stdout
    assert table.stderr == ""
    summary = json.loads(_run(str(path), "--json").stdout)
    assert len(summary["warnings"]) == 1 and "quad.png" in summary["warnings"][0]


@pytest.mark.parametrize(
    ("name", "content", "exit_code", "message"),
    [
        ("absent.glb", None, 3, "absent.glb: no such file"),
        ("model.fbx", b"x", 2, "unsupported scene format '.fbx'"),
        pytest.param(
            "broken.glb",
            b"glTF" + bytes(40),
            2,
            "broken.glb: GLB version 0: farfield reads glTF 2.0",
            marks=pytest.mark.invalid_glb,
        ),
        pytest.param(
            "random.glb",
            b"MQYs" + bytes(96),
            2,
            "random.glb: not a GLB: a GLB starts with the bytes 'glTF', this file with b'MQYs'",
            marks=pytest.mark.invalid_glb,
        ),
        (
            "broken.ply",
            b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n",
            2,
            "broken.ply: the header declares 3 vertex elements but the file holds 1",
        ),
        ("nan.obj", scenes.bad_obj("nan").encode(), 2, "non-finite"),
    ],
    ids=["missing", "unsupported", "corrupt-glb", "not-a-glb", "corrupt-ply", "nan"],
)
@pytest.mark.slow
def test_errors_are_one_line_on_stderr_with_the_error_kind_exit_code(tmp_path, name, content, exit_code, message):
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    result = subprocess.run(
        [sys.executable, "-m", "farfield.cli.main", "inspect", str(path)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == exit_code
    assert result.stdout == ""
    assert "Traceback" not in result.stderr
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("farfield: error: ")
    assert message in lines[0]
