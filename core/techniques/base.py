"""What a technique is: the one object each technique module exposes, and what every consumer asks of it.

A :class:`Technique` names its ``Options`` (a frozen dataclass of :func:`farfield.core.options.option`
fields), its scope (``part``: impostors of a scene's objects; ``scene``: the whole scene around a
view cell), the check that runs when a job is created (``check``: the layer planning that proves
every cell can have an impostor, returning the cell's :class:`CellCost` from that plan), the bake, the evaluation against the real geometry, and the
text the CLI prints of its statistics and its evaluation.  The registry
(:data:`farfield.core.techniques.TECHNIQUES`) holds one of each; the service, the CLI and the dashboard read
it instead of naming techniques.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Literal

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
class Technique:
    """One impostor technique, as every consumer sees it."""

    name: str
    scope: Scope
    help: str  # one line: what it makes, and the paper
    Options: type  # frozen dataclass; its fields' metadata give defaults, bounds and help
    # check(cell, options, part_bounds or None, max_texels=None) -> the cell's CellCost; raises
    # LayerPlanError/ViewCellError when the cell cannot have an impostor (the planning a job runs for
    # every cell at creation, whose figures the job's cost admission sums).  Given max_texels, it may
    # stop planning once the cell is past them (a CellCost that is not complete).
    check: Callable[..., CellCost]
    # bake(scene, cell, options, objects or None, progress or None) -> Impostor
    bake: Callable[[Scene, ViewCell, Any, list[str] | None, Progress | None], Impostor]
    # summary(stats) -> the lines the CLI prints after a bake
    summary: Callable[[dict], str]
    # evaluate(scene, impostor, random_count, outside_count, seed) -> a result with to_dict()
    evaluate: Callable[[Scene, Impostor, int, int, int], Any]
    # evaluation_text(result, impostor) -> the table the CLI prints
    evaluation_text: Callable[[Any, Impostor], str]
    # estimate(cell, options, part_bounds) -> (layers, texels per layer): the cheap figures a
    # placement ranks candidates by (seed 000 §5.8.1); raises where the cell can have no impostor.
    # None: the technique cannot be placed (a scene-scope technique replaces everything around its cell).
    estimate: Callable[[ViewCell, Any, np.ndarray], tuple[float, float]] | None = None

    def options(self, values: Mapping[str, Any] | None = None, resolution: int | None = None, fov_deg: float | None = None) -> Any:
        """Validated ``Options`` from a job's or the CLI's option values (unknown names refused);
        ``resolution`` and ``fov_deg`` (``None``: the technique's default) come from the job's top level."""
        given = dict(values or {})
        image = [name for name in IMAGE_FIELDS if name in given]
        if image:
            raise LayerPlanError(f"{image} are the job's own fields, not technique options")
        if resolution is not None:
            given["resolution"] = resolution
        if fov_deg is not None:
            given["fov_deg"] = fov_deg
        return options_from_mapping(self.Options, given, f"{self.name} options", unlisted=IMAGE_FIELDS)

    def options_of(self, params: Mapping[str, Any]) -> Any:
        """The ``Options`` of a job's stored parameters (``resolution``, ``fov_deg``, ``options``)."""
        return self.options(params.get("options"), params.get("resolution"), params.get("fov_deg"))

    def describe(self) -> dict:
        """JSON-ready: name, scope, help, the image fields' defaults and every option."""
        fields = describe_options(self.Options)
        return {
            "name": self.name,
            "scope": self.scope,
            "help": self.help,
            "image": [f for f in fields if f["name"] in IMAGE_FIELDS],
            "options": [f for f in fields if f["name"] not in IMAGE_FIELDS],
        }
