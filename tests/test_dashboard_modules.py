"""The dashboard's JavaScript as ES modules (no browser, no service): every page loads one entry
module, every relative import names a module of the folder and a name it exports, the key and the
request helpers live once (``api.js``), and no module knows a technique or a placement algorithm
by its name (what a page knows of a technique comes from ``GET /v1/techniques``, of an algorithm
from ``GET /v1/placement-algorithms``; how the 3D view draws a cell, from its bundle's manifest)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from farfield.core.techniques import TECHNIQUES
from farfield.service.placement import ALGORITHMS

DASHBOARD = Path(__file__).resolve().parents[1] / "api" / "dashboard"
MODULES = sorted(DASHBOARD.glob("*.js"))
IMPORT = re.compile(r"^import\s*\{([^}]*)\}\s*from\s*\"\./([\w.-]+)\";", re.M)
EXPORT = re.compile(r"^export (?:async function|function|const|class) ([\w$]+)", re.M)


def _code(path: Path) -> str:
    return re.sub(r"//[^\n]*", "", path.read_text(encoding="utf-8"))


def test_each_page_loads_its_entry_module():
    index = (DASHBOARD / "index.html").read_text(encoding="utf-8")
    viewer = (DASHBOARD / "viewer.html").read_text(encoding="utf-8")
    assert re.findall(r"<script[^>]*src=\"([^\"]+)\"", index) == ["/dashboard/app.js"]
    assert '<script type="module" src="/dashboard/app.js"></script>' in index
    assert '<script type="module" src="/dashboard/viewer.js"></script>' in viewer


@pytest.mark.parametrize("module", MODULES, ids=lambda p: p.name)
def test_relative_imports_name_exported_names_of_the_folder(module):
    for names, target in IMPORT.findall(module.read_text(encoding="utf-8")):
        path = DASHBOARD / target
        assert path.is_file(), f"{module.name} imports ./{target}, which is not in api/dashboard"
        exported = set(EXPORT.findall(path.read_text(encoding="utf-8")))
        for name in (n.strip() for n in names.split(",")):
            name = name.split(" as ")[0].strip()
            assert name in exported, f"{module.name} imports {name} from ./{target}, which does not export it"


def test_the_key_and_the_requests_live_in_api_js():
    for module in MODULES:
        code = _code(module)
        if module.name == "api.js":
            assert "localStorage" in code and "fetch(" in code
            continue
        assert "localStorage" not in code, f"{module.name} reads the key itself: use api.js"
        assert "Authorization" not in code, f"{module.name} sends the key itself: use api.js"
        # the health check needs no key; every other call goes through api.js
        assert re.findall(r"\bfetch\(([^)]*)\)", code) in ([], ['"/v1/health"']), module.name


@pytest.mark.parametrize("module", MODULES, ids=lambda p: p.name)
def test_no_module_compares_a_technique_name(module):
    code = _code(module)
    for name in TECHNIQUES:
        assert not re.search(rf"[\"'`]{re.escape(name)}[\"'`]", code), f"{module.name} names the technique {name!r}"


@pytest.mark.parametrize("page", [*MODULES, DASHBOARD / "index.html", DASHBOARD / "viewer.html"], ids=lambda p: p.name)
def test_no_page_names_a_placement_algorithm(page):
    code = _code(page) if page.suffix == ".js" else page.read_text(encoding="utf-8")
    for name in ALGORITHMS:
        assert not re.search(rf"[\"'`]{re.escape(name)}[\"'`]", code), f"{page.name} names the algorithm {name!r}"


def test_the_octahedral_runtime_is_a_module_a_three_js_engine_can_copy():
    """``octahedral-impostor.js`` imports three.js alone (no dashboard module: a user copies it into
    an engine), exports what the docs show, and the 3D view draws a GLB's octahedral cards with it."""
    code = _code(DASHBOARD / "octahedral-impostor.js")
    assert re.findall(r"^import .*? from \"([^\"]+)\";", code, re.M) == ["three"]
    exported = set(EXPORT.findall(code))
    assert {"octahedralImpostors", "OctahedralImpostor", "readGrid", "blendFrames", "OCTAHEDRAL_EXTENSION"} <= exported
    viewer = _code(DASHBOARD / "viewer.js")
    assert (
        '{octahedralImpostors} from "./octahedral-impostor.js"' in viewer
        and "await octahedralImpostors(gltf)" in viewer
    )
