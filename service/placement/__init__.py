"""Placement jobs: scene + view space + budget -> the impostors a placement algorithm chooses, baked as cells, checked and repaired.

The registry of placement algorithms, by name, as :data:`farfield.core.techniques.TECHNIQUES` is of
techniques: each is an :class:`~farfield.service.placement.base.Algorithm` (one module each:
:mod:`.frame_time`, seed 000; :mod:`.primitive_budget`, seed 004) that owns its request fields, its
admission, planning, cell kind, check rounds, database index and the documents the API serves of
it.  Adding one means adding its module (an ``Algorithm`` named ``ALGORITHM``) and one line here.

The package's other modules are the same for every algorithm: :mod:`.schema` (the request's
``placement`` object, made of every algorithm's fields), :mod:`.admission` (a job from a request),
:mod:`.lease` (one worker at a time plans or checks a job), :mod:`.rounds` (plan, bake, check,
commit: the job's life) and :mod:`.documents` (the parsed indexes the API keeps, and what it serves).
"""

from __future__ import annotations

from farfield.core.placement.hierarchy import PlacementError
from farfield.service.placement import frame_time, primitive_budget
from farfield.service.placement.base import PLACEMENT_JOB, Algorithm

ALGORITHMS: dict[str, Algorithm] = {a.name: a for a in (frame_time.ALGORITHM, primitive_budget.ALGORITHM)}
DEFAULT_ALGORITHM = frame_time.NAME  # what a request that names none gets, and a job stored before there were two
INDEX_KINDS: dict[str, Algorithm] = {
    a.index_kind: a for a in ALGORITHMS.values()
}  # by the "kind" of the index each writes

__all__ = [
    "ALGORITHMS",
    "DEFAULT_ALGORITHM",
    "INDEX_KINDS",
    "PLACEMENT_JOB",
    "Algorithm",
    "algorithm_of",
    "get_algorithm",
    "job_algorithm",
]


def get_algorithm(name: str) -> Algorithm:
    """The registered algorithm ``name``, or PlacementError listing the known ones.

    >>> get_algorithm("primitive-budget").index_kind
    'primitive-placement'
    >>> get_algorithm("nope")
    Traceback (most recent call last):
    ...
    farfield.core.placement.hierarchy.PlacementError: unknown placement algorithm 'nope'; one of ['frame-time', 'primitive-budget']
    """
    try:
        return ALGORITHMS[name]
    except (KeyError, TypeError):
        raise PlacementError(f"unknown placement algorithm {name!r}; one of {list(ALGORITHMS)}") from None


def algorithm_of(params: dict) -> Algorithm:
    """A placement job's algorithm, from its stored params (a job stored before there were two: frame-time)."""
    return get_algorithm(params["placement"].get("algorithm", DEFAULT_ALGORITHM))


def job_algorithm(job) -> Algorithm | None:
    """The algorithm of a placement job (a JobRow); None for a job of view cells (grid or list)."""
    return algorithm_of(job.params) if job.job_type == PLACEMENT_JOB else None
