"""A job request (``POST /v1/jobs``): :class:`JobSpec`, one impostor per view cell (a list or a :class:`GridSpec`) or a placement job.

A job names a technique of the registry (:data:`farfield.core.techniques.TECHNIQUES`: ``layered``,
``envmap``, ``tdm``, ...; the request's former field ``job_type`` is still accepted) and its options;
a placement job's ``placement`` object is :class:`~farfield.service.placement.schema.PlacementSpec`,
made of every placement algorithm's fields.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, StrictBool, StrictFloat, StrictInt, model_validator

from farfield.core.errors import ViewCellError
from farfield.core.options import options_json_schema
from farfield.core.techniques import DEFAULT_TECHNIQUE, TECHNIQUES
from farfield.core.viewcells import BoxCell, BoxCells, grid_box_cells, grid_boxes
from farfield.service.placement.schema import PlacementSpec
from farfield.service.settings import MAX_CELLS

__all__ = ["MAX_CELLS", "GridSpec", "JobSpec", "grid_cell_arrays", "grid_cells"]


def _whole_number(value):
    """A JSON integer: an int, or a number with no fractional part (JSON Schema's ``integer`` holds
    ``3.0``); never a boolean or a string (pydantic's lax mode took ``"1"`` and ``true`` as 1)."""
    if isinstance(value, float) and value.is_integer():
        return int(value)
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"must be a whole number, got {value!r}")
    return value


# A count of the document's ``{"type": "integer", "minimum": 1}``.
Count = Annotated[int, BeforeValidator(_whole_number)]


class GridSpec(BaseModel):
    """A grid of equal box view cells over a view-space box."""

    model_config = ConfigDict(extra="forbid")
    # Strict: a string or a boolean is not a number (pydantic would coerce "1" and true to 1).
    lo: tuple[StrictFloat | StrictInt, StrictFloat | StrictInt, StrictFloat | StrictInt]
    hi: tuple[StrictFloat | StrictInt, StrictFloat | StrictInt, StrictFloat | StrictInt]
    counts: tuple[Count, Count, Count] = Field(
        description=f"cells along x, y, z (each >= 1; {MAX_CELLS} in all at most)",
        # The document says what grid_cells refuses (ViewCellError, 422): a count below 1.
        json_schema_extra={"prefixItems": [{"type": "integer", "minimum": 1}] * 3},
    )


def _options_help() -> str:
    return (
        "technique parameters (GET /v1/techniques lists each technique's options with types, defaults, bounds and help); "
        + "; ".join(f"{t.name}: " + ", ".join(o["name"] for o in t.describe()["options"]) for t in TECHNIQUES.values())
    )


class JobSpec(BaseModel):
    """A job request (``POST /v1/jobs``): one impostor per view cell of a scene's part (or of the
    whole scene, for a technique of scope ``scene``)."""

    # The document says what _one_view_space checks: exactly one of the two view spaces, not
    # null, and not both 'technique' and its former name.
    model_config = ConfigDict(extra="forbid", json_schema_extra={"oneOf": [
        {"required": ["viewcells"], "properties": {"viewcells": {"type": "array"}}},
        {"required": ["grid"], "properties": {"grid": {"type": "object"}}},
        {"required": ["placement"], "properties": {"placement": {"type": "object"}}},
    ], "not": {"anyOf": [
        {"required": ["technique", "job_type"], "properties": {"technique": {"type": "string"}, "job_type": {"type": "string"}}},
        {"required": ["placement", "objects"], "properties": {"placement": {"type": "object"}, "objects": {"type": "array"}}},
    ]}})  # fmt: skip
    scene_id: str
    technique: Literal[tuple(TECHNIQUES)] | None = Field(  # type: ignore[valid-type]
        None,
        description="the impostor technique (default layered): "
        + "; ".join(f"{t.name}: {t.help}" for t in TECHNIQUES.values()),
    )
    job_type: Literal[tuple(TECHNIQUES)] | None = Field(  # type: ignore[valid-type]
        None,
        deprecated=True,
        description="the former name of 'technique', accepted until format 2 of the API; give one of them, not both",
    )
    viewcells: list[dict] | None = Field(
        None, description="explicit view cells, e.g. {'kind': 'box', 'lo': [..], 'hi': [..]}"
    )
    grid: GridSpec | None = Field(None, description="or a grid of box cells over a view-space box")
    placement: PlacementSpec | None = Field(
        None,
        description="or a placement job: a view space, a frame budget and the planner's knobs; a worker plans where impostors of "
        "'technique' (a part technique: layered, tdm) are needed, bakes them, checks and repairs (job state 'placing' while it plans)",
    )
    objects: list[str] | None = Field(
        None,
        min_length=1,
        description="the represented objects, at least one (default, left out: all; not for scene-scope techniques)",
    )
    resolution: StrictInt | None = Field(
        None, description="output image pixels per side (default: the technique's, 512)"
    )
    fov_deg: StrictFloat | None = Field(
        None, description="output field of view, degrees (default: the technique's: 45, envmap 90)"
    )
    options: dict = Field(
        default_factory=dict,
        description=_options_help(),
        json_schema_extra={
            "x-technique-options": {t.name: options_json_schema(t.Options) for t in TECHNIQUES.values()}
        },
    )
    evaluate: StrictBool = Field(
        True,
        description="evaluate each baked cell against the real geometry on the worker (techniques of one part: layered, tdm): "
        "hole pixels, pixels bloated beyond 1 px, colour error mean and 99th percentile, SSIM, from the reference viewpoint "
        "and three cell corners; the figures are in the cell's stats.evaluation, the time apart from the bake's. "
        "It changes no bundle; false skips it",
    )

    @model_validator(mode="after")
    def _one_view_space(self) -> JobSpec:
        if (self.viewcells is not None) + (self.grid is not None) + (self.placement is not None) != 1:
            raise ValueError("give exactly one of 'viewcells' (a list), 'grid' or 'placement'")
        if self.placement is not None and self.objects is not None:
            raise ValueError("a placement job chooses the objects its impostors replace: leave out 'objects'")
        former = self.__dict__.get("job_type")
        if self.technique is not None and former is not None:
            raise ValueError(
                f"'technique' ({self.technique}) and its former name 'job_type' ({former}) are both given; give one"
            )
        return self

    @property
    def technique_name(self) -> str:
        # Read through __dict__: the deprecated field's attribute access warns.
        return self.technique or self.__dict__.get("job_type") or DEFAULT_TECHNIQUE


def _check_counts(grid: GridSpec) -> None:
    # Counts are checked as Python integers first: numpy's int64 product of huge ones would wrap.
    if min(grid.counts) < 1:
        raise ViewCellError(f"grid counts must be >= 1, got {list(grid.counts)}")
    total = math.prod(grid.counts)
    if total > MAX_CELLS:
        raise ViewCellError(f"grid of {total} cells is over the limit of {MAX_CELLS}")


def grid_cells(grid: GridSpec) -> list[tuple[tuple[int, int, int], BoxCell]]:
    """The boxes of ``grid``, x fastest, with their (i, j, k)."""
    _check_counts(grid)
    return grid_boxes(grid.lo, grid.hi, grid.counts)


def grid_cell_arrays(grid: GridSpec) -> tuple[np.ndarray, BoxCells]:
    """:func:`grid_cells` as arrays ((n, 3) (i, j, k), :class:`~farfield.core.viewcells.BoxCells`), in numpy."""
    _check_counts(grid)
    return grid_box_cells(grid.lo, grid.hi, grid.counts)
