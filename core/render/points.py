"""Points drawn with a depth test: the runtime of a point-based impostor (seed 001 §5.3).

Each point lands in the pixel that contains its projection (a one-pixel point's footprint); nearer
points hide farther ones.  Its colour is either the one it carries (§5.3's "lower quality, but
faster preview ... using only one color per point", and a compressed point's only colour) or,
given an :class:`Appearance`, a bilinear look-up (in linear light: the pages are sRGB
textures, as the meshes' base colours) in its tile of an atlas page at the place where
the ray from the eye to the point crosses the sampling plane (§5.3; the vertex shader,
``shaders/points.vert``).

``grid`` (the baked image's resolution and field of view) draws the points as the baked image's
pixels: each point snapped to the centre of the baked pixel it falls in and drawn as a square of
that pixel's size, so that a camera whose pixels subdivide the baked ones (the evaluation's
supersampled views and its confirmation windows, :mod:`farfield.core.quality.evaluation`) sees what the baked
resolution shows, not sparse dots.  Such cameras must share the baked camera's axis (their
``offset`` is measured from it), and a window's sides must fall on baked pixels' edges: the GL
drops a point whose centre lies outside the viewport, so a window that cuts a baked pixel in two
loses its part of that pixel (the evaluation's windows start and end on evaluated pixels).

A point's alpha is the share of its pixel's footprint the part covers (:mod:`farfield.core.techniques.points.appearance`):
drawn without blending, the image holds the nearest point's colour (that of what covers the pixel)
and that coverage, for a runtime to composite over what lies behind the impostor; a point without
a coverage of its own (a preview's) has alpha 255.

The camera, targets and read-back are :class:`farfield.core.render.raster.MeshRenderer`'s, so its images
compare pixel for pixel with the mesh's.  :meth:`PointRenderer.render_ids` draws each point's index
instead: the visibility of the points among themselves, as the z-buffer resolves it (§4.3's v_j).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import moderngl
import numpy as np

from farfield.core.colour_space import srgb_to_linear
from farfield.core.errors import RenderBackendError
from farfield.core.render.programs import program, srgb_texture
from farfield.core.render.raster import Camera, MeshRenderer


@dataclass(frozen=True)
class Appearance:
    """Where each point's directional colours are: ``pages`` (H, W, 4) uint8 sRGB, top row first;
    ``page`` (n,) int64 each point's page, -1 for a point of one colour; ``texel`` (n, 2) int64 its
    tile's first texel (x, y); ``tile`` (texels along u, along v); the sampling plane's ``normal``
    (3,) and ``offset`` (normal · x = offset), its in-plane axes ``u``, ``v`` (3,) and the
    rectangle ``lo``, ``hi`` (2,) of plane coordinates (x · u, x · v) the tiles span."""

    pages: tuple
    page: np.ndarray
    texel: np.ndarray
    tile: tuple[int, int]
    normal: np.ndarray
    offset: float
    u: np.ndarray
    v: np.ndarray
    lo: np.ndarray
    hi: np.ndarray


def material_columns(materials: np.ndarray, emissive: np.ndarray | None, count: int) -> list[np.ndarray]:
    """[(n, 3) float64 occlusion, roughness, metallic in 0..1, (n, 3) float64 linear emission] of
    ``count`` elements from their (n, 4) uint8 ORM bytes and sRGB emission bytes (None: no emission),
    the vertex columns of a material G-buffer's points and splats (the values the GL reads from a
    linear ORM page and an sRGB emissive page at a texel's centre)."""
    orm = np.asarray(materials, dtype=np.float64).reshape(count, 4)[:, :3] / 255.0
    if emissive is None:
        light = np.zeros((count, 3))
    else:
        light = srgb_to_linear(np.asarray(emissive, dtype=np.float64).reshape(count, 4)[:, :3] / 255.0)
    return [orm, light]


