"""farfield's import graph: no cycle among ``farfield.*`` modules, and ``farfield.core`` builds on
none of the service's layers.

Every module's imports are read with :mod:`ast`, at every level: top-level imports and those inside
functions (a function-level import is how a cycle hides from Python's import machinery, so it counts
here as a top-level one would), ``if TYPE_CHECKING`` blocks included.  ``from package import name``
is an edge to ``package.name`` when that is a module, else to ``package``.  A package's ``__init__``
is its own node (``farfield.service.jobs``); importing a submodule is not counted as importing its
parents' ``__init__`` (Python runs those first, but they import their children, not the reverse,
unless they re-export them: then the explicit edges show it).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# The repository's top-level folders are farfield's subpackages (pyproject.toml's package-dir).
SUBPACKAGES = {
    "core": "farfield.core",
    "api": "farfield.api",
    "service": "farfield.service",
    "workers": "farfield.workers",
    "cli": "farfield.cli",
}
# What farfield.core must never import: the layers built on it.
ABOVE_CORE = ("farfield.service", "farfield.api", "farfield.workers", "farfield.cli")


def module_files() -> dict[str, Path]:
    """Every farfield module's dotted name and file (migration scripts are loaded by alembic, not imported: left out)."""
    found = {}
    for folder, package in SUBPACKAGES.items():
        for path in sorted((ROOT / folder).rglob("*.py")):
            parts = path.relative_to(ROOT / folder).with_suffix("").parts
            if "migrations" in parts or "__pycache__" in parts:
                continue
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join((package, *parts))] = path
    return found


def imports_of(name: str, path: Path, modules: set[str]) -> dict[str, int]:
    """The farfield modules ``name`` imports (top-level and function-level), each with the first line that does."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    edges: dict[str, int] = {}

    def add(target: str, line: int) -> None:
        if target.startswith("farfield.") and target != name:
            while (
                target not in modules and "." in target
            ):  # farfield.core.errors.LayerPlanError -> farfield.core.errors
                target = target.rpartition(".")[0]
            if target in modules and target != name:
                edges.setdefault(target, line)

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                add(alias.name, node.lineno)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join([*anchor, *([base] if base else [])])
            for alias in node.names:
                full = f"{base}.{alias.name}"
                add(full if full in modules else base, node.lineno)
    return edges


def import_graph() -> dict[str, dict[str, int]]:
    files = module_files()
    names = set(files)
    return {name: imports_of(name, path, names) for name, path in files.items()}


def cycles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm, iterative), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    found: list[list[str]] = []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, {})))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def describe(component: list[str], graph: dict[str, dict[str, int]], files: dict[str, Path]) -> str:
    """A cycle's modules and the import lines that tie them (file:line)."""
    members = set(component)
    lines = [f"cycle of {len(component)} modules: {', '.join(component)}"]
    for name in component:
        for target, line in sorted(graph[name].items()):
            if target in members:
                lines.append(f"    {files[name].relative_to(ROOT)}:{line}: {name} imports {target}")
    return "\n".join(lines)


def test_the_module_walk_finds_the_packages():
    files = module_files()
    for name in (
        "farfield.core",
        "farfield.core.techniques",
        "farfield.service",
        "farfield.service.db",
        "farfield.api.app",
        "farfield.workers.tasks",
        "farfield.cli.main",
    ):
        assert name in files, name


def test_the_walk_counts_function_level_and_relative_imports(tmp_path):
    source = tmp_path / "m.py"
    source.write_text(
        "import farfield.a\n\ndef f():\n    from farfield.b import thing\n    from .c import other\n    from . import d\n"
    )
    modules = {"farfield.pkg.m", "farfield.a", "farfield.b", "farfield.pkg.c", "farfield.pkg.d"}
    assert set(imports_of("farfield.pkg.m", source, modules)) == {
        "farfield.a",
        "farfield.b",
        "farfield.pkg.c",
        "farfield.pkg.d",
    }
    assert cycles({"a": {"b": 1}, "b": {"c": 1}, "c": {"a": 1}, "d": {"a": 1}}) == [["a", "b", "c"]]


def test_no_import_cycle_among_farfield_modules():
    graph, files = import_graph(), module_files()
    found = cycles(graph)
    assert not found, "import cycles among farfield modules (top-level and function-level imports):\n" + "\n".join(
        describe(c, graph, files) for c in found
    )


def test_core_imports_none_of_the_layers_above_it():
    graph, files = import_graph(), module_files()
    wrong = [
        f"{files[name].relative_to(ROOT)}:{line}: {name} imports {target}"
        for name, targets in sorted(graph.items()) if name == "farfield.core" or name.startswith("farfield.core.")
        for target, line in sorted(targets.items()) if target.startswith(ABOVE_CORE)
    ]  # fmt: skip
    assert not wrong, "farfield.core imports a layer above it:\n" + "\n".join(wrong)


def test_placement_builds_on_no_module_of_service_jobs():
    """service.jobs asks the placement registry for a placement job's part; the reverse would be a
    cycle between the two packages, even when no two modules form one."""
    graph, files = import_graph(), module_files()
    wrong = [
        f"{files[name].relative_to(ROOT)}:{line}: {name} imports {target}"
        for name, targets in sorted(graph.items()) if name.startswith("farfield.service.placement")
        for target, line in sorted(targets.items()) if target == "farfield.service.jobs" or target.startswith("farfield.service.jobs.")
    ]  # fmt: skip
    assert not wrong, "\n".join(wrong)
