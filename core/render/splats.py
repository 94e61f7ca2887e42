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


class SplatRenderer(MeshRenderer):
    """``objects`` drawn as geometry, then the ``ldis``' samples and the ``splats`` (positions, colours,
    footprint widths: :func:`ldi_splats`'s arrays) as splats (module docstring)."""

    def __init__(self, objects: list[SceneObject] | tuple[SceneObject, ...], ldis: list[LayeredDepthImage] | tuple = (),
                 splats: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None):  # fmt: skip
        super().__init__(objects)
        parts = [ldi_splats(ldi) for ldi in ldis] + ([splats] if splats is not None else [])
        positions = np.concatenate([p[0] for p in parts]) if parts else np.zeros((0, 3))
        colours = np.concatenate([p[1] for p in parts]) if parts else np.zeros((0, 4), np.uint8)
        extents = np.concatenate([p[2] for p in parts]) if parts else np.zeros(0)
        self.count = int(positions.shape[0])
        self.origin = 0.5 * (positions.min(axis=0) + positions.max(axis=0)) if self.count else np.zeros(3)
        self.splat_program = program(self.ctx, "splats.vert", "splats.frag")
        data = np.concatenate([positions - self.origin, colours.astype(np.float64) / 255.0, extents[:, None]], axis=1)
        self._vbo = self.ctx.buffer(np.ascontiguousarray(data, dtype="<f4").tobytes() if self.count else b"\0" * 32)
        self._vao = self.ctx.vertex_array(
            self.splat_program, [(self._vbo, "3f 4f 1f", "in_position", "in_color", "in_extent")]
        )
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