class PointRenderer(MeshRenderer):
    """``positions`` (n, 3) float64 world and ``colours`` (n, 4) uint8 sRGB, uploaded once; with an
    ``appearance``, the points of a page look their colour up there (module docstring); ``grid``:
    (resolution, fov radians) of the image the points were baked for, or None (module docstring).

    ``gbuffer=True`` makes a G-buffer renderer for the lit evaluation (:meth:`render_normals`, as
    :class:`~farfield.core.render.raster.MeshRenderer`'s): each point's pixels hold its ``normals``
    (n, 3) float64 unit world normal, or without them the normal of a sprite facing the viewer
    (minus the camera's forward axis: a point lit as a flat card).

    ``materials`` (n, 4) uint8 (with ``gbuffer``): each point's glTF ORM bytes (occlusion, roughness,
    metallic; :mod:`farfield.core.ldi.materials`), and ``emissive`` (n, 4) uint8 its sRGB-encoded
    emission (None: none), make the renderer a material G-buffer (``materials`` true,
    :meth:`~farfield.core.render.raster.MeshRenderer.render_material`, the same contract): each
    point's pixels hold its bytes / 255 and its emission decoded to linear light, zero where
    nothing is drawn."""

    def __init__(
        self,
        positions: np.ndarray,
        colours: np.ndarray,
        appearance: Appearance | None = None,
        grid: tuple[int, float] | None = None,
        gbuffer: bool = False,
        normals: np.ndarray | None = None,
        materials: np.ndarray | None = None,
        emissive: np.ndarray | None = None,
    ):
        super().__init__([], normals=gbuffer, materials=materials is not None and gbuffer)
        if normals is not None and not gbuffer:
            raise ValueError("point normals are drawn by a G-buffer renderer only (gbuffer=True)")
        if (materials is not None or emissive is not None) and not self.materials:
            raise ValueError("point materials are drawn by a G-buffer renderer only (gbuffer=True, materials given)")
        positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        colours = np.asarray(colours, dtype=np.uint8).reshape(-1, 4)
        if positions.shape[0] != colours.shape[0]:
            raise ValueError(f"{positions.shape[0]} positions but {colours.shape[0]} colours")
        self.count = int(positions.shape[0])
        self.grid = grid
        self.appearance = appearance
        self.origin = 0.5 * (positions.min(axis=0) + positions.max(axis=0)) if self.count else np.zeros(3)
        page = np.full(self.count, -1, np.int64) if appearance is None else np.asarray(appearance.page, np.int64)
        # Drawn page by page (the single-colour points first): (program, first, count, texture).
        self.order = np.argsort(page, kind="stable")
        data = [(positions - self.origin)[self.order], colours[self.order].astype(np.float64) / 255.0]
        layout = "3f 4f"
        attributes = ["in_position", "in_color"]
        defines: tuple[str, ...] = ()
        if appearance is not None:
            texel = np.where(page[:, None] >= 0, np.asarray(appearance.texel, np.float64), -1.0)
            data.append(texel[self.order])
            layout += " 2f"
            attributes.append("in_tile")
            defines = ("APPEARANCE",)
        if gbuffer:
            defines += ("NORMALS",)
        if normals is not None:
            data.append(np.asarray(normals, dtype=np.float64).reshape(self.count, 3)[self.order])
            layout += " 3f"
            attributes.append("in_normal")
            defines += ("POINT_NORMALS",)
        if self.materials:
            data += [column[self.order] for column in material_columns(materials, emissive, self.count)]
            layout += " 3f 3f"
            attributes += ["in_material", "in_emissive"]
            defines += ("MATERIAL",)
        self.points_program = program(self.ctx, "points.vert", "points.frag", defines=defines)
        self.id_program = program(self.ctx, "points.vert", "points.frag", defines=("POINT_ID",))
        # a vertex: position, colour[, tile][, normal][, material, emission]
        floats = 7 + 2 * (appearance is not None) + 3 * (normals is not None) + 6 * self.materials
        blob = (
            np.ascontiguousarray(np.concatenate(data, axis=1), dtype="<f4").tobytes()
            if self.count
            else b"\0" * 4 * floats
        )
        self._vbo = self.ctx.buffer(blob)
        self._vao = self.ctx.vertex_array(self.points_program, [(self._vbo, layout, *attributes)])
        self._id_vao = self.ctx.vertex_array(self.id_program, [(self._vbo, f"3f {4 * (floats - 3)}x", "in_position")])
        self._owned += [self._vbo, self._vao, self._id_vao]
        self._ranges = []
        sorted_page = page[self.order]
        for value in np.unique(sorted_page):
            first = int(np.searchsorted(sorted_page, value, "left"))
            last = int(np.searchsorted(sorted_page, value, "right"))
            texture = None
            if value >= 0:
                # Uploaded as srgb_texture flips rows to GL's order, so the shader's texel rows
                # count from the texture's bottom: flip back to keep row y of the page at y.
                texture = srgb_texture(self.ctx, np.ascontiguousarray(appearance.pages[int(value)][::-1]))
                texture.repeat_x = texture.repeat_y = False
                self._owned.append(texture)
            self._ranges.append((first, last - first, texture))

    def _frame(self, prog: moderngl.Program, camera: Camera) -> None:
        t = math.tan(0.5 * camera.fov)
        prog["half_tan"].value = (t, t)
        prog["depth_range"].value = (camera.near, camera.far)
        prog["eye_from_local"].write(camera.eye_matrix(self.origin).tobytes())
        own = 2.0 * t / camera.resolution
        if self.grid is None:
            origin, step = (-t, -t), own
        else:
            resolution, fov = self.grid
            half = math.tan(0.5 * fov)
            step = 2.0 * half / int(resolution)
            origin = (-half - camera.offset[0], -half - camera.offset[1])
        prog["grid_origin"].value = origin
        prog["grid_step"].value = step
        prog["point_size"].value = step / own

    def _draw(self, camera: Camera, ids: bool = False):
        colour = super()._draw(camera)  # clears colour and depth
        if not self.count:
            return colour
        prog = self.id_program if ids else self.points_program
        self._frame(prog, camera)
        if prog["point_size"].value > 255.0:
            raise RenderBackendError(
                f"points of {prog['point_size'].value:.0f} pixels: the camera's pixels are too fine for the points' grid"
            )
        a = self.appearance
        if a is not None and not ids:
            width = np.asarray(a.hi, np.float64) - np.asarray(a.lo, np.float64)
            u, v, n = (np.asarray(x, np.float64) for x in (a.u, a.v, a.normal))
            prog["eye_local"].value = tuple(float(x) for x in camera.eye - self.origin)
            prog["plane"].value = (*(float(x) for x in n), float(a.offset - n @ self.origin))
            prog["rect_u"].value = (*(float(x) for x in u / width[0]), float((u @ self.origin - a.lo[0]) / width[0]))
            prog["rect_v"].value = (*(float(x) for x in v / width[1]), float((v @ self.origin - a.lo[1]) / width[1]))
            prog["tile"].value = tuple(float(x) for x in a.tile)
        if (
            not ids and prog.get("facing", None) is not None
        ):  # a G-buffer without point normals: sprites facing the viewer
            prog["facing"].value = tuple(float(-x) for x in camera.forward)
        self.ctx.enable(moderngl.PROGRAM_POINT_SIZE)
        try:
            if ids:
                self._id_vao.render(moderngl.POINTS, vertices=self.count)
            else:
                for first, count, texture in self._ranges:
                    if texture is not None:
                        texture.use(0)
                        prog["page"].value = 0
                        prog["page_size"].value = (float(texture.width), float(texture.height))
                    self._vao.render(moderngl.POINTS, vertices=count, first=first)
        finally:
            self.ctx.disable(moderngl.PROGRAM_POINT_SIZE)
        return colour

    def render_ids(self, camera: Camera) -> np.ndarray:
        """(h, w) int64, top row first: the index (in the order given) of the point each pixel
        shows, -1 where none."""
        colour = self._draw(camera, ids=True)
        raw = np.frombuffer(colour.read(), dtype="<u4").reshape(camera.resolution, camera.resolution)[::-1]
        error = self.ctx.error
        if error != "GL_NO_ERROR":
            raise RenderBackendError(f"OpenGL error while rendering: {error}")
        drawn = raw.astype(np.int64) - 1
        return np.where(drawn >= 0, self.order[np.maximum(drawn, 0)], -1)
