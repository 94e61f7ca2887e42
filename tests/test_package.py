"""The installable package: a built wheel adds one top-level import name, ``farfield``, ships its
shaders, migrations and dashboard, and works installed outside the checkout."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest
from scenes import box_object, write_scene

from farfield.core.scene import Scene

pytestmark = pytest.mark.slow  # ./run-tests --fast leaves it out (tests/conftest.py: the tiers)

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    # Built from a copy of the package's files, so the build leaves nothing in the checkout.
    source, out = tmp_path_factory.mktemp("source"), tmp_path_factory.mktemp("wheel")
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(ROOT / name, source / name)
    for folder in ("core", "api", "service", "workers", "cli"):
        shutil.copytree(
            ROOT / folder, source / folder, ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "*.nbi", "*.nbc")
        )
    built = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "--wheel-dir", str(out), str(source)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert built.returncode == 0, built.stderr[-3000:]
    (path,) = out.glob("farfield-*.whl")
    return path


def test_the_wheel_holds_one_package_and_its_data_files(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    assert {n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")} == {"farfield"}
    for data in ("farfield/core/render/shaders/slab.frag", "farfield/service/migrations/env.py",
                 "farfield/service/migrations/versions/0001_initial.py", "farfield/api/dashboard/index.html",
                 "farfield/api/dashboard/app.js", "farfield/core/techniques/octahedral/shaders/octahedral.frag"):  # fmt: skip
        assert data in names, data
    for init in sorted(
        p for folder in ("core", "api", "service", "workers", "cli") for p in (ROOT / folder).rglob("__init__.py")
    ):
        module = "farfield/" + init.relative_to(ROOT).as_posix()  # every package of the checkout is shipped
        assert module in names, f"{module}: add its package to pyproject.toml's [tool.setuptools] packages"
    entry_points = zipfile.ZipFile(wheel).read(next(n for n in names if n.endswith("entry_points.txt"))).decode()
    assert "farfield = farfield.cli.main:main" in entry_points


def test_the_installed_wheel_runs_outside_the_checkout(wheel, tmp_path):
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    python = venv / "bin" / "python"
    # The dependencies come from this interpreter's site-packages (a path entry, so its editable
    # install of the checkout is not activated); farfield itself only from the wheel.
    site = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        capture_output=True,
        text=True,
        check=True,
    )
    (Path(site.stdout.strip()) / "farfield-test-deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    installed = subprocess.run(
        [str(python), "-m", "pip", "install", "--quiet", "--no-deps", "--no-index", str(wheel)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert installed.returncode == 0, installed.stderr[-3000:]
    work = tmp_path / "elsewhere"
    work.mkdir()

    def run(*args):
        return subprocess.run(args, cwd=work, capture_output=True, text=True, timeout=600)

    where = run(str(python), "-c", "import farfield.core, sys; print(farfield.core.__file__)")
    assert where.returncode == 0 and str(venv) in where.stdout and str(ROOT) not in where.stdout, where
    for bare in ("core", "api", "service", "workers", "cli"):
        assert run(str(python), "-c", f"import {bare}").returncode != 0, bare  # no bare top-level names
    farfield = str(venv / "bin" / "farfield")
    helped = run(farfield, "--help")
    assert helped.returncode == 0 and "bake" in helped.stdout, helped.stderr
    listed = run(farfield, "techniques", "--json")
    assert listed.returncode == 0 and [t["name"] for t in json.loads(listed.stdout)["techniques"]] == [
        "layered",
        "envmap",
        "tdm",
        "points",
        "ldi",
        "octahedral",
    ]
    scene = Scene.from_objects(
        [box_object("block", (-5.0, 0.0, -5.0), (5.0, 8.0, 5.0), (0.8, 0.35, 0.2, 1.0))], source="package"
    )
    scene_file = write_scene(scene, work, "glb", "block")
    baked = run(
        farfield,
        "bake",
        str(scene_file),
        "--viewcell",
        "box:-2,3,-27,2,7,-23",
        "--resolution",
        "64",
        "--out",
        "bundle",
        "--json",
    )
    assert baked.returncode == 0, baked.stderr
    assert json.loads(baked.stdout)["stats"]["quads"] > 0 and (work / "bundle" / "impostor.glb").stat().st_size > 0
