"""A toy impostor technique defined outside ``farfield.core.techniques``: one fixed quad, one flat
grey page.  Importing this module registers it (``FARFIELD_TECHNIQUE_MODULES=toy_technique`` with
this folder on ``PYTHONPATH``), which is all that "one package + one registry line" asks of a
technique: the CLI, the service's job API and workers, ``GET /v1/techniques`` and the bundle, GLB
and evaluation code take it as they take farfield's own.

The quad stands across the part's bounding sphere, at its centre, facing the view cell's centre
(the reference viewpoint), and shows one ``shade`` of grey.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from farfield.core import __version__
from farfield.core.impostor.impostor import Impostor, QuadPayload
from farfield.core.options import check_options, option
from farfield.core.techniques import register
from farfield.core.techniques.base import CellCost, TechniqueDefinition
from farfield.core.techniques.part import evaluate_part, part_evaluation_text

NAME = "toy"
PAGE = 8  # texels per side of its one page


@dataclass(frozen=True)
class ToyOptions:
    """The toy's knobs: the output image it serves, and the grey it shows."""

    resolution: int = option(64, "output image pixels per side the impostor serves", ge=1, le=4096)
    fov_deg: float = option(45.0, "output field of view, degrees", gt=0.0, lt=180.0)
    shade: int = option(200, "the quad's grey, 0-255", ge=0, le=255)

    def __post_init__(self) -> None:
        check_options(self)


def check(cell, options, bounds, max_texels=None) -> CellCost:
    """Any cell can have the toy: one layer of one page."""
    return CellCost.of_layers(1, (PAGE, PAGE))


def bake(scene, cell, options, objects=None, progress=None) -> Impostor:
    part = scene.subset(objects) if objects else scene
    lo, hi = np.asarray(part.bounds, dtype=np.float64)
    centre, radius = 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo))
    eye = np.asarray(cell.center, dtype=np.float64)
    axis = (centre - eye) / np.linalg.norm(centre - eye)
    up = np.array([0.0, 1.0, 0.0]) if abs(axis[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(up, axis)
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    corners = centre + radius * np.array([[-1.0, 1.0], [1.0, 1.0], [1.0, -1.0], [-1.0, -1.0]]) @ np.stack(
        [u, v]
    )  # TL TR BR BL
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    page = np.full((PAGE, PAGE, 4), 255, np.uint8)
    page[..., :3] = options.shade
    if progress is not None:
        progress("quad", 1, 1)
    return Impostor(
        technique=NAME,
        viewcell=cell.to_dict(),
        reference_viewpoint=eye,
        resolution=options.resolution,
        fov_deg=options.fov_deg,
        pages=(page,),
        payload=QuadPayload(corners[None], uv[None], np.zeros(1, np.int64), np.zeros(1, np.int64)),
        stats={"layers": 1, "quads": 1, "texture_bytes": page.size, "geometry_bytes": 4 * 5 * 4},
        parameters={"shade": options.shade, "objects": list(part.names)},
        code_version=__version__,
    )


def summary(stats: dict) -> str:
    return f"toy: {stats['quads']} quad, {stats['texture_bytes']} texture bytes"


TECHNIQUE = register(
    TechniqueDefinition(
        name=NAME,
        scope="part",
        help="a toy: one grey quad across the part (a test of the technique registry)",
        Options=ToyOptions,
        payload_kind=QuadPayload.kind,
        check=check,
        bake=bake,
        summary=summary,
        evaluate=evaluate_part,
        evaluation_text=part_evaluation_text,
    )
)
