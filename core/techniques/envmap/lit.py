"""The lit evaluation of an environment-map impostor: what it stands in for, the scene beyond its
cell's near field, lit as the geometry would be (:mod:`farfield.core.quality.lit`).

An envmap impostor is the far field of a whole scene around a cubic view cell; the runtime draws
the near field as geometry in front of it (seed 002 §3, :mod:`farfield.core.techniques.envmap.runtime`).
So the lit evaluation looks as the unlit one does (:func:`~farfield.core.techniques.envmap.runtime.evaluate_envmap`):
from the cell's corners, centre and seeded random points, along every recorded face axis and the
diagonals between neighbouring ones, at the impostor's field of view, and it compares only the
samples that the near field does not cover.  The near field, drawn alone and clipped to its cube
as the runtime draws it, is the mask: from inside the cube it hides whatever lies beyond, so the
samples it covers are the same geometry in the scene and in the runtime, and counting them would
only dilute the figures (a normal error median of 0 over a street's near field says nothing of
the layers).  Faces left without layers belong to the near field, so their views are masked too.
"""

from __future__ import annotations

from contextlib import ExitStack

import numpy as np

from farfield.core.impostor.impostor import Impostor
from farfield.core.quality.lit import LitEvaluation, evaluate_lit_views, impostor_gbuffer
from farfield.core.render.raster import Camera, MeshRenderer
from farfield.core.scene import Scene, has_material
from farfield.core.techniques.envmap.near_field import NearField
from farfield.core.techniques.envmap.runtime import camera_at, depth_range_for, envmap_viewpoints, view_directions
from farfield.core.viewcells import BoxCell


class NearFieldMask:
    """The (h, w) bool samples a camera sees the near field at (drawn alone, clipped to its cube),
    remembered for the last camera so that the three G-buffers of a view share one drawing."""

    def __init__(self, renderer: MeshRenderer | None):
        self.renderer = renderer
        self._last: tuple[Camera, np.ndarray] | None = None

    def __call__(self, camera: Camera) -> np.ndarray:
        if self._last is None or self._last[0] is not camera:
            if self.renderer is None:
                covered = np.zeros((camera.resolution, camera.resolution), dtype=bool)
            else:
                covered = self.renderer.render(camera)[..., 3] > 0
            self._last = (camera, covered)
        return self._last[1]


class FarField:
    """A G-buffer renderer (``render_normals``) showing only what ``mask`` leaves: masked samples
    are cleared (transparent, zero normal), as if nothing were drawn there."""

    def __init__(self, renderer, mask: NearFieldMask):
        self.renderer, self.mask = renderer, mask
        self.materials = getattr(renderer, "materials", False)  # what gbuffer_of asks

    def render_normals(self, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
        image, normals = self.renderer.render_normals(camera)
        hidden = self.mask(camera)
        image[hidden] = 0
        normals[hidden] = 0.0
        return image, normals

    def render_material(self, camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        image, normals, material = self.renderer.render_material(camera)
        hidden = self.mask(camera)
        image[hidden] = 0
        normals[hidden] = 0.0
        material[hidden] = 0.0
        return image, normals, material


def evaluate_envmap_lit(
    scene: Scene,
    impostor: Impostor,
    random_count: int = 4,
    seed: int = 0,
    samples: int = 2,
    lights=None,
    directions: np.ndarray | None = None,
) -> LitEvaluation:
    """The lit figures of ``impostor`` (an envmap) against ``scene`` beyond its near field (module
    docstring), from the views of :func:`~farfield.core.techniques.envmap.runtime.evaluate_envmap`
    (``directions`` (d, 3) default to the recorded faces' axes and their diagonals), ``samples``
    per pixel side, under ``lights`` (default :func:`~farfield.core.quality.lighting.default_lights`).
    Each row holds its ``position``, ``forward`` and ``kind``."""
    cell = BoxCell(np.asarray(impostor.viewcell["lo"]), np.asarray(impostor.viewcell["hi"]))
    points, kinds = envmap_viewpoints(cell, random_count, seed)
    if directions is None:
        directions = view_directions(impostor.parameters["directions"])
    near = NearField.from_dict(impostor.parameters["near_field"])
    near_objects = near.objects(scene)
    corners = impostor.payload.world_points()
    reach = float(np.max(np.linalg.norm(corners - near.centre, axis=1))) if corners.size else 0.0

    def views():
        for position, kind in zip(points, kinds):
            depth = depth_range_for(scene, cell, position, reach)
            for forward in directions:
                camera = camera_at(position, forward, impostor.fov_deg, impostor.resolution * samples, *depth)
                yield camera, {"position": position.tolist(), "forward": forward.tolist(), "kind": kind}

    with ExitStack() as stack:
        near_renderer = (
            stack.enter_context(MeshRenderer(near_objects, [near.clip] * len(near_objects))) if near_objects else None
        )
        mask = NearFieldMask(near_renderer)
        materials = any(has_material(obj) for obj in scene.objects)
        geometry = stack.enter_context(MeshRenderer(scene.objects, normals=True, materials=materials))
        stand_in = stack.enter_context(impostor_gbuffer(impostor))
        cards = stack.enter_context(impostor_gbuffer(impostor, normals=False))
        return evaluate_lit_views(
            FarField(geometry, mask), FarField(stand_in, mask), FarField(cards, mask), views(), samples, lights
        )
