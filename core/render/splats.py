"""The GPU drawer of a warped layered depth image (seed 004 §4), composited with geometry.

The geometry is drawn first, as :class:`farfield.core.render.raster.MeshRenderer` draws it.  Then every LDI
sample is drawn as a depth-tested square point, as wide as its LDI pixel's footprint seen from the
camera, in whole pixels (``shaders/splats.vert``; the same widths as the CPU warp,
:mod:`farfield.core.ldi.warp`).  Splat pixels get alpha 254 and geometry 255, so
:meth:`SplatRenderer.render` can run the 3x3 pass (:func:`farfield.core.ldi.warp.fill_pin_holes`) on the
pixels the splats left empty next to splats, after read-back.
"""

from __future__ import annotations

import math

import moderngl
import numpy as np

from farfield.core.ldi.image import LayeredDepthImage
from farfield.core.ldi.warp import fill_pin_holes
from farfield.core.render.points import material_columns
from farfield.core.render.programs import program
from farfield.core.render.raster import Camera, MeshRenderer
from farfield.core.scene import SceneObject

SPLAT_ALPHA = 254


def ldi_splats(ldi: LayeredDepthImage) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """((m, 3) world positions, (m, 4) uint8 colours, (m,) world footprint widths) of an LDI's samples."""
    positions, index = ldi.samples()
    colour = (
        ldi.colour[index[:, 0], index[:, 1], index[:, 2]]
        if ldi.colour is not None
        else np.full((positions.shape[0], 4), 255, np.uint8)
    )
    pixel = 2.0 * math.tan(0.5 * ldi.camera.fov) / ldi.camera.resolution
    return positions, colour, pixel * ldi.depth[index[:, 0], index[:, 1], index[:, 2]]


def ldi_splat_normals(ldi: LayeredDepthImage) -> np.ndarray:
    """(m, 3) float64 world normals of an LDI's samples (in :func:`ldi_splats`' order); the LDI must keep them."""
    index = np.argwhere(np.isfinite(ldi.depth))
    return ldi.normal[index[:, 0], index[:, 1], index[:, 2]]


