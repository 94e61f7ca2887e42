"""The reference runtime of a placement database (beside :mod:`farfield.core.techniques.envmap.runtime`): for a view,
the CPV's impostors plus every element no impostor of that CPV replaces, culled to the stored
potentially visible set and to the frustum.

Seed 000 §5.7: the runtime looks up the view's conservative problem view (CPV, a 3D region x a
view-direction interval), draws the impostors chosen for it and, as geometry, the rest of the
scene.  Here every *element* of the placement (a scene object, or a cluster ``name#k`` of a split
object, :class:`farfield.core.placement.hierarchy.Elements`) can be left out on its own, so that what an
impostor replaces is exactly what is left out.  Drawn, a whole object is one draw call, and a split
object's clusters lie in element order in the one index buffer of the object: a run of consecutive
clusters drawn is one call over its index range, so an object drawn whole costs one draw call,
as the planner counts it (``Elements.draw_calls``: each cluster ``1 / n`` of its object's call).
Each impostor bundle is read and uploaded once,
when a view first needs it, and drawn as its payload draws itself everywhere else
(:meth:`farfield.core.impostor.impostor.Payload.draw_objects`: quads or meshes textured from the atlas pages).
A payload not drawn as triangles that has a renderer drawing into the bound framebuffer
(``draw_card``: an octahedral impostor's :class:`~farfield.core.techniques.octahedral.runtime.OctahedralRenderer`,
its camera-facing card blending three frames) is drawn by that renderer after the geometry, depth-tested
against it, in the same framebuffer: a draw list holds the geometry's draws, then such cards.

**Visibility culling.**  A database planned with visibility stores the potentially visible set of
every smallest region of its view space (:mod:`farfield.core.visibility.region_sets`); the runtime
then draws as geometry only the elements of the PVS of the region holding the eye (as a
thesis-era engine with from-region culling did: seed 000 §5.8.1, "Visibility culling was done
for the model using a conservative from-region visibility algorithm [Wonk00]"), plus the impostors.  A view outside
every stored region, or a database without a PVS, draws every element as before.  The PVS is
sampled, not conservative: a visible element it lacks is missing from the frame, which the
walkthrough counts against the full scene (:func:`farfield.core.quality.walkthrough.placement_walkthrough`).

**Simplified geometry.**  A cell of technique ``lod`` (:mod:`farfield.core.placement.lod`) is drawn
in place of the elements it replaces as its level of detail of their merged mesh, simplified from
the scene when a view first needs it (the placement's chain, rebuilt from the same triangles), one
vertex-coloured draw call; its triangles count as an impostor's (``ViewFigures.triangles``).

Frustum culling is conservative: an element (or impostor) is left out only when every corner of
its bounding box lies outside one of the camera's four side planes, or behind the eye; no far
plane (the depth range reaches past the scene).  Plain geometry for comparison is the same
renderer with every element selected, culled the same way (:meth:`PlacementRenderer.draw` with
``plain=True``), and the reference image of the full scene draws every element unculled.

Figures per view (:class:`ViewFigures`): draw calls, triangles (geometry and impostor), quads,
impostors drawn, the CPV and its status, and the model's estimate: the CPV's ``time_after`` by the
placement, or for a view no CPV holds ("under budget") the cost model's estimate of the plain
geometry in the view (:func:`plain_estimate`: the planner's per-element law, pixels each drawn
element's box projected and clipped to the frame's camera, summed and capped at ``depth_complexity``
frames).
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass
from typing import Self

import numpy as np

from farfield.core.errors import RenderBackendError
from farfield.core.impostor.database import ImpostorDatabase
from farfield.core.placement.cost_model import CostModel
from farfield.core.placement.element_draws import ElementDraws
from farfield.core.placement.frame_pixels import box_frame_pixels
from farfield.core.placement.hierarchy import Elements, PlacementError
from farfield.core.placement.lod import LOD_TECHNIQUE, keeps_border, level_for
from farfield.core.placement.view_space import DEFAULT_DEPTH_COMPLEXITY, element_pixels
from farfield.core.render.raster import Camera, MeshRenderer
from farfield.core.scene import Scene
from farfield.core.techniques.envmap.runtime import camera_at
from farfield.core.viewcells import box_corners


def placement_section(database: ImpostorDatabase) -> dict:
    """The ``placement`` section of a placement database's index (PlacementError when it has none)."""
    section = database.placement
    if not section:
        raise PlacementError(f"{database.root}: not a placement database (its index has no 'placement' section)")
    return section


