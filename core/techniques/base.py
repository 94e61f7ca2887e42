"""What a technique is: the one object each technique module exposes, and what every consumer asks of it.

A :class:`Technique` names its ``Options`` (a frozen dataclass of :func:`farfield.core.options.option`
fields), its scope (``part``: impostors of a scene's objects; ``scene``: the whole scene around a
view cell), the cheap lower bound of a job's cells' cost its request is refused by (``bound``), the
check that runs on a worker before a job's cells are baked (``check``: the layer planning that proves
every cell can have an impostor, returning the cell's :class:`CellCost` from that plan), the bake, the evaluation against the real geometry, and the
text the CLI prints of its statistics and its evaluation.  The registry
(:data:`farfield.core.techniques.TECHNIQUES`) holds one of each; the service, the CLI and the dashboard read
it instead of naming techniques.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol, runtime_checkable

import numpy as np

from farfield.core.errors import LayerPlanError
from farfield.core.impostor.impostor import Impostor
from farfield.core.options import IMAGE_FIELDS, describe_options, options_from_mapping
from farfield.core.scene import Scene
from farfield.core.viewcells import ViewCell

Progress = Callable[[str, int, int], None]  # (stage, done, total)
Scope = Literal["part", "scene"]

# Bytes of one recorded texel: RGBA8, as the layers are read back and the atlas pages stored.
TEXEL_BYTES = 4


@dataclass(frozen=True, slots=True)
class CellCost:
    """The work of baking one cell, from the plan its technique's check computes: ``layers`` images
    of ``texture`` texels each (an envmap's layers of every chosen cube face counted apart), ``texels``
    their sum and ``bytes`` their raw RGBA8 size.  An upper bound of what a bake records: layers
    with nothing in view and culled texels cost less.  Python integers, so no product overflows.
    ``complete`` is False when the check was given a budget and stopped planning past it: the
    cell needs at least this much.

    >>> cost = CellCost.of_layers(14, (16384, 8460))
    >>> cost.texels, cost.bytes, cost.describe()
    (1940520960, 7762083840, '14 layers of 16384x8460')
    >>> CellCost.of_layers(10**6, (65536, 65536)).texels  # no int64 wrap
    4294967296000000
    >>> CellCost.of_layers(1, (64, 64), complete=False).describe()
    'at least 1 layer of 64x64'
    """

    layers: int
    texture: tuple[int, int]  # texels along the image's x and y (each layer's)
    texels: int
    bytes: int
    complete: bool = True

    @classmethod
    def of_layers(cls, layers: int, texture, complete: bool = True) -> CellCost:
        """``layers`` images of ``texture`` (x, y) texels each."""
        x, y = (int(t) for t in texture)
        texels = int(layers) * x * y
        return cls(int(layers), (x, y), texels, texels * TEXEL_BYTES, complete)

    def describe(self) -> str:
        """``'14 layers of 16384x8460'`` (``'at least ...'`` when not ``complete``)."""
        layers = f"{self.layers} layer{'s' if self.layers != 1 else ''} of {self.texture[0]}x{self.texture[1]}"
        return layers if self.complete else f"at least {layers}"


@dataclass(frozen=True)
class Promise:
    """What a technique guarantees, in output pixels, from every viewpoint inside its view cell, at
    the error budget its impostor was baked for (``max_error_px``, 1 when it has none): what
    ``farfield techniques`` states and ``farfield evaluate --check`` checks.

    ``holes``: no hole pixel (geometry with no impostor pixel within ``budget - 1``); ``bloat``: no
    impostor pixel farther than the budget from the geometry.  A technique promising neither has
    nothing to check (``checked`` is false), as ``ldi``, whose splats serve a triangle budget.
    """

    text: str  # one sentence, for people
    holes: bool = False
    bloat: bool = False
    # outside(impostor) -> why its view cell lies where the promise does not hold (a sentence), or
    # None where it holds: e.g. octahedral's, only beyond an accuracy distance (bake warns, --check fails)
    outside: Callable[[Impostor], str | None] | None = field(default=None, compare=False)

    @property
    def checked(self) -> bool:
        """Whether ``evaluate --check`` has anything to check."""
        return self.holes or self.bloat

    def to_dict(self) -> dict:
        return {"text": self.text, "holes": self.holes, "bloat": self.bloat}


NO_PROMISE = Promise("none in pixels")


@runtime_checkable
class Technique(Protocol):
    """One impostor technique, as every consumer sees it: what the registry
    (:func:`farfield.core.techniques.register`) holds, whether defined in ``farfield.core.techniques``
    or in a module of its own (``FARFIELD_TECHNIQUE_MODULES``).  :class:`TechniqueDefinition` is the
    ready-made one, built from plain functions.  A consumer never compares a technique's name: it
    asks the technique (its ``scope``, ``estimate``, ``placement``, ``runtime``) or its impostor's payload
    (:mod:`farfield.core.impostor.impostor`)."""

    name: str
    scope: Scope  # "part": impostors of a scene's objects; "scene": the whole scene around a view cell
    help: str  # one line: what it makes, and the paper
    Options: type  # frozen dataclass; its fields' metadata give defaults, bounds and help
    payload_kind: (
        str  # the kind of payload its impostors carry (a key of farfield.core.impostor.impostor.PAYLOAD_KINDS)
    )
    # estimate(cell, options, part_bounds) -> (layers, texels per layer): the cheap figures a
    # placement ranks candidates by (seed 000 §5.8.1); raises where the cell can have no impostor.
    # None: the frame-time planner cannot place it.
    estimate: Callable[[ViewCell, Any, np.ndarray], tuple[float, float]] | None
    # Why the frame-time planner cannot place it and what places it instead (appended to the refusal);
    # "" when there is nothing to add.
    placement: str
    # runtime(scene, impostor) -> a cell renderer (``renderer``, ``reach``, ``near_triangles``,
    # ``quad_triangles``, ``release()``) for ``farfield walkthrough`` of an impostor database; None: no walk-through runtime.
    runtime: Callable[[Scene, Impostor], Any] | None
    # What it guarantees in pixels, and what ``farfield evaluate --check`` checks (NO_PROMISE: nothing).
    promise: Promise

    # bound(cells, options, part_bounds or None) -> (n,) int64: per cell a lower bound of the texels
    # its check finds, for many cells at once in well under a millisecond each: what ``POST /v1/jobs``
    # refuses by (service.jobs.admission); raises LayerPlanError/ViewCellError naming the cell.
    # None, or absent (an optional member: a technique of its own need not have it): nothing is
    # refused by cost in the request, the checks on a worker decide.

    def check(self, cell: ViewCell, options: Any, bounds: np.ndarray | None, max_texels: int | None = None) -> CellCost:
        """The cell's :class:`CellCost` from the planning a job runs for every cell on a worker before it bakes any (state ``admitting``);
        raises LayerPlanError/ViewCellError when the cell cannot have an impostor.  Given
        ``max_texels``, it may stop planning once past them (a cost that is not ``complete``)."""
        ...

    def bake(
        self,
        scene: Scene,
        cell: ViewCell,
        options: Any,
        objects: list[str] | None = None,
        progress: Progress | None = None,
    ) -> Impostor:
        """The impostor of ``objects`` of ``scene`` (a part technique; None: every object) or of the
        whole scene around ``cell`` (a scene technique)."""
        ...

    def summary(self, stats: dict) -> str:
        """The text the CLI prints after a bake, of the impostor's ``stats``."""
        ...

    def evaluate(self, scene: Scene, impostor: Impostor, random_count: int, outside_count: int, seed: int) -> Any:
        """The impostor against the real geometry: a result with ``to_dict()``."""
        ...

    def evaluation_text(self, result: Any, impostor: Impostor) -> str:
        """The table the CLI prints of an evaluation's ``result``."""
        ...

    def warm(self) -> float:
        """Compile (or load from numba's cache) the technique's numba kernels on tiny inputs, without
        GL; the seconds it took (0 when it has none).  A render worker and the test session call it
        for every registered technique (:func:`farfield.core.techniques.warm_techniques`)."""
        ...

    def options(
        self, values: Mapping[str, Any] | None = None, resolution: int | None = None, fov_deg: float | None = None
    ) -> Any:
        """Validated ``Options`` from a job's or the CLI's option values."""
        ...

    def options_of(self, params: Mapping[str, Any]) -> Any:
        """The ``Options`` of a job's stored parameters (``resolution``, ``fov_deg``, ``options``)."""
        ...

    def describe(self) -> dict:
        """JSON-ready: what ``GET /v1/techniques`` and ``farfield techniques`` show of it."""
        ...


@dataclass(frozen=True, slots=True)
class Instancing:
    """How a part technique's impostor of one instance is its prototype's, baked once in the
    prototype's local space and moved (:mod:`farfield.core.techniques.instances`)."""

    # local_cell(cell, matrix, options) -> the prototype's view cell whose impostor, moved by the
    # instance's (4, 4) matrix, serves ``cell``; None: this instance is baked as an object of its own
    local_cell: Callable[[ViewCell, np.ndarray, Any], ViewCell | None]
    # moved(impostor, matrix, objects, scene_hash) -> the prototype's impostor moved to the instance
    moved: Callable[[Impostor, np.ndarray, list[str] | None, str | None], Impostor]


@dataclass(frozen=True)
class TechniqueDefinition:
    """A :class:`Technique` made of plain functions: what each technique module exposes as ``TECHNIQUE``.

    >>> from farfield.core.techniques import get_technique
    >>> isinstance(get_technique("layered"), Technique)
    True
    """

    name: str
    scope: Scope
    help: str  # one line: what it makes, and the paper
    Options: type  # frozen dataclass; its fields' metadata give defaults, bounds and help
    payload_kind: str  # the kind of payload its impostors carry (farfield.core.impostor.impostor.PAYLOAD_KINDS)
    # check(cell, options, part_bounds or None, max_texels=None) -> the cell's CellCost (Technique.check)
    check: Callable[..., CellCost]
    # bake(scene, cell, options, objects or None, progress or None) -> Impostor
    bake: Callable[[Scene, ViewCell, Any, list[str] | None, Progress | None], Impostor]
    # summary(stats) -> the lines the CLI prints after a bake
    summary: Callable[[dict], str]
    # evaluate(scene, impostor, random_count, outside_count, seed) -> a result with to_dict()
    evaluate: Callable[[Scene, Impostor, int, int, int], Any]
    # evaluation_text(result, impostor) -> the table the CLI prints
    evaluation_text: Callable[[Any, Impostor], str]
    # estimate(cell, options, part_bounds) -> (layers, texels per layer) for the frame-time planner; None: not placeable there
    estimate: Callable[[ViewCell, Any, np.ndarray], tuple[float, float]] | None = None
    # bound(cells, options, part_bounds or None) -> (n,) int64 lower bounds of the cells' texels (Technique.bound); None: none
    bound: Callable[[list[ViewCell], Any, np.ndarray | None], np.ndarray] | None = None
    # what places it instead, when the frame-time planner cannot (Technique.placement)
    placement: str = ""
    # outside_estimate(options, part_bounds) -> an OutsideEstimate (farfield.core.techniques.octahedral.estimate):
    # for an impostor that serves every view beyond a distance from its part (octahedral), the frame-time
    # planner's one candidate per element (that outside-sphere cell, its exact memory and quads) instead
    # of shafts and boxes; None: shafts and boxes, ranked by ``estimate`` (optional in Technique: read
    # it with getattr(technique, "outside_estimate", None))
    outside_estimate: Callable[[Any, np.ndarray], Any] | None = None
    # runtime(scene, impostor) -> its walk-through cell renderer (Technique.runtime); None: none
    runtime: Callable[[Scene, Impostor], Any] | None = None
    # Its numba kernels' warm-ups: each compiles some kernels on tiny inputs and returns the seconds
    # it took (Technique.warm); shared ones (the slab recording's) appear in several techniques.
    kernels: tuple[Callable[[], float], ...] = ()
    # What it guarantees in pixels (Technique.promise)
    promise: Promise = NO_PROMISE
    # evaluate_lit(scene, impostor, random_count, seed) -> a LitEvaluation (farfield.core.quality.lit) of
    # what the impostor stands in for, from the views its own evaluation uses; None: evaluate_lit of its
    # part (the impostor's objects) from its cell's viewpoints, what a part technique stands in for
    evaluate_lit: Callable[[Scene, Impostor, int, int], Any] | None = None
    # How an instance's impostor is its prototype's, moved (farfield.core.techniques.instances); None:
    # every instance is baked as an object of its own
    instancing: Instancing | None = None

    def warm(self) -> float:
        """Compile its numba kernels (every function of ``kernels``); the seconds it took."""
        return float(sum(warm() for warm in self.kernels))

    def options(
        self, values: Mapping[str, Any] | None = None, resolution: int | None = None, fov_deg: float | None = None
    ) -> Any:
        """Validated ``Options`` from a job's or the CLI's option values (unknown names refused);
        ``resolution`` and ``fov_deg`` (``None``: the technique's default) come from the job's top level."""
        return technique_options(self, values, resolution, fov_deg)

    def options_of(self, params: Mapping[str, Any]) -> Any:
        """The ``Options`` of a job's stored parameters (``resolution``, ``fov_deg``, ``options``)."""
        return self.options(params.get("options"), params.get("resolution"), params.get("fov_deg"))

    def describe(self) -> dict:
        """JSON-ready (:func:`describe_technique`)."""
        return describe_technique(self)


def technique_options(
    technique: Technique,
    values: Mapping[str, Any] | None = None,
    resolution: int | None = None,
    fov_deg: float | None = None,
) -> Any:
    """Validated ``technique.Options`` from option values (unknown names refused), with the job's
    ``resolution`` and ``fov_deg`` (``None``: the technique's default): what :meth:`Technique.options` does."""
    given = dict(values or {})
    image = [name for name in IMAGE_FIELDS if name in given]
    if image:
        raise LayerPlanError(f"{image} are the job's own fields, not technique options")
    if resolution is not None:
        given["resolution"] = resolution
    if fov_deg is not None:
        given["fov_deg"] = fov_deg
    return options_from_mapping(technique.Options, given, f"{technique.name} options", unlisted=IMAGE_FIELDS)


def describe_technique(technique: Technique) -> dict:
    """JSON-ready: name, scope, help, the kind of payload it bakes (``payload``), whether the
    frame-time planner can place it (``placeable``), whether it has a walk-through runtime
    (``runtime``), what it guarantees (``promise``: :class:`Promise`), the image fields' defaults
    and every option.  A client (the dashboard) reads
    these fields instead of comparing technique names."""
    fields = describe_options(technique.Options)
    return {
        "name": technique.name,
        "scope": technique.scope,
        "help": technique.help,
        "payload": technique.payload_kind,
        "placeable": technique.estimate is not None,
        "runtime": technique.runtime is not None,
        "promise": technique.promise.to_dict(),
        "image": [f for f in fields if f["name"] in IMAGE_FIELDS],
        "options": [f for f in fields if f["name"] not in IMAGE_FIELDS],
    }
