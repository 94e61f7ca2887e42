"""The examples in farfield's docstrings, run against the installed package (``farfield.*``).

They are collected here rather than with pytest's ``--doctest-modules`` over the source folders:
that would import ``core/x.py`` a second time as a top-level ``core.x``, beside the package's
``farfield.core.x`` (two copies of each class, and numba caches written under a module name the
package does not have).
"""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest

SUBPACKAGES = ("farfield.core", "farfield.api", "farfield.service", "farfield.workers", "farfield.cli")
MODULES = sorted(
    {name for name in SUBPACKAGES}
    | {
        info.name
        for package in SUBPACKAGES
        for info in pkgutil.walk_packages(importlib.import_module(package).__path__, package + ".")
        if ".migrations" not in info.name
    }
)


def test_every_subpackage_is_found():
    assert {
        "farfield.core.techniques.layered",
        "farfield.core.exchange.gltf",
        "farfield.api.app",
        "farfield.workers.tasks",
    } <= set(MODULES)


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS, report=False)
    assert result.failed == 0, (
        f"{result.failed} of {result.attempted} examples in {name} failed (run python -m doctest -v on it)"
    )
