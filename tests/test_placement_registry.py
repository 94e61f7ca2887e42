"""The placement-algorithm registry (:data:`farfield.service.placement.ALGORITHMS`): what each algorithm
declares, how a stored job finds its algorithm, and that nothing outside the registry's package
branches on an algorithm's name or its index kind."""

from __future__ import annotations

import ast
import json
import re
from pathlib import Path
from types import SimpleNamespace

import pytest

from farfield.core.placement.hierarchy import PlacementError
from farfield.core.techniques import TECHNIQUES
from farfield.service.placement import (
    ALGORITHMS,
    DEFAULT_ALGORITHM,
    INDEX_KINDS,
    PLACEMENT_JOB,
    algorithm_of,
    get_algorithm,
    job_algorithm,
)
from farfield.service.placement.base import Algorithm
from farfield.service.placement.schema import PlacementSpec

ROOT = Path(__file__).resolve().parents[1]


def test_every_algorithm_declares_its_parts():
    assert list(ALGORITHMS) == ["frame-time", "primitive-budget"] and DEFAULT_ALGORITHM == "frame-time"
    for name, algorithm in ALGORITHMS.items():
        assert isinstance(algorithm, Algorithm) and algorithm.name == name and algorithm.help and algorithm.fields
        for method in (
            "params",
            "plan",
            "impostors",
            "check",
            "too_many_cells",
            "bake_cell",
            "write_index",
            "read_index",
            "placement_document",
            "lookup",
        ):
            assert getattr(type(algorithm), method) is not getattr(Algorithm, method), (
                f"{name} does not implement {method}"
            )
    assert set(INDEX_KINDS) == {"placement", "primitive-placement"}


def test_the_request_schema_is_made_of_every_algorithm_s_fields():
    own = [name for algorithm in ALGORITHMS.values() for name in algorithm.fields]
    assert len(own) == len(set(own))  # no field belongs to two algorithms
    assert list(PlacementSpec.model_fields) == ["view_space", "budget", "algorithm", *own]


def test_a_stored_job_finds_its_algorithm():
    assert algorithm_of({"placement": {}}).name == "frame-time"  # stored before there were two
    assert algorithm_of({"placement": {"algorithm": "primitive-budget"}}).name == "primitive-budget"
    assert job_algorithm(SimpleNamespace(job_type="layered", params={})) is None
    assert (
        job_algorithm(SimpleNamespace(job_type=PLACEMENT_JOB, params={"placement": {"algorithm": "primitive-budget"}}))
        is ALGORITHMS["primitive-budget"]
    )
    with pytest.raises(PlacementError, match="unknown placement algorithm"):
        get_algorithm("nope")


def test_an_image_cell_is_keyed_without_its_name():
    params = {"technique": "ldi", "image": "3-1", "params": {"resolution": 64}}
    kind, own = ALGORITHMS["primitive-budget"].cell_inputs(SimpleNamespace(params=params))
    assert (kind, own) == ("placement/ldi", {"technique": "ldi", "params": {"resolution": 64}})
    impostor = {"technique": "layered", "objects": ["a"], "params": {}, "cluster_triangles": 0}
    assert ALGORITHMS["frame-time"].cell_inputs(SimpleNamespace(params=impostor)) == ("placement/layered", impostor)


def test_no_algorithm_name_is_compared_outside_the_registry_s_package():
    # The frame-time index's kind, "placement", is also the job type and the request's field: left out.
    names = [n for n in (*ALGORITHMS, *INDEX_KINDS) if n != PLACEMENT_JOB]
    quoted = re.compile("|".join(rf"""["']{re.escape(n)}["']""" for n in names))
    found = []
    for folder in ("service", "api", "workers", "cli"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            if path.is_relative_to(ROOT / "service" / "placement"):
                continue
            text = path.read_text()
            documented = _docstring_lines(text)  # a docstring (its doctests included) compares nothing
            for number, line in enumerate(text.splitlines(), 1):
                if number in documented:
                    continue
                if quoted.search(line) and not line.lstrip().startswith(("#", '"', "'")):
                    found.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    for path in sorted((ROOT / "api" / "dashboard").glob("*.*")):
        if path.suffix not in (".js", ".html"):
            continue
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            code = line.split("//")[0] if path.suffix == ".js" else line
            if re.search("|".join(rf"""["'`]{re.escape(n)}["'`]""" for n in names), code):
                found.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    assert not found, "an algorithm's name (or index kind) outside service/placement:\n" + "\n".join(found)


def _docstring_lines(text: str) -> set[int]:
    """The line numbers of a module's docstrings (module, classes, functions)."""
    lines = set()
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if (
                isinstance(first, ast.Expr)
                and isinstance(first.value, ast.Constant)
                and isinstance(first.value.value, str)
            ):
                lines.update(range(first.lineno, first.end_lineno + 1))
    return lines


def test_every_algorithm_describes_itself():
    for name, algorithm in ALGORITHMS.items():
        described = algorithm.describe()
        assert json.loads(json.dumps(described)) == described
        assert described["name"] == name and described["help"] == algorithm.help
        assert described["technique"] is None or described["technique"] in TECHNIQUES
        assert described["index_kind"] == algorithm.index_kind and described["fields"] == list(algorithm.fields)
        assert algorithm.offline  # what farfield place does with it offline
    assert ALGORITHMS["primitive-budget"].describe()["technique"] == "ldi"
    assert ALGORITHMS["frame-time"].describe()["technique"] is None
