"""``farfield layers`` end to end through the installed command line (a real subprocess)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow  # ./run-tests --fast leaves it out (tests/conftest.py: the tiers)

SHARED_SCENES = Path(__file__).resolve().parents[1].parent / "shared" / "scenes"


def farfield(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "farfield.cli.main", *args], capture_output=True, text=True, timeout=120
    )


def test_envmap_json_reproduces_the_paper():
    out = farfield(
        "layers",
        "envmap",
        "--cell-size",
        "10",
        "--resolution",
        "512",
        "--layers",
        "64",
        "--alpha",
        "2.2661e-3",
        "--json",
    )
    assert out.returncode == 0, out.stderr
    data = json.loads(out.stdout)
    assert data["layers"] == 64 and len(data["distances"]) == 64 and len(data["borders"]) == 65
    assert 41.5 <= data["near_field"] <= 42.5
    assert data["borders"][-1] is None  # the outermost layer reaches infinity
    one = json.loads(
        farfield("layers", "envmap", "--cell-size", "10", "--layers", "1", "--alpha", "2.2661e-3", "--json").stdout
    )
    assert one["near_field"] == pytest.approx(1738.0, abs=1.0)


def test_envmap_near_field_round_trip():
    data = json.loads(
        farfield(
            "layers", "envmap", "--cell-size", "10", "--near-field", "42.5", "--alpha", "2.2661e-3", "--json"
        ).stdout
    )
    assert data["layers"] == 64 and data["near_field"] <= 42.5


def test_part_with_bounds_json():
    out = farfield(
        "layers",
        "part",
        "--bounds",
        "140,-15,-10,185,15,10",
        "--viewcell",
        "box-center:0,0,0,100",
        "--fov",
        "45",
        "--resolution",
        "512",
        "--pixel-model",
        "center",
        "--json",
    )
    assert out.returncode == 0, out.stderr
    data = json.loads(out.stdout)
    assert abs(data["layers"] - 110) <= 11  # seed 000 Table 4.1 at 90 m
    assert data["borders"][0] == 90.0 and data["borders"][-1] == 135.0
    assert len(data["depth_ranges"]) == data["layers"]


@pytest.mark.parametrize(
    "scene",
    ["stanford_bunny/bun_zipper.ply", "duck/duck.obj", "damaged_helmet/DamagedHelmet.glb", "scrub_pine/scrubPine.obj"],
)
def test_part_on_shared_scenes(scene):
    path = SHARED_SCENES / scene
    if not path.exists():
        pytest.skip(f"{path} not present (shared/scenes is beside the checkout in CI)")
    # A cubic cell ten scene-diameters in front of the model along -x.
    inspect = json.loads(farfield("inspect", str(path), "--json").stdout)
    (x0, y0, z0), (x1, y1, z1) = inspect["bounds"]
    size = max(x1 - x0, y1 - y0, z1 - z0)
    cx, cy, cz = x0 - 10 * size, (y0 + y1) / 2, (z0 + z1) / 2
    out = farfield("layers", "part", str(path), "--viewcell", f"box-center:{cx},{cy},{cz},{size}", "--json")
    assert out.returncode == 0, out.stderr
    data = json.loads(out.stdout)
    assert data["layers"] >= 1
    assert np.allclose(data["part_bounds"], inspect["bounds"])


def test_points_on_a_shared_scene_json():
    path = SHARED_SCENES / "scrub_pine/scrubPine.obj"
    if not path.exists():
        pytest.skip(f"{path} not present (shared/scenes is beside the checkout in CI)")
    # A 200-unit cell 2,000 units in front of the 700-unit pine.
    out = farfield(
        "layers", "points", str(path), "--viewcell", "box-center:0,450,2500,200", "--resolution", "512", "--json"
    )
    assert out.returncode == 0, out.stderr
    data = json.loads(out.stdout)
    assert len(data["cameras"]) == 3 and len(data["polygon"]) >= 3
    normal = np.array(data["plane"]["normal"])
    assert normal[2] < -0.99  # from the cell (z = 2500) towards the pine (z about 0)
    for camera in data["cameras"]:
        assert np.dot(camera["position"], normal) == pytest.approx(data["plane"]["offset"])
        assert 64 < camera["resolution"] < 4096
    assert data["factors"]["movement"] > 1.0 and data["factors"]["perspective"] == pytest.approx(1.3431, abs=1e-4)
    text = farfield("layers", "points", str(path), "--viewcell", "box-center:0,450,2500,200")
    assert text.returncode == 0 and "LDI pixels" in text.stdout


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["layers", "part", "--bounds", "1,0,0,2,1,1", "--viewcell", "box-center:0,0,0,10"], "touches or overlaps"),
        (
            ["layers", "part", "--bounds", "50,0,0,60,1,1", "--viewcell", "box-center:0,0,0,10", "--fov", "180"],
            "field of view",
        ),
        (
            ["layers", "part", "--bounds", "50,0,0,60,1,1", "--viewcell", "box-center:0,0,0,10", "--resolution", "0"],
            "resolution",
        ),
        (["layers", "part", "--bounds", "50,0,0", "--viewcell", "box-center:0,0,0,10"], "--bounds"),
        (["layers", "part", "--bounds", "50,0,0,60,1,1", "--viewcell", "box-center:0,0,0,-10"], "view cell"),
        (["layers", "envmap", "--cell-size", "10", "--layers", "4", "--alpha", "0"], "alpha"),
        (["layers", "envmap", "--cell-size", "10", "--near-field", "3"], "outside the view cell"),
        (["layers", "envmap", "--cell-size", "10"], "--layers or --near-field"),
        (["layers", "points", "--bounds", "0,0,0,1,1,1", "--viewcell", "box-center:0,0,0,1"], "reaches the view cell"),
        (["layers", "points", "--bounds", "5,0,0,6,1,1", "--viewcell", "shaft:0,0,0,1,0,0,30,1"], "box view cell"),
    ],
)
def test_bad_configurations_print_one_line_and_exit_non_zero(args, needle):
    out = farfield(*args)
    assert out.returncode != 0
    assert "Traceback" not in out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0]


def test_bake_refuses_an_out_folder_that_is_not_a_bundle_and_bad_numbers_are_errors_not_tracebacks(tmp_path):
    """``bake --out`` replaces its folder whole: pointed at the scene's own folder it deleted the
    scene, and ``--out .`` crashed.  A folder of other files, the current folder and an unwritable
    path are one-line errors, before the bake; an earlier bundle is replaced.  Then ``evaluate``'s
    negative counts and ``place``'s cost model of random bytes, which were tracebacks."""
    folder = tmp_path / "duck"
    shutil.copytree(SHARED_SCENES / "duck", folder)
    before = sorted(p.name for p in folder.iterdir())
    scene = str(folder / "duck.obj")
    cell = ("--viewcell", "box-center:-8,0.9,0,1", "--resolution", "32", "--quiet")
    refused = farfield("bake", scene, *cell, "--out", str(folder))
    assert refused.returncode == 4 and refused.stderr.strip().splitlines() == [
        f"farfield: error: {folder}: exists and is not a bundle (it holds duck.mtl, duck.obj, duckCM.png); "
        "the bundle would replace it whole: give a new or empty folder, or an earlier bundle's"
    ], refused.stderr
    assert sorted(p.name for p in folder.iterdir()) == before
    here = subprocess.run(
        [sys.executable, "-m", "farfield.cli.main", "bake", scene, *cell, "--out", "."],
        cwd=folder,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert (
        here.returncode == 4
        and "the current folder or one above it" in here.stderr
        and sorted(p.name for p in folder.iterdir()) == before
    )
    unwritable = farfield("bake", scene, *cell, "--out", "/proc/farfield-nope")
    assert (
        unwritable.returncode == 2
        and unwritable.stderr.strip()
        == "farfield: error: /proc/farfield-nope: cannot write a bundle there: No such file or directory"
    )
    for _ in range(2):  # new, then an earlier bundle replaced
        made = farfield("bake", scene, *cell, "--out", str(tmp_path / "bundle"))
        assert made.returncode == 0, made.stderr
    assert (tmp_path / "bundle" / "manifest.json").is_file()
    (tmp_path / "bundle" / "notes.txt").write_text("mine")  # a bundle holding a user's file is not replaced either
    kept = farfield("bake", scene, *cell, "--out", str(tmp_path / "bundle"))
    assert (
        kept.returncode == 4
        and "exists and holds files no bundle has (notes.txt)" in kept.stderr
        and (tmp_path / "bundle" / "notes.txt").exists()
    )
    for flag in ("--random", "--outside", "--seed"):  # were tracebacks (numpy's "negative dimensions")
        bad = farfield("evaluate", str(tmp_path / "bundle"), scene, flag, "-1")
        assert (
            bad.returncode == 2
            and f"Invalid value for '{flag}': -1 is not in the range x>=0" in bad.stderr
            and "Traceback" not in bad.stderr
        ), bad.stderr
    (tmp_path / "model.json").write_bytes(bytes(range(128, 256)))
    corrupt = farfield(
        "place", scene, "--view-space", "-8,0,0,-7,1,1", "--frame-ms", "1", "--cost-model", str(tmp_path / "model.json")
    )
    assert (
        corrupt.returncode == 2
        and corrupt.stderr.strip()
        == f"farfield: error: cost model {str(tmp_path / 'model.json')!r} is not JSON: not UTF-8 text"
    )


@pytest.mark.invalid_glb  # writes a truncated GLB on purpose
def test_messages_a_new_user_met_name_the_problem(tmp_path):
    """Each of these printed something about another thing (a BytesIO, a byte count the user did
    not give, 'not both' when neither was given, Python's warning format) or ignored an option."""
    duck = str(SHARED_SCENES / "duck" / "duck.obj")
    neither = farfield("layers", "part", "--viewcell", "box:0,0,0,1,1,1")
    assert (
        neither.returncode == 2
        and neither.stderr.strip() == "farfield: error: give either a SCENE or --bounds; neither was given"
    )
    mb = farfield("place", duck, "--view-space", "2,0,0,3,1,1", "--frame-ms", "5", "--max-impostor-mb", "-1")
    assert mb.returncode == 2 and mb.stderr.strip() == "farfield: error: --max-impostor-mb must be > 0, got -1.0"
    lone = tmp_path / "lone.obj"
    lone.write_text("mtllib nothere.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    baked = farfield(
        "bake",
        str(lone),
        "--viewcell",
        "box-center:0.3,0.3,5,0.5",
        "--resolution",
        "32",
        "--out",
        str(tmp_path / "b"),
        "--quiet",
    )
    assert baked.returncode == 0 and baked.stderr.strip() == (
        "farfield: warning: lone.obj: material library 'nothere.mtl' not found; objects use the default colour"
    ), baked.stderr
    codec = farfield(
        "glb", str(tmp_path / "b"), "--out", str(tmp_path / "x.glb"), "--textures", "png", "--codec", "uastc"
    )
    assert (
        codec.returncode == 2
        and "with --textures png there are none" in codec.stderr
        and not (tmp_path / "x.glb").exists()
    )
    glb = (tmp_path / "b" / "impostor.glb").read_bytes()
    (tmp_path / "cut.glb").write_bytes(glb[: len(glb) // 2])
    cut = farfield("glb", str(tmp_path / "cut.glb"), "--out", str(tmp_path / "y.glb"))
    assert (
        cut.returncode == 2
        and cut.stderr.strip()
        == f"farfield: error: GLB: truncated: its header says {len(glb):,} bytes, the file has {len(glb) // 2:,}"
    )