def boxes_in_frustum(camera: Camera, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(k,) bool: whether each axis-aligned box ``lo``..``hi`` ((k, 3) each) may show in ``camera``'s
    image.  Conservative: a box is culled only when all eight corners lie outside one side plane of
    the frustum (or all behind the eye); no far plane.

    >>> cam = Camera.look_at(np.zeros(3), [0.0, 0.0, 1.0], math.radians(90), 8, 0.1, 100.0)
    >>> lo = np.array([[-1, -1, 4.0], [-1, -1, -6.0], [8, -1, 4.0], [5.5, -1, 4.0], [-1, -1, -1]])
    >>> boxes_in_frustum(cam, lo, lo + 2.0).tolist()
    [True, False, False, True, True]
    """
    lo, hi = np.asarray(lo, dtype=np.float64).reshape(-1, 3), np.asarray(hi, dtype=np.float64).reshape(-1, 3)
    pick = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], dtype=bool)
    corners = np.where(pick[None, :, :], hi[:, None, :], lo[:, None, :])  # (k, 8, 3)
    e = (corners - camera.eye) @ np.stack([camera.right, camera.up, camera.forward]).T
    scale = 1e-9 * (1.0 + np.abs(e).max(axis=(1, 2), initial=0.0))[:, None]  # rounding slack
    t = math.tan(0.5 * camera.fov)
    x = e[..., 0] - camera.offset[0] * e[..., 2]
    y = e[..., 1] - camera.offset[1] * e[..., 2]
    z = e[..., 2]
    inside = np.any(z >= -scale, axis=1)
    for value in (x, -x, y, -y):
        inside &= np.any(value - t * z <= scale, axis=1)
    return inside


def plain_estimate(
    model: CostModel,
    elements: Elements,
    drawn: np.ndarray,
    position,
    fov: float,
    resolution: int,
    depth_complexity: float = DEFAULT_DEPTH_COMPLEXITY,
    camera: Camera | None = None,
) -> float:
    """The cost model's time of drawing elements ``drawn`` (indices) as geometry from ``position``:
    ``d + sum(a calls + b triangles) + c pixels``, their pixels summed and capped at
    ``depth_complexity`` frames.

    With the frame's ``camera`` (its eye is the position; its field of view and resolution count),
    each element's pixels are its box's projection clipped to the near plane and the frame
    (:func:`~farfield.core.placement.frame_pixels.box_frame_pixels`: 0 behind the eye or outside the
    frame).  Without one (no view direction), each element's
    :func:`~farfield.core.placement.view_space.element_pixels` from the eye (bounding-sphere disc or
    box faces; a whole frame where the eye is inside its bounds), as the planner estimates a problem
    view (:mod:`farfield.core.placement.view_space`)."""
    drawn = np.asarray(drawn, dtype=np.int64)
    if camera is not None:
        b = elements.bounds[drawn]
        pixels = box_frame_pixels(camera, b[:, 0], b[:, 1]) if drawn.size else np.zeros(0)
        resolution = camera.resolution
    else:
        p = np.asarray(position, dtype=np.float64)
        pixels = element_pixels(elements, p, p, fov, resolution, drawn) if drawn.size else np.zeros(0)
    cap = float(depth_complexity) * float(resolution) ** 2
    base = model.geometry_time(elements.draw_calls[drawn], elements.triangles[drawn], 0.0)
    return float(model.frame_time + np.sum(base) + model.geometry[2] * min(float(pixels.sum()), cap))


def depth_range(position: np.ndarray, corners: np.ndarray, lows: np.ndarray, highs: np.ndarray) -> tuple[float, float]:
    """(near, far) of a runtime's camera at ``position``: far past every point of ``corners``
    (n, 3), near half the distance to the nearest of the boxes ``lows``/``highs`` (m, 3), at least
    far / 1e5."""
    far = 1.01 * float(np.max(np.linalg.norm(corners - position, axis=1)))
    gap = np.maximum(0.0, np.maximum(lows - position, position - highs))
    near = max(0.5 * float(np.sqrt((gap * gap).sum(axis=1)).min()), far * 1e-5)
    return near, max(far, 2.0 * near)


@dataclass
class ViewFigures:
    """What one :meth:`PlacementRenderer.draw` drew, and what the model expected of it."""

    cpv: int | None
    status: str
    estimate: float | None  # model units (ms or triangles)
    draw_calls: int
    triangles: int  # geometry and impostor triangles together
    geometry_triangles: int
    quads: int
    impostors: int  # impostors drawn (after culling)
    impostors_in_cpv: int
    elements: int  # elements drawn as geometry (after culling)
    near: float
    far: float
    pvs: int | None = None  # elements in the PVS of the eye's region (None: no PVS used)
    pvs_culled: int = 0  # elements in the frustum, not replaced, that the PVS left out
    drawn: tuple[int, ...] = ()  # the elements drawn as geometry (indices, ascending); not in to_dict

    def to_dict(self) -> dict:
        figures = asdict(self)
        del figures["drawn"]
        return figures


class PlacementRenderer:
    """A placement database's reference runtime: the scene's objects uploaded once, an element drawn
    on its own or with the clusters next to it in one draw call; the impostors uploaded when first needed (see the module docstring).  Release with
    :meth:`release` or use as a context manager."""

    def __init__(self, scene: Scene, database: ImpostorDatabase):
        from farfield.core.placement.database import PlacementLookup

        section = placement_section(database)
        self.database = database
        self.section = section
        params = section["parameters"]
        self.t_max = float(params["t_max"])
        self.model = CostModel.from_dict(params["cost_model"])
        self.unit = self.model.unit
        options = params.get("options") or {}
        self.resolution = int(options.get("resolution", 256))
        self.fov_deg = float(options.get("fov_deg", 45.0))
        # A database without the parameter predates it: planned with the cap of 4 frames then.
        depth = params.get("depth_complexity", 4.0)
        self.depth_complexity = math.inf if depth is None else float(depth)
        self.view_space = np.asarray(params["view_space"], dtype=np.float64).reshape(2, 3)
        cluster = (section.get("elements") or {}).get("cluster_triangles")
        self.elements = Elements.of(scene, cluster)
        self.lookup = PlacementLookup(database.index)
        names = self.elements.names
        self.element_of = {name: i for i, name in enumerate(names)}
        # The stored sets' element indices -> this scene's (the same elements, perhaps in another
        # order: a scene read from another file format lists its objects in its own order).
        sets = self.lookup.sets
        self.pvs_elements = None
        if sets is not None:
            stored_names = sets.names or (list(names) if sets.count == self.elements.count else [])
            if sets.count != self.elements.count or set(stored_names) != set(names):
                raise PlacementError(
                    f"the placement's stored potentially visible sets are of {sets.count} elements, the scene has {self.elements.count} "
                    "(or other names): is it the placement's scene?"
                )
            self.pvs_elements = np.array([self.element_of[name] for name in stored_names], dtype=np.int64)
        missing = sorted({name for objects in self.lookup.objects.values() for name in objects} - set(names))
        if missing:
            raise PlacementError(
                f"the scene has no elements {missing[:5]}{' ...' if len(missing) > 5 else ''} that the placement's impostors replace "
                f"(objects split at {self.elements.cluster_triangles} triangles): is it the placement's scene?"
            )
        self.uploads = ElementDraws(scene, self.elements)
        self.gpu = self.uploads.renderer
        self.scene_corners = box_corners(scene.bounds)
        self._impostors: dict[int, tuple] = {}
        self.uploaded_impostor_bytes = 0
        self.scene = scene
        # Cells of simplified geometry: no bundle, simplified from the scene when first drawn.
        self.lod_cells = {int(e["index"]): e for e in database.index["cells"] if e.get("technique") == LOD_TECHNIQUE}
        self.uploaded_lod_bytes = 0

    @staticmethod
    def element_names(scene: Scene, database: ImpostorDatabase) -> tuple[str, ...]:
        """The names of the placement's elements of ``scene`` (what a lookup's ``replaced`` names)."""
        return Elements.of(scene, (placement_section(database).get("elements") or {}).get("cluster_triangles")).names

    # -- impostors ------------------------------------------------------------------------

    def impostor(self, cell: int) -> tuple[MeshRenderer, int, int, np.ndarray, np.ndarray, np.ndarray]:
        """(renderer, triangles, quads, bounds lo, bounds hi, bounds corners) of impostor ``cell``,
        read and uploaded once; the renderer is a MeshRenderer of its payload's draw objects, or
        the payload's own renderer where it draws a card (``draw_card``, module docstring)."""
        if cell in self.lod_cells and cell not in self._impostors:
            self._impostors[cell] = self._lod(cell)
        if cell not in self._impostors:
            impostor = self.database.impostor(cell)
            objects = impostor.payload.draw_objects(impostor)  # the payload's runtime draw list
            if objects is not None:
                renderer = MeshRenderer(objects)
            else:
                renderer = impostor.payload.renderer(impostor)
                if not hasattr(renderer, "draw_card"):
                    renderer.release()
                    raise PlacementError(
                        f"impostor {cell}: no drawer for a {impostor.payload.kind!r} payload ({impostor.technique})"
                    )
            points = impostor.payload.world_points().reshape(-1, 3)
            if points.size:
                lo, hi = points.min(axis=0), points.max(axis=0)
            else:
                lo = hi = np.zeros(3)
            self._impostors[cell] = (
                renderer,
                impostor.triangle_count,
                impostor.quad_count,
                lo,
                hi,
                box_corners(np.stack([lo, hi])),
            )
            self.uploaded_impostor_bytes += impostor.texture_bytes
        return self._impostors[cell]

    def _lod(self, cell: int) -> tuple:
        """:meth:`impostor`'s tuple for a cell of simplified geometry: its level of detail of its
        elements' merged mesh (:func:`farfield.core.placement.lod.level_for`), one vertex-coloured draw."""
        entry = self.lod_cells[cell]
        ids = [self.element_of[name] for name in entry["objects"]]
        cluster = keeps_border(self.elements, ids)
        level = level_for(self.elements.scene_of(self.scene, ids), int(entry["params"]["options"]["level"]), cluster)
        lo, hi = level.vertices.min(axis=0), level.vertices.max(axis=0)
        self.uploaded_lod_bytes += level.memory_bytes
        renderer = MeshRenderer([level.scene_object(f"lod-{cell}")])
        return renderer, level.triangles, 0, lo, hi, box_corners(np.stack([lo, hi]))

    # -- drawing --------------------------------------------------------------------------

    def _depth(self, position: np.ndarray, points: list[np.ndarray]) -> tuple[float, float]:
        """:func:`depth_range` of the scene's corners and elements and the impostors' ``points``."""
        corners = np.concatenate([self.scene_corners, *points]) if points else self.scene_corners
        lows = np.concatenate([self.elements.bounds[:, 0]] + [p.min(axis=0, keepdims=True) for p in points])
        highs = np.concatenate([self.elements.bounds[:, 1]] + [p.max(axis=0, keepdims=True) for p in points])
        return depth_range(position, corners, lows, highs)

    def prepare(
        self,
        position,
        forward,
        fov_deg: float | None = None,
        resolution: int | None = None,
        plain: bool = False,
        cull: bool = True,
        camera: Camera | None = None,
        pvs: bool | None = None,
    ) -> tuple[Camera, list, ViewFigures]:
        """The camera, the draw list and the figures of one view (nothing drawn yet).

        ``plain``: every element as geometry, no impostor (the scene without the placement);
        ``cull``: False draws everything selected whether in the frustum or not (a reference image);
        ``camera``: draw from this camera (another view's, to compare images) instead of a new one;
        ``pvs``: draw only the stored PVS of the eye's region (None: unless ``plain``; no effect
        where none is stored).
        The depth range counts every element and the view's impostors, whichever are drawn, so the
        runtime's camera also serves the plain geometry and the full scene.
        """
        position = np.asarray(position, dtype=np.float64).reshape(3)
        forward = np.asarray(forward, dtype=np.float64).reshape(3)
        fov_deg = self.fov_deg if fov_deg is None else float(fov_deg)
        resolution = self.resolution if resolution is None else int(resolution)
        found = self.lookup.find(position, forward)
        replaced = set() if plain else set(found.get("replaced") or [])
        cells = [int(c) for c in found.get("impostors") or []]
        keep = np.ones(self.elements.count, dtype=bool)
        for name in replaced:
            keep[self.element_of[name]] = False
        stored = self.lookup.visible_set(position) if (not plain if pvs is None else pvs) else None
        dropped = np.zeros(self.elements.count, dtype=bool)  # what the PVS leaves out of ``keep``
        if stored is not None:
            stored = self.pvs_elements[stored]
            dropped[:] = keep
            keep[:] = False
            keep[stored] = dropped[stored]
            dropped &= ~keep
        loaded = [self.impostor(c) for c in cells]
        if camera is None:
            near, far = self._depth(position, [item[5] for item in loaded])
            camera = camera_at(position, forward, fov_deg, resolution, near, far)
        if plain:
            loaded = []
        selected = np.flatnonzero(keep)
        if cull and selected.size:
            b = self.elements.bounds[selected]
            selected = selected[boxes_in_frustum(camera, b[:, 0], b[:, 1])]
        pvs_culled = np.flatnonzero(dropped)
        if cull and pvs_culled.size:
            b = self.elements.bounds[pvs_culled]
            pvs_culled = pvs_culled[boxes_in_frustum(camera, b[:, 0], b[:, 1])]
        draws = self.geometry_draws(selected)
        shown = [
            item for item in loaded if not cull or bool(boxes_in_frustum(camera, item[3][None, :], item[4][None, :])[0])
        ]
        for item in shown:
            draws.extend(item[0]._draws if isinstance(item[0], MeshRenderer) else [item[0]])
        geometry_triangles = int(self.elements.triangles[selected].sum())
        estimate = None if plain else found.get("time_estimated")
        if estimate is None:
            estimate = plain_estimate(
                self.model,
                self.elements,
                selected,
                position,
                math.radians(fov_deg),
                resolution,
                self.depth_complexity,
                camera,
            )
        figures = ViewFigures(
            cpv=None if found.get("cpv") is None else int(found["cpv"]), status="plain" if plain else found["status"],
            estimate=float(estimate), draw_calls=len(draws), triangles=geometry_triangles + sum(item[1] for item in shown),
            geometry_triangles=geometry_triangles, quads=sum(item[2] for item in shown), impostors=len(shown),
            impostors_in_cpv=0 if plain else len(cells), elements=int(selected.size), near=camera.near, far=camera.far,
            pvs=None if stored is None else int(stored.size), pvs_culled=int(pvs_culled.size),
            drawn=tuple(int(i) for i in selected),
        )  # fmt: skip
        return camera, draws, figures

    def geometry_draws(self, elements) -> list[tuple]:
        """The draws of ``elements`` (indices, ascending): :meth:`ElementDraws.draws`."""
        return self.uploads.draws(elements)

    def _draw(self, camera: Camera, draws: list):
        """Draw ``draws``: the geometry's (MeshRenderer draw tuples) first, then the cards
        (renderers with ``draw_card``) into the same framebuffer; the colour texture."""
        saved = self.gpu._draws
        self.gpu._draws = [d for d in draws if isinstance(d, tuple)]
        try:
            colour = self.gpu._draw(camera)
        finally:
            self.gpu._draws = saved
        for card in (d for d in draws if not isinstance(d, tuple)):
            card.draw_card(camera)
        return colour

    def render(self, camera: Camera, draws: list) -> np.ndarray:
        """(h, w, 4) uint8 image of ``draws`` (from :meth:`prepare`) from ``camera``, top row first."""
        colour = self._draw(camera, draws)
        image = np.frombuffer(colour.read(), dtype=np.uint8).reshape(camera.resolution, camera.resolution, 4)
        error = self.gpu.ctx.error
        if error != "GL_NO_ERROR":
            raise RenderBackendError(f"OpenGL error while rendering a placement's view: {error}")
        return image[::-1].copy()

    def frame_seconds(self, camera: Camera, draws: list) -> float:
        """Seconds to draw ``draws`` and finish (no read-back), as :meth:`MeshRenderer.frame_seconds`."""
        self.gpu.ctx.finish()
        start = time.perf_counter()
        self._draw(camera, draws)
        self.gpu.ctx.finish()
        return time.perf_counter() - start

    def draw(
        self, position, forward, fov_deg: float | None = None, resolution: int | None = None
    ) -> tuple[np.ndarray, ViewFigures]:
        """Draw one view as the runtime does; returns the image and its figures."""
        camera, draws, figures = self.prepare(position, forward, fov_deg, resolution)
        return self.render(camera, draws), figures

    def release(self) -> None:
        for item in self._impostors.values():
            item[0].release()
        self._impostors.clear()
        self.uploads.release()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.release()
