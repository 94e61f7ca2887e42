"""The technique registry: every impostor technique farfield bakes, by name.

Adding a technique means a module whose object satisfies :class:`~farfield.core.techniques.base.Technique`
(e.g. a :class:`~farfield.core.techniques.base.TechniqueDefinition`) and one :func:`register` call:
a line in :data:`TECHNIQUES` below for farfield's own, or the module's own call for one defined
elsewhere (``FARFIELD_TECHNIQUE_MODULES`` names such modules to the CLI and the service, which
import them with :func:`load_technique_modules`).  The job API, the CLI (``farfield bake
--technique``, ``farfield techniques``), ``GET /v1/techniques`` and the dashboard's job form read
this table; the bundle, GLB, evaluation and runtimes ask the impostor's payload, not the name.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterable

from farfield.core.errors import UnknownTechniqueError
from farfield.core.techniques import envmap, layered, ldi, octahedral, points, tdm
from farfield.core.techniques.base import Technique, TechniqueDefinition

__all__ = [
    "DEFAULT_TECHNIQUE",
    "TECHNIQUES",
    "Technique",
    "TechniqueDefinition",
    "get_technique",
    "load_technique_modules",
    "register",
    "warm_techniques",
]

TECHNIQUES: dict[str, Technique] = {}
DEFAULT_TECHNIQUE = "layered"  # what a job or a bake that names none gets


def register(technique: Technique) -> Technique:
    """Add ``technique`` to :data:`TECHNIQUES` under its name; returns it.  Refuses (ValueError) an
    object that is not a :class:`Technique`, a name already registered, or a payload kind the bundle
    format does not know (:data:`farfield.core.impostor.impostor.PAYLOAD_KINDS`).

    >>> register(get_technique("tdm"))
    Traceback (most recent call last):
    ...
    ValueError: a technique named 'tdm' is registered already
    """
    from farfield.core.impostor.impostor import PAYLOAD_KINDS

    if not isinstance(technique, Technique):
        missing = (
            [m for m in Technique.__protocol_attrs__ if not hasattr(technique, m)]
            if hasattr(Technique, "__protocol_attrs__")
            else []
        )
        raise ValueError(f"{technique!r} is not a technique" + (f" (it has no {missing})" if missing else ""))
    if not isinstance(technique.name, str) or not technique.name:
        raise ValueError(f"a technique needs a name, got {technique.name!r}")
    if technique.name in TECHNIQUES:
        raise ValueError(f"a technique named {technique.name!r} is registered already")
    if technique.payload_kind not in PAYLOAD_KINDS:
        raise ValueError(
            f"technique {technique.name!r}: unknown payload kind {technique.payload_kind!r}; one of {sorted(PAYLOAD_KINDS)}"
        )
    TECHNIQUES[technique.name] = technique
    return technique


for _technique in (layered.TECHNIQUE, envmap.TECHNIQUE, tdm.TECHNIQUE, points.TECHNIQUE, ldi.TECHNIQUE):
    register(_technique)
register(octahedral.TECHNIQUE)


def get_technique(name: str) -> Technique:
    """The registered technique ``name``, or UnknownTechniqueError listing the known ones.

    >>> get_technique("tdm").scope
    'part'
    >>> get_technique("nope")
    Traceback (most recent call last):
    ...
    farfield.core.errors.UnknownTechniqueError: unknown technique 'nope'; one of ['layered', 'envmap', 'tdm', 'points', 'ldi', 'octahedral']
    """
    try:
        return TECHNIQUES[name]
    except (KeyError, TypeError):
        raise UnknownTechniqueError(f"unknown technique {name!r}; one of {list(TECHNIQUES)}") from None


def load_technique_modules(names: Iterable[str]) -> list[str]:
    """Import each module of ``names`` (importable module names; blanks skipped) whose import
    registers techniques (:func:`register`); returns the names imported.  A module imported before
    is not run again, so calling this twice registers nothing twice.  The edges call it with the
    setting ``FARFIELD_TECHNIQUE_MODULES`` before they read the registry; ``core`` reads no setting.

    Raises ServiceConfigError naming a module that cannot be imported."""
    from farfield.core.errors import ServiceConfigError

    loaded = []
    for name in names:
        name = name.strip()
        if not name:
            continue
        try:
            importlib.import_module(name)
        except ImportError as error:
            raise ServiceConfigError(f"technique module {name!r} cannot be imported: {error}") from error
        loaded.append(name)
    return loaded


def warm_techniques() -> float:
    """Compile every registered technique's numba kernels (:meth:`Technique.warm`), each shared
    kernel set once; the seconds it took.  What a render worker runs when it starts and the test
    session before its first test."""
    seconds, done = 0.0, set()
    for technique in TECHNIQUES.values():
        kernels = getattr(technique, "kernels", None)  # a TechniqueDefinition's warm-ups: shared ones run once
        if kernels is None:
            seconds += float(technique.warm())
            continue
        for warm in kernels:
            if warm not in done:
                done.add(warm)
                seconds += float(warm())
    return seconds
