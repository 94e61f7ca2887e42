"""The deferred shading pass: an (h, w) G-buffer (sRGB base colour, world shading normals) lit on
the GL, one full-screen triangle, as :func:`farfield.core.quality.lighting.shade` lights it in numpy.

A runtime that draws lit impostors shades this way: the G-buffer pass draws the geometry (the
impostor's quads with their normal maps, :meth:`MeshRenderer.render_normals
<farfield.core.render.raster.MeshRenderer.render_normals>`), this pass lights every pixel once.
Its cost depends on the pixels, not on what was drawn, so the full scene and its impostors pay
alike.  The walkthrough (:mod:`farfield.core.quality.walkthrough`) times it to say what the
lit draw costs on the GL; the figures still come from ``shade`` (float64), which this pass agrees
with to about a level (float32 arithmetic, the GL's rounding of the output; ``tests/test_walkthrough_lit.py``).
Shaders: ``deferred.vert``, ``deferred.frag`` (roughness and metallic uniform, ``geometryRoughness`` 0).
"""

from __future__ import annotations

import math
import time

import moderngl
import numpy as np

from farfield.core.errors import RenderBackendError
from farfield.core.quality.dfg import TABLE
from farfield.core.quality.lighting import AMBIENT, DirectionalLight
from farfield.core.render.context import gl_context
from farfield.core.render.programs import park_framebuffer, program


class DeferredShader:
    """The pass at one ``resolution``: :meth:`load` a G-buffer, then :meth:`shade` it (read back) or
    time it (:meth:`frame_seconds`).  A context manager; ``release()`` frees what it made."""

    def __init__(self, resolution: int, roughness: float = 1.0, metallic: float = 0.0):
        self.ctx = ctx = gl_context()
        self.resolution = n = int(resolution)
        self.prog = program(ctx, "deferred.vert", "deferred.frag")
        self.vao = ctx.vertex_array(self.prog, [])
        self.albedo = ctx.texture((n, n), 4)
        self.normals = ctx.texture((n, n), 4, dtype="f4")
        self.lut = ctx.texture(TABLE.shape[1::-1], 2, np.ascontiguousarray(TABLE, dtype="f4").tobytes(), dtype="f4")
        self.lut.filter = (moderngl.LINEAR, moderngl.LINEAR)
        self.lut.repeat_x = self.lut.repeat_y = False  # clamp to edge, as three.js samples its table
        for texture in (self.albedo, self.normals):
            texture.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.target = ctx.texture((n, n), 4)
        self.fbo = ctx.framebuffer([self.target])
        self._owned = [self.vao, self.albedo, self.normals, self.lut, self.target, self.fbo]
        self.prog["albedo"].value, self.prog["normals"].value, self.prog["dfg_lut"].value = 0, 1, 2
        self.prog["roughness"].value, self.prog["metallic"].value = float(roughness), float(metallic)

    def load(self, image: np.ndarray, normals: np.ndarray) -> None:
        """Upload a G-buffer: ``image`` (n, n, 4) uint8 and ``normals`` (n, n, 3) float, top row first."""
        n = self.resolution
        if image.shape[:2] != (n, n) or normals.shape[:2] != (n, n):
            raise ValueError(f"a G-buffer of {n} x {n} pixels, got {image.shape[:2]} and {normals.shape[:2]}")
        rgba = np.zeros((n, n, 4), dtype="f4")
        rgba[..., :3] = normals
        self.albedo.write(np.ascontiguousarray(image[::-1], dtype=np.uint8).tobytes())
        self.normals.write(np.ascontiguousarray(rgba[::-1]).tobytes())

    def _draw(self, camera, light: DirectionalLight, ambient) -> None:
        prog, t = self.prog, math.tan(0.5 * camera.fov)
        for name, value in (("forward", camera.forward), ("right", camera.right), ("up", camera.up),
                            ("to_light", light.direction), ("ambient", ambient),
                            ("irradiance", np.asarray(light.colour, dtype=np.float64) * float(light.intensity))):  # fmt: skip
            prog[name].value = tuple(float(x) for x in np.asarray(value, dtype=np.float64))
        prog["half_tan"].value = (t, t)
        prog["offset"].value = tuple(float(x) for x in camera.offset)
        self.fbo.use()
        self.ctx.viewport = (0, 0, self.resolution, self.resolution)
        self.ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND | moderngl.CULL_FACE)
        self.albedo.use(0)
        self.normals.use(1)
        self.lut.use(2)
        self.vao.render(moderngl.TRIANGLES, vertices=3)

    def shade(self, camera, light: DirectionalLight, ambient=AMBIENT) -> np.ndarray:
        """(n, n, 3) uint8 sRGB: the loaded G-buffer lit by ``light`` and ``ambient`` as seen by ``camera``."""
        self._draw(camera, light, ambient)
        out = np.frombuffer(self.target.read(), dtype=np.uint8).reshape(self.resolution, self.resolution, 4)
        error = self.ctx.error
        if error != "GL_NO_ERROR":
            raise RenderBackendError(f"OpenGL error while shading: {error}")
        return out[::-1, :, :3].copy()

    def frame_seconds(self, camera, light: DirectionalLight, ambient=AMBIENT) -> float:
        """Seconds to shade the loaded G-buffer and wait for the GL to finish (no read-back)."""
        self.ctx.finish()
        start = time.perf_counter()
        self._draw(camera, light, ambient)
        self.ctx.finish()
        return time.perf_counter() - start

    def release(self) -> None:
        park_framebuffer(self.ctx)
        for resource in self._owned:
            resource.release()
        self._owned.clear()

    def __enter__(self) -> DeferredShader:
        return self

    def __exit__(self, *exc) -> None:
        self.release()
