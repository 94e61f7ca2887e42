"""The layers of a plan as recorded and culled: each an RGBA image (H, W, 4) uint8, top row first,
with the (H, W) bool mask of the texels seen from somewhere in the view cell.

The one record -> cull loop of every layer-based technique (layered impostors, environment-map
faces, the voxel field of a textured depth mesh): gap-free recording of each layer (seed 000
§3.3.2, :func:`farfield.core.layering.recording.iter_layers`), an optional fill of the recorded image from the layer
before it (seed 002 §5.1 gap filling), then culling against the layers in front (seed 000 §3.4,
§3.4.1, :class:`farfield.core.layering.culling.LayerCuller`).  Layers stream one at a time, so memory grows with what
the caller keeps, not with layers x image.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from farfield.core.layering.culling import CullingMode, LayerCuller
from farfield.core.layering.recording import iter_layers
from farfield.core.scene import Scene, SceneObject
from farfield.core.stage_clock import StageClock

# fill(closer, image) -> (filled image, texels added): ``closer`` is the layer before as recorded.
Fill = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, int]]


@dataclass(frozen=True, slots=True)
class CulledLayer:
    """One recorded layer after culling."""

    index: int  # the layer's index in the plan
    image: np.ndarray  # (H, W, 4) uint8 (8 with the normal channel), top row first (after the fill, if any)
    kept: np.ndarray  # (H, W) bool: covered and not hidden from the whole view cell
    covered: int  # texels covered
    culled: int  # covered texels hidden from the whole view cell
    drawn: int  # triangles drawn to record it
    filled: int  # texels the fill added


def culled_layers(
    scene: Scene | Sequence[SceneObject],
    plan,
    culling: CullingMode,
    clock: StageClock,
    conservative: bool = True,
    fill: Fill | None = None,
    normals: bool = False,
    depth: bool = False,
    material: bool = False,
) -> Iterator[CulledLayer]:
    """Record, fill and cull ``plan``'s layers of ``scene`` in order, timing ``record``, ``gap_fill``
    (when ``fill`` is given) and ``cull`` on ``clock``.

    ``plan`` is anything :func:`farfield.core.layering.recording.iter_layers` records (a part's
    :class:`~farfield.core.layering.plan.LayerPlan` or an environment-map face); ``scene`` a scene
    or its objects as the view cell sees them (:func:`farfield.core.sidedness.seen_from_cell`).
    ``normals`` records the normal channel too: each image is then (H, W, 8), the world shading
    normals in its last four channels (:func:`~farfield.core.layering.recording.iter_layers`);
    ``depth`` writes the depth in their alpha; ``material`` (with ``normals``) the material channel after them, (H, W, 12), and the emissive
    channel where an object emits, (H, W, 16).
    """
    res_x, res_y = (int(r) for r in plan.texture_resolution)
    culler = LayerCuller((res_y, res_x), culling)
    layers = iter_layers(scene, plan, conservative, normals, depth=depth, material=material)
    previous = None
    while True:
        with clock("record"):
            step = next(layers, None)
        if step is None:
            return
        i, recorded, drawn = step
        image, filled = recorded[::-1], 0
        if fill is not None:
            with clock("gap_fill"):
                closer, previous = previous, image  # fill from the closer layer as recorded, not as filled
                if closer is not None and closer[..., 3].any():
                    image, filled = fill(closer, image)
        with clock("cull"):
            covered = image[..., 3] > 0
            hidden = culler.hidden(covered)
            kept = covered & ~hidden
        yield CulledLayer(int(i), image, kept, int(covered.sum()), int(hidden.sum()), int(drawn), int(filled))
