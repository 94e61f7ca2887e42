"""The reference runtime of environment-map impostors, and the plain renderer it is compared with.

Seed 002 §3, runtime: for a viewpoint (1) find its view cell, (2) prefetch the neighbours' impostors,
(3) draw the near-field geometry, (4) draw the cell's impostor quads.  Both this runtime and the
full-scene renderer draw through the same :class:`farfield.core.render.raster.MeshRenderer` (same shader,
same camera), so frame times and images differ only by what is drawn.  The runtime draws nearest
first (:func:`nearest_first`): the near field, each object's triangles front to back but the
objects in the scene's order (so coplanar objects resolve their depth ties as in the full scene),
then the layers from the innermost out, so that fragments behind nearer ones fail the depth test
before they are shaded (opaque geometry is drawn without a discard for this, see
:class:`farfield.core.render.raster.MeshRenderer`).  The near-field triangles
are clipped to their cube (by the GL's clip planes; by the fragment shader's discard where faces
are open), the layers were clipped to the same cube's faces
when recorded, so nothing is drawn twice or lost at the border (:mod:`farfield.core.techniques.envmap.near_field`).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from farfield.core.cube_faces import face_normal
from farfield.core.impostor.impostor import Impostor, page_of
from farfield.core.quality.evaluation import compare_images, error_budget_px, impostor_objects, vertex_pixels
from farfield.core.render.raster import Camera, MeshRenderer
from farfield.core.scene import Scene, SceneObject
from farfield.core.techniques.envmap.near_field import NearField
from farfield.core.viewcells import BoxCell, box_corners


def camera_at(position, forward, fov_deg: float, resolution: int, near: float, far: float) -> Camera:
    """A camera at ``position`` looking along ``forward`` (any length > 0)."""
    position = np.asarray(position, dtype=np.float64)
    return Camera.look_at(
        position, position + np.asarray(forward, dtype=np.float64), math.radians(fov_deg), resolution, near, far
    )


# Triangles sorted nearest first in runs of this many, each run kept in the mesh's own order: the
# GL shades a vertex once for the indices it sees together, and a per-triangle sort scattered them
# (the near field alone at 16 px, 0.83 against 0.69 ms unsorted; see the README, "The runtime's
# frame, second round").  The layers' quads are sorted two triangles at a time, a quad's pair together.
NEAR_FIELD_RUN = 64
QUAD_RUN = 2


def nearest_first(
    objects: list[SceneObject], centre, keep_object_order: bool = False, run: int = 1
) -> list[SceneObject]:
    """``objects`` with each one's triangles sorted by the distance of their centroid from
    ``centre`` in the cube (maximum) norm, and, unless ``keep_object_order``, the objects by their
    nearest triangle.  With ``run`` > 1 the triangles move in runs of that many consecutive ones,
    each run keyed by its nearest triangle and kept in its order.

    Seen from inside the near-field cube, a layer's quads lie at its border distance in that norm,
    so this draws the layers innermost first and geometry roughly front to back: an order, not a
    guarantee.  The depth test makes the image independent of the order except where two
    triangles tie in depth (coplanar overlaps, which z-fight in any renderer): there the first
    drawn wins, so ``keep_object_order`` keeps the scene's winner between objects.

    >>> tri = lambda x: SceneObject(f"at{x}", np.array([[x, 0.0, 0.0], [x, 1.0, 0.0], [x, 0.0, 1.0]]), np.array([[0, 1, 2]]))
    >>> two = SceneObject("two", np.array([[5.0, 0, 0], [5, 1, 0], [5, 0, 1], [2, 0, 0], [2, 1, 0], [2, 0, 1]]), np.array([[0, 1, 2], [3, 4, 5]]))
    >>> [(o.name, o.faces.tolist()) for o in nearest_first([tri(9.0), two, tri(-3.0)], np.zeros(3))]
    [('two', [[3, 4, 5], [0, 1, 2]]), ('at-3.0', [[0, 1, 2]]), ('at9.0', [[0, 1, 2]])]
    >>> [o.name for o in nearest_first([tri(9.0), two, tri(-3.0)], np.zeros(3), keep_object_order=True)]
    ['at9.0', 'two', 'at-3.0']
    >>> four = SceneObject("four", np.array([[x, y, z] for x in (5.0, 2.0, 7.0, 1.0) for y, z in ((0, 0), (1, 0), (0, 1))]), np.arange(12).reshape(4, 3))
    >>> nearest_first([four], np.zeros(3), run=2)[0].faces[:, 0].tolist()  # runs (5, 2) and (7, 1): the second's nearest is nearer
    [6, 9, 0, 3]
    """
    centre = np.asarray(centre, dtype=np.float64)
    keyed = []
    for obj in objects:
        if obj.faces.shape[0] == 0:  # kept, so the list stays aligned with what was given
            keyed.append((math.inf, obj))
            continue
        key = np.max(np.abs(obj.vertices[obj.faces].mean(axis=1) - centre), axis=1)
        if run > 1:  # every triangle takes its run's key; the stable sort keeps a run's order
            key = np.repeat(np.minimum.reduceat(key, np.arange(0, key.size, run)), run)[: key.size]
        order = np.argsort(key, kind="stable")
        keyed.append((float(key[order[0]]), replace(obj, faces=obj.faces[order])))
    if not keep_object_order:
        keyed.sort(key=lambda pair: pair[0])
    return [obj for _, obj in keyed]


class EnvmapCellRenderer:
    """One cell's near-field geometry (clipped to its cube) and impostor quads, uploaded once.

    With ``lit`` it also uploads the same draw as two G-buffer renderers (``render_normals``, the
    lit evaluation's, :mod:`farfield.core.quality.lit`): ``gbuffer``, the quads with the impostor's
    normal pages as world-space normal maps, and ``cards``, the quads as flat cards (the near
    field with its own normals in both); and ``near_field``, the near field alone (None where the
    cell has none), which masks it out of the lit walkthrough's far-field figures.  An impostor
    without normal pages (``has_normals`` False) has only the cards, and ``gbuffer`` is ``cards``."""

    def __init__(self, scene: Scene, impostor: Impostor, lit: bool = False):
        if impostor.technique != "envmap":
            raise ValueError(f"an envmap runtime needs an envmap impostor, got {impostor.technique!r}")
        self.impostor = impostor
        self.near = NearField.from_dict(impostor.parameters["near_field"])
        near_objects = nearest_first(
            self.near.objects(scene), self.near.centre, keep_object_order=True, run=NEAR_FIELD_RUN
        )
        quads = nearest_first(impostor_objects(impostor), self.near.centre, run=QUAD_RUN)
        clips = [self.near.clip] * len(near_objects) + [None] * len(quads)
        self.renderer = MeshRenderer(near_objects + quads, clips)
        self.has_normals = "normal" in impostor.channels
        self.gbuffer = self.cards = self.near_field = None
        if lit:
            if near_objects:  # drawn alone, the samples the near field covers (the lit walkthrough's far-field figures)
                self.near_field = MeshRenderer(near_objects, clips[: len(near_objects)])
            self.cards = MeshRenderer(near_objects + quads, clips, normals=True)
            self.gbuffer = self.cards
            if self.has_normals:
                pages = impostor.channels["normal"]
                maps = [None] * len(near_objects) + [pages[page_of(quad)] for quad in quads]
                self.gbuffer = MeshRenderer(near_objects + quads, clips, normals=True, normal_maps=maps)
        self.near_triangles = sum(obj.faces.shape[0] for obj in near_objects)
        self.quad_triangles = impostor.triangle_count  # the impostor's triangles, whatever its payload
        corners = impostor.payload.world_points()
        self.reach = float(np.max(np.linalg.norm(corners - self.near.centre, axis=1))) if corners.size else 0.0

    def release(self) -> None:
        self.renderer.release()
        for renderer in {id(r): r for r in (self.gbuffer, self.cards, self.near_field) if r is not None}.values():
            renderer.release()


def depth_range_for(scene: Scene, cell: BoxCell, position, reach: float = 0.0) -> tuple[float, float]:
    """(near, far) for cameras in ``cell``: near a hundredth of the cell side, far past the scene
    and the impostor quads (``reach`` from the cell centre)."""
    position = np.asarray(position, dtype=np.float64)
    corners = box_corners(scene.bounds)
    far = max(
        float(np.max(np.linalg.norm(corners - position, axis=1))), reach + float(np.linalg.norm(position - cell.center))
    )
    near = 0.01 * float(np.min(cell.size))
    return near, max(far * 1.01, 2.0 * near)


def compare_views(
    scene_renderer: MeshRenderer,
    cell_renderer: EnvmapCellRenderer,
    camera: Camera,
    samples: int = 1,
    objects=None,
    budget_px: float = 1.0,
) -> dict:
    """Pixel statistics (:func:`farfield.core.quality.evaluation.compare_images`) of the full scene vs the runtime;
    given the scene's ``objects``, an impostor pixel within one pixel of a vertex is not bloat
    (:func:`farfield.core.quality.evaluation.vertex_pixels`: geometry smaller than a sample is still there)."""
    if samples > 1:
        camera = Camera(
            camera.eye,
            camera.right,
            camera.up,
            camera.forward,
            camera.fov,
            camera.resolution * samples,
            camera.near,
            camera.far,
        )
    reach = None if objects is None else (lambda: vertex_pixels(objects, camera, samples))
    return compare_images(
        scene_renderer.render(camera), cell_renderer.renderer.render(camera), samples, reach=reach, budget_px=budget_px
    )


def view_directions(directions: list[str] | tuple[str, ...]) -> np.ndarray:
    """(n, 3) unit view directions for evaluating an envmap cell: every recorded face axis, and the
    diagonals between neighbouring recorded faces (where a view spans two faces)."""
    vectors = [face_normal(d) for d in directions]
    out = list(vectors)
    for a in range(len(vectors)):
        for b in range(a + 1, len(vectors)):
            if float(vectors[a] @ vectors[b]) == 0.0:
                out.append((vectors[a] + vectors[b]) / math.sqrt(2.0))
    return np.array(out)


def envmap_viewpoints(cell: BoxCell, random_count: int, seed: int) -> tuple[np.ndarray, list[str]]:
    """(n, 3) float64 viewpoints of ``cell`` an envmap evaluation looks from (its 8 corners, its
    centre and ``random_count`` seeded random points inside) and their kinds."""
    points = np.concatenate([cell.corners(), cell.center[None, :], cell.sample_random(random_count, seed)])
    return points, ["corner"] * 8 + ["centre"] + ["random"] * random_count


def evaluate_envmap(
    scene: Scene,
    impostor: Impostor,
    random_count: int = 4,
    seed: int = 0,
    samples: int = 2,
    directions: np.ndarray | None = None,
) -> dict:
    """Render the full scene and the runtime's view from viewpoints inside the impostor's cell
    (its 8 corners, its centre and ``random_count`` seeded random points), each looking along
    ``directions`` (default :func:`view_directions` of the recorded faces); returns per-view rows and
    totals (hole pixels, colour error per pixel: mean over views, worst view's 99th percentile,
    maximum; within one pixel; SSIM), as :func:`farfield.core.quality.evaluation.evaluate` does for one part."""
    cell = BoxCell(np.asarray(impostor.viewcell["lo"]), np.asarray(impostor.viewcell["hi"]))
    points, kinds = envmap_viewpoints(cell, random_count, seed)
    if directions is None:
        directions = view_directions(impostor.parameters["directions"])
    rows = []
    budget = error_budget_px(impostor)
    cell_renderer = EnvmapCellRenderer(scene, impostor)
    try:
        with MeshRenderer(scene.objects) as full:
            for position, kind in zip(points, kinds):
                near, far = depth_range_for(scene, cell, position, cell_renderer.reach)
                for forward in directions:
                    camera = camera_at(position, forward, impostor.fov_deg, impostor.resolution, near, far)
                    stats = compare_views(full, cell_renderer, camera, samples, scene.objects, budget)
                    rows.append(
                        {"position": position.tolist(), "forward": forward.tolist(), "kind": kind, "stats": stats}
                    )
    finally:
        cell_renderer.release()
    stats = [r["stats"] for r in rows]
    totals = {
        "views": len(rows),
        "hole_pixels": sum(s["hole_pixels"] for s in stats),
        "max_hole_pixels": max(s["hole_pixels"] for s in stats),
        "geometry_pixels": sum(s["geometry_pixels"] for s in stats),
        "bloat_beyond_1px": sum(s["bloat_beyond_1px"] for s in stats),
        "error_budget_px": budget,
        "hole_pixels_beyond_budget": sum(s["hole_pixels_beyond_budget"] for s in stats),
        "bloat_beyond_budget": sum(s["bloat_beyond_budget"] for s in stats),
        "colour_error_mean": float(np.mean([s["colour_error_mean"] for s in stats])),
        "colour_error_p99": float(np.max([s["colour_error_p99"] for s in stats])),
        "colour_error_max": max(s["colour_error_max"] for s in stats),
        "colour_error_1px_mean": float(np.mean([s["colour_error_1px_mean"] for s in stats])),
        "ssim": float(np.mean([s["ssim"] for s in stats])),
        "ssim_min": min(s["ssim"] for s in stats),
    }
    return {"views": rows, "totals": totals}
