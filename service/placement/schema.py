"""The request's ``placement`` object (``POST /v1/jobs``): the view space, the budget, the algorithm and its knobs.

:class:`PlacementSpec` is made of the fields every placement reads (``view_space``, ``budget``,
``algorithm``) and each registered algorithm's own (:attr:`~farfield.service.placement.base.Algorithm.fields`),
in the registry's order; a request that gives another algorithm's field is refused by the admission
(:func:`farfield.service.placement.admission.placement_params`).
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, StrictFloat, StrictInt, create_model

from farfield.service.placement import ALGORITHMS, DEFAULT_ALGORITHM

Number = StrictFloat | StrictInt


class ViewSpaceSpec(BaseModel):
    """The box the viewer moves in (may be flat or a point)."""

    model_config = ConfigDict(extra="forbid")
    lo: tuple[Number, Number, Number]
    hi: tuple[Number, Number, Number]


# What the algorithms accept (service/placement/frame_time.py, primitive_budget.py), for the
# document: exactly one of frame_ms and primitives, a positive number; cost_model only with frame_ms.
_ONE_BUDGET = {
    "oneOf": [
        {"required": ["frame_ms"], "properties": {"frame_ms": {"type": "number", "exclusiveMinimum": 0}, "primitives": {"type": "null"}}},
        {"required": ["primitives"], "properties": {"primitives": {"type": "number", "exclusiveMinimum": 0}, "frame_ms": {"type": "null"}, "cost_model": {"type": "null"}}},
    ]
}  # fmt: skip


class BudgetSpec(BaseModel):
    """Every view within ``frame_ms`` by a cost model, or at most ``primitives`` triangles."""

    model_config = ConfigDict(extra="forbid", json_schema_extra=_ONE_BUDGET)
    frame_ms: Number | None = Field(None, description="t_max in milliseconds by the cost model")
    cost_model: str | dict | None = Field(
        None,
        description="with frame_ms: 'llvmpipe' (the builtin model, the default) or a cost model document (CostModel.to_dict(), farfield calibrate --out)",
    )
    primitives: Number | None = Field(None, description="or t_max as a triangle count (the primitive model)")


PlacementSpec = create_model(
    "PlacementSpec",
    __config__=ConfigDict(extra="forbid"),
    __doc__="A placement job's view space, budget and the planner's knobs (``farfield place --help``).",
    __module__=__name__,
    view_space=(ViewSpaceSpec, ...),
    budget=(BudgetSpec, ...),
    algorithm=(Literal[tuple(ALGORITHMS)], Field(DEFAULT_ALGORITHM, description=" or ".join(f"'{a.name}' ({a.help})" for a in ALGORITHMS.values()))),
    **{name: spec for algorithm in ALGORITHMS.values() for name, spec in algorithm.fields.items()},
)  # fmt: skip
