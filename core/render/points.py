"""One-pixel points drawn with a depth test: the preview of a point-based impostor (seed 001 §5.3,
"a lower quality, but faster preview ... using only one color per point").

Each point lands in the pixel that contains its projection (a one-pixel point's footprint) with the
colour it carries; nearer points hide farther ones.  The camera, targets and read-back are
:class:`core.render.raster.MeshRenderer`'s, so its images compare pixel for pixel with the mesh's.
"""

from __future__ import annotations

import moderngl
import numpy as np

from farfield.core.render.programs import program
from farfield.core.render.raster import Camera, MeshRenderer


class PointRenderer(MeshRenderer):
    """``positions`` (n, 3) float64 world and ``colours`` (n, 4) uint8 sRGB, uploaded once."""

    def __init__(self, positions: np.ndarray, colours: np.ndarray):
        super().__init__([])
        positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        colours = np.asarray(colours, dtype=np.uint8).reshape(-1, 4)
        if positions.shape[0] != colours.shape[0]:
            raise ValueError(f"{positions.shape[0]} positions but {colours.shape[0]} colours")
        self.count = int(positions.shape[0])
        self.origin = 0.5 * (positions.min(axis=0) + positions.max(axis=0)) if self.count else np.zeros(3)
        self.points_program = program(self.ctx, "points.vert", "points.frag")
        data = np.concatenate([(positions - self.origin).astype("<f4"), colours.astype("<f4") / 255.0], axis=1)
        self._vbo = self.ctx.buffer(np.ascontiguousarray(data, dtype="<f4").tobytes() if self.count else b"\0" * 28)
        self._vao = self.ctx.vertex_array(self.points_program, [(self._vbo, "3f 4f", "in_position", "in_color")])
        self._owned += [self._vbo, self._vao]

    def _draw(self, camera: Camera):
        colour = super()._draw(camera)  # clears colour and depth
        if self.count:
            prog = self.points_program
            t = float(np.tan(0.5 * camera.fov))
            prog["half_tan"].value = (t, t)
            prog["depth_range"].value = (camera.near, camera.far)
            prog["eye_from_local"].write(camera.eye_matrix(self.origin).tobytes())
            self.ctx.enable(moderngl.PROGRAM_POINT_SIZE)
            self._vao.render(moderngl.POINTS, vertices=self.count)
            self.ctx.disable(moderngl.PROGRAM_POINT_SIZE)
        return colour
