"""What every part of a placement's candidate step needs (:mod:`farfield.core.placement.candidate_parts`),
as one picklable value another process receives."""

from __future__ import annotations

import pickle
from dataclasses import dataclass

from farfield.core.placement.hierarchy import Hierarchy
from farfield.core.placement.view_space import ProblemViews


@dataclass(frozen=True, slots=True, eq=False)
class PartInputs:
    """What every part needs: the planner's settings (its techniques are rebuilt from them in each
    process: their estimates are closures), the hierarchy, the problem views, the nodes whose
    outside candidate is an instance's (:func:`~farfield.core.placement.planner.instance_sources`)
    and the frame's resolution."""

    settings: object  # farfield.core.placement.planner.PlacementSettings
    hierarchy: Hierarchy
    pv: ProblemViews
    shared: tuple
    resolution: int

    def dumps(self) -> bytes:
        return pickle.dumps(self, protocol=pickle.HIGHEST_PROTOCOL)

    @staticmethod
    def loads(data: bytes) -> PartInputs:
        return pickle.loads(data)  # noqa: S301 - our own planner's inputs, from our own blob store
