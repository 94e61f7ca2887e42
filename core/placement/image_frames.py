"""Frames of a primitive-budget placement (seed 004 Fig. 12): what a view draws as geometry and which
LDI it warps, drawn on the GL, and how far that frame falls short of the full scene.

For a view (eye, yaw): :meth:`PrimitivePlacement.view` picks the grid point and its image.  The
cells the eye's frustum meets are drawn as geometry, less the image's subset, and the image's LDI
is warped in (:class:`farfield.core.render.splats.SplatRenderer`, then its 3x3 pass).  *Hole pixels* are
pixels the full scene covers from that view and the frame leaves empty.  They are counted against
the subset's *footprint*: the pixels its geometry covers when drawn alone from there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from farfield.core.ldi.construction import ConstructedLdi, construct_ldi
from farfield.core.placement.octree_cells import OctreeCells
from farfield.core.placement.solution_grid import GridPoint, PrimitivePlacement
from farfield.core.placement.yaw_ranges import drawn_cells, forward, right
from farfield.core.render.raster import Camera, MeshRenderer
from farfield.core.render.splats import SplatRenderer
from farfield.core.scene import Scene, SceneObject
from farfield.core.viewcells import BoxCell

UP = np.array([0.0, 1.0, 0.0])


def cell_objects(scene: Scene, cells: OctreeCells, chosen) -> list[SceneObject]:
    """The scene's triangles held by ``chosen`` cells (indices or a mask), as objects (materials kept)."""
    out = []
    for k, faces in cells.faces_of(chosen):
        out.append(scene.objects[k].with_faces(faces))
    return out


def view_camera(eye, yaw: float, fov: float, resolution: int, near: float, far: float) -> Camera:
    """The square run-time camera at ``eye`` with yaw ``yaw`` (pitch 0)."""
    return Camera(
        np.asarray(eye, dtype=np.float64),
        right(yaw),
        UP.copy(),
        forward(yaw),
        float(fov),
        int(resolution),
        float(near),
        float(far),
    )


def image_ldi(
    scene: Scene, placement: PrimitivePlacement, point: GridPoint, image: dict, resolution: int, images: int = 9
) -> ConstructedLdi:
    """The LDI of one image of ``point`` (:func:`farfield.core.ldi.construction.construct_ldi`)."""
    objects = cell_objects(scene, placement.cells, image["cells"])
    cell = BoxCell(point.position - point.radius, point.position + point.radius)  # as image_entries bakes it
    return construct_ldi(
        objects, point.position, image["yaw"], image["quad"], image["depth"], resolution, images=images, cell=cell
    )


@dataclass(frozen=True)
class FrameHoles:
    """One view's hybrid frame against the full scene: pixels, holes, and the subset's footprint."""

    covered: int  # pixels the full scene covers
    holes: int  # of those, left empty by the frame
    footprint: int  # pixels the image's subset covers alone
    border_holes: int  # holes within 2 pixels of the quad's projected outline (cracks)

    @property
    def share(self) -> float:
        return self.holes / self.footprint if self.footprint else 0.0


def _quad_outline(quad: np.ndarray, camera: Camera, shape: tuple[int, int]) -> np.ndarray:
    """(h, w) bool: pixels within 2 of the quad's projected edges (quads wholly ahead of the eye)."""
    frame = np.stack([camera.right, camera.up, camera.forward])
    d = (np.asarray(quad) - camera.eye) @ frame.T
    out = np.zeros(shape, dtype=bool)
    if np.any(d[:, 2] <= 0):
        return out
    t = math.tan(0.5 * camera.fov)
    n = camera.resolution
    cols = (d[:, 0] / d[:, 2] + t) / (2 * t) * n
    rows = (t - d[:, 1] / d[:, 2]) / (2 * t) * n
    for i in range(4):
        j = (i + 1) % 4
        steps = int(max(abs(cols[j] - cols[i]), abs(rows[j] - rows[i]))) * 2 + 2
        for s in np.linspace(0.0, 1.0, steps):
            c, r = cols[i] + s * (cols[j] - cols[i]), rows[i] + s * (rows[j] - rows[i])
            r0, c0 = int(math.floor(r)), int(math.floor(c))
            out[max(r0 - 2, 0) : max(r0 + 3, 0), max(c0 - 2, 0) : max(c0 + 3, 0)] = True
    return out


def frame_holes(scene: Scene, placement: PrimitivePlacement, eye, yaw: float, point_index: int, image_index: int, ldi,
                resolution: int, near: float, far: float) -> tuple[FrameHoles, dict]:  # fmt: skip
    """The hybrid frame at (eye, yaw) warping image ``image_index`` of grid point ``point_index``
    (``ldi``: its LayeredDepthImage), against the full scene.  A run time's choice is
    :meth:`PrimitivePlacement.view`'s; any point whose frustum holds the eye may be forced here."""
    point = placement.points[point_index]
    image = point.images[image_index]
    cells = drawn_cells(placement.cells.lo, placement.cells.hi, eye, yaw, placement.half)
    cells[image["cells"]] = False
    view = {"point": point_index, "image": image_index, "cells": cells}
    camera = view_camera(eye, yaw, 2.0 * placement.half, resolution, near, far)
    seen = view["cells"].copy()
    seen[image["cells"]] = True
    with MeshRenderer(cell_objects(scene, placement.cells, seen)) as full:
        reference = full.render(camera)
    with MeshRenderer(cell_objects(scene, placement.cells, image["cells"])) as alone:
        footprint = alone.render(camera)[..., 3] > 0
    with SplatRenderer(
        cell_objects(scene, placement.cells, view["cells"]) if view["cells"].any() else [], [ldi]
    ) as hybrid:
        frame = hybrid.render(camera)
    covered = reference[..., 3] > 0
    holes = covered & (frame[..., 3] == 0)
    border = _quad_outline(image["quad"], camera, holes.shape)
    result = FrameHoles(int(covered.sum()), int(holes.sum()), int(footprint.sum()), int((holes & border).sum()))
    return result, {"reference": reference, "frame": frame, "view": view}


def boundary_eyes(
    point: GridPoint, image: dict, half: float, count: int, rng: np.random.Generator
) -> list[tuple[np.ndarray, float]]:
    """(eye, yaw) pairs on ``point``'s star sphere (the eyes farthest from its images' centre of
    projection) with a yaw that uses ``image`` and a frustum of ``point`` that holds the eye."""
    index = point.images.index(image)
    out = []
    tries = 0
    while len(out) < count and tries < 200 * count:
        tries += 1
        yaw = float(rng.random() * 2.0 * math.pi)
        if point.image_for(yaw) != index:
            continue
        # a direction inside the point's frustum at this yaw, scaled to the sphere
        t = math.tan(half)
        u, v = rng.uniform(-t, t, 2)
        d = forward(yaw) + u * right(yaw) + v * UP
        out.append((point.position + point.radius * (1 - 1e-9) * d / np.linalg.norm(d), yaw))
    return out