class SplatRenderer(MeshRenderer):
    """``objects`` drawn as geometry, then the ``ldis``' samples and the ``splats`` (positions, colours,
    footprint widths: :func:`ldi_splats`'s arrays) as splats (module docstring).

    ``gbuffer=True`` makes a G-buffer renderer for the lit evaluation (:meth:`render_normals`): the
    geometry's shading normals, and each splat's pixels its sample's normal where every LDI keeps
    normals (:attr:`~farfield.core.ldi.image.LayeredDepthImage.normal`; ``splats`` then have none),
    else the normal of a sprite facing the viewer (minus the camera's forward axis: flat cards).

    ``materials`` (with ``gbuffer``): ((m, 4) uint8 ORM bytes, (m, 4) uint8 sRGB emission bytes or
    None) of the m splats in the order drawn (the ``ldis``' samples, :func:`ldi_splats`' order, then
    ``splats``), makes a material G-buffer (``materials`` true, :meth:`render_material`, the
    contract of :meth:`~farfield.core.render.raster.MeshRenderer.render_material`); the geometry is
    drawn with its own material."""

    def __init__(self, objects: list[SceneObject] | tuple[SceneObject, ...], ldis: list[LayeredDepthImage] | tuple = (),
                 splats: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None, gbuffer: bool = False,
                 materials: tuple[np.ndarray, np.ndarray | None] | None = None):  # fmt: skip
        if materials is not None and not gbuffer:
            raise ValueError("splat materials are drawn by a G-buffer renderer only (gbuffer=True)")
        super().__init__(objects, normals=gbuffer, materials=materials is not None)
        parts = [ldi_splats(ldi) for ldi in ldis] + ([splats] if splats is not None else [])
        positions = np.concatenate([p[0] for p in parts]) if parts else np.zeros((0, 3))
        colours = np.concatenate([p[1] for p in parts]) if parts else np.zeros((0, 4), np.uint8)
        extents = np.concatenate([p[2] for p in parts]) if parts else np.zeros(0)
        self.count = int(positions.shape[0])
        self.origin = 0.5 * (positions.min(axis=0) + positions.max(axis=0)) if self.count else np.zeros(3)
        own_normals = gbuffer and bool(ldis) and splats is None and all(ldi.normal is not None for ldi in ldis)
        defines = ("NORMALS",) * gbuffer + ("SPLAT_NORMALS",) * own_normals
        columns = [positions - self.origin, colours.astype(np.float64) / 255.0, extents[:, None]]
        layout, names = "3f 4f 1f", ["in_position", "in_color", "in_extent"]
        if own_normals:
            columns.append(np.concatenate([ldi_splat_normals(ldi) for ldi in ldis]))
            layout, names = layout + " 3f", names + ["in_normal"]
        if materials is not None:
            columns += material_columns(materials[0], materials[1], self.count)
            layout, names = layout + " 3f 3f", names + ["in_material", "in_emissive"]
            defines += ("MATERIAL",)
        self.splat_program = program(self.ctx, "splats.vert", "splats.frag", defines=defines)
        data = np.concatenate(columns, axis=1)
        floats = data.shape[1]
        self._vbo = self.ctx.buffer(
            np.ascontiguousarray(data, dtype="<f4").tobytes() if self.count else b"\0" * 4 * floats
        )
        self._vao = self.ctx.vertex_array(self.splat_program, [(self._vbo, layout, *names)])
        self._owned += [self._vbo, self._vao]

    def _draw(self, camera: Camera):
        colour = super()._draw(camera)  # clears colour and depth, draws the geometry
        if not self.count:
            return colour
        prog = self.splat_program
        t = math.tan(0.5 * camera.fov)
        prog["half_tan"].value = (t, t)
        prog["depth_range"].value = (camera.near, camera.far)
        prog["eye_from_local"].write(camera.eye_matrix(self.origin).tobytes())
        prog["pixel_tan"].value = 2.0 * t / camera.resolution
        if prog.get("facing", None) is not None:  # a G-buffer without sample normals: sprites facing the viewer
            prog["facing"].value = tuple(float(-x) for x in camera.forward)
        self.ctx.enable(moderngl.PROGRAM_POINT_SIZE)
        try:
            self._vao.render(moderngl.POINTS, vertices=self.count)
        finally:
            self.ctx.disable(moderngl.PROGRAM_POINT_SIZE)
        return colour

    def render_raw(self, camera: Camera) -> np.ndarray:
        """The frame before the 3x3 pass: splat pixels have alpha 254."""
        return super().render(camera)

    def render(self, camera: Camera) -> np.ndarray:
        """The frame after the 3x3 pass, alpha 255 wherever something was drawn."""
        image = self.render_raw(camera)
        splat = image[..., 3] == SPLAT_ALPHA
        empty = image[..., 3] == 0
        filled = fill_pin_holes(image, splat, empty=empty)
        filled[..., 3] = np.where(empty & (filled[..., 3] == 0), 0, 255)
        return filled

    def render_normals(self, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
        """(:meth:`render`'s image, (h, w, 3) float32 world normals): the 3x3 pass fills a pin hole's
        normal with the renormalised mean of its splat neighbours', as it fills its colour."""
        image, normals, _, _ = self._gbuffer(camera)
        return image, normals

    def render_material(self, camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`render_normals` and the (h, w, 6) float32 material of the same pixels (occlusion,
        roughness, metallic, linear emitted RGB; zero where nothing was drawn): the 3x3 pass fills a
        pin hole's material with the mean of its splat neighbours'.  A renderer made with
        ``materials`` only."""
        if not self.materials:
            raise ValueError("this renderer was made without materials")
        image, normals, splat, holes = self._gbuffer(camera)
        size = camera.resolution
        _, _, _, _, orm, light = self._targets[size]
        material = np.concatenate(
            [np.frombuffer(t.read(), dtype=np.float32).reshape(size, size, 4)[::-1, :, :3] for t in (orm, light)],
            axis=-1,
        )
        if holes.any():
            total = np.zeros(material.shape, dtype=np.float64)
            count = np.zeros(splat.shape)
            pad = np.pad(np.where(splat[..., None], material, 0.0), ((1, 1), (1, 1), (0, 0)))
            hits = np.pad(splat, 1).astype(np.float64)
            h, w = splat.shape
            for dr in (-1, 0, 1):
                for dc in (-1, 0, 1):
                    total += pad[1 + dr : 1 + dr + h, 1 + dc : 1 + dc + w]
                    count += hits[1 + dr : 1 + dr + h, 1 + dc : 1 + dc + w]
            material[holes] = total[holes] / np.maximum(count[holes], 1.0)[:, None]
        return image, normals, material

    def _gbuffer(self, camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(:meth:`render_normals`' image and normals, (h, w) bool the splats' pixels, (h, w) bool
        the pin holes the 3x3 pass filled)."""
        if not self.normals:
            raise ValueError("this renderer was made without normals")
        image = self.render_raw(camera)
        raw = self._targets[camera.resolution][3]
        normals = np.frombuffer(raw.read(), dtype=np.float32).reshape(camera.resolution, camera.resolution, 4)
        normals = normals[::-1, :, :3].copy()
        splat = image[..., 3] == SPLAT_ALPHA
        empty = image[..., 3] == 0
        filled = fill_pin_holes(image, splat, empty=empty)
        holes = empty & (filled[..., 3] > 0)
        if holes.any():
            total = np.zeros_like(normals, dtype=np.float64)
            pad = np.pad(np.where(splat[..., None], normals, 0.0), ((1, 1), (1, 1), (0, 0)))
            h, w = splat.shape
            for dr in (-1, 0, 1):
                for dc in (-1, 0, 1):
                    total += pad[1 + dr : 1 + dr + h, 1 + dc : 1 + dc + w]
            length = np.linalg.norm(total[holes], axis=1, keepdims=True)
            normals[holes] = total[holes] / np.maximum(length, 1e-12)
        filled[..., 3] = np.where(empty & (filled[..., 3] == 0), 0, 255)
        return filled, normals, splat, holes
