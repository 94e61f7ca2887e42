"""Depth peeling on the GL: every surface a camera's pixel-centre rays meet, nearest first.

Pass k draws the objects with the depth test on and discards every fragment not strictly behind
pass k-1's surface at its pixel (``peel.frag``), so it keeps the k-th surface along each ray.  Back
faces count (no culling); alpha-cut texels do not (glTF's MASK rule).  Passes stop when one
draws nothing.  Surfaces closer than the depth buffer's 24-bit resolution of [near, far] at a
pixel merge into one: give a tight depth range.

``touching=True`` peels instead the pixels each triangle touches without covering their centre
(``peel_touch.geom`` / ``.frag``: the triangle's screen rectangle, an exact triangle-square overlap
test, and as the sample the triangle's point whose projection is nearest the centre), so geometry
thinner than a pixel, which pixel-centre rays can miss, still leaves a sample in every pixel it
crosses (:func:`farfield.core.ldi.image.record_ldi` merges the two).  An alpha-cut triangle's
touched sample stays when the texture passes the cut at any point of a fine grid over the
triangle's part of the pixel, also where it covers the pixel's centre on a cut texel, so a needle
the centre ray meets beside its opaque texels is kept.  A triangle reaching behind the camera
(eye depth <= 0 at a corner) adds no touched samples: give a camera that has the geometry in front,
as the LDI cameras of a point impostor do.
"""

from __future__ import annotations

import math
import time

import moderngl
import numpy as np

from farfield.core.errors import LayerPlanError, RenderBackendError
from farfield.core.render.context import gl_context
from farfield.core.render.programs import park_framebuffer, program, set_material
from farfield.core.render.raster import Camera, upload
from farfield.core.scene import SceneObject


def peel(
    objects: list[SceneObject] | tuple[SceneObject, ...],
    camera: Camera,
    max_layers: int = 256,
    touching: bool = False,
    centre: np.ndarray | None = None,
    same_surface: float = 0.0,
    truncate: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """((layers, h, w, 3) float64 hits, (layers, h, w, 4) uint8 colours) of ``camera``'s rays,
    nearest first, rows top first: (eye depth along the camera's forward axis, object index,
    primitive index), NaN / -1 / -1 where a ray has fewer surfaces, and the surface's colour at
    the hit as the mesh shader draws it (sRGB-encoded, alpha 255; 0 where none).  More than ``max_layers`` surfaces on one ray is an error,
    unless ``truncate``: then the nearest ``max_layers`` are returned (``max_layers=1``: a plain image with depth and ids).
    ``touching``: the samples of touched, not covered, pixels instead (module docstring), skipping
    those within ``same_surface`` times their depth of one of the ``centre`` eye depths (layers, h,
    w; NaN where none) of their pixel or of the touched sample peeled before them there.
    (One camera; :class:`Peeler` uploads the objects once for many.)"""
    with Peeler(objects, touching) as peeler:
        return peeler.peel(camera, max_layers, centre, same_surface, truncate)


class Peeler:
    """``objects`` uploaded once to the process's context and peeled from any number of cameras
    (:meth:`peel`, the rules of :func:`peel`); a context manager that frees what it made."""

    def __init__(self, objects: list[SceneObject] | tuple[SceneObject, ...], touching: bool = False):
        self.ctx = ctx = gl_context()
        self.touching = bool(touching)
        if touching:
            self.prog = program(ctx, "peel_touch.vert", "peel_touch.frag", "peel_touch.geom")
        else:
            self.prog = program(ctx, "peel.vert", "peel.frag")
        self._owned: list = []
        textures: dict = {}
        self._draws = []
        self._by_size: dict = {}  # render targets per image size
        self.seconds = {"draw": 0.0, "read": 0.0}  # the passes' draw calls (to their end), and the rest of peel
        try:
            for index, obj in enumerate(objects):
                origin = 0.5 * (obj.bounds[0] + obj.bounds[1])
                vao, texture = upload(ctx, self.prog, obj, origin, textures, self._owned)
                self._draws.append((index, obj, origin, vao, texture))
        except BaseException:
            self.release()
            raise

    def _targets(self, size: tuple[int, int]) -> tuple[list, list, list]:
        """(hits, colours, framebuffers) of ``size``: two of each, made once per size and kept."""
        if size not in self._by_size:
            ctx = self.ctx
            hits = [ctx.texture(size, 4, dtype="f4") for _ in range(2)]
            colours = [ctx.texture(size, 4) for _ in range(2)]
            depth = ctx.depth_texture(size)
            for texture in hits:
                texture.filter = (moderngl.NEAREST, moderngl.NEAREST)
            framebuffers = [ctx.framebuffer([h, c], depth) for h, c in zip(hits, colours)]
            self._owned += [*hits, *colours, depth, *framebuffers]
            self._by_size[size] = (hits, colours, framebuffers)
        return self._by_size[size]

    def __enter__(self) -> Peeler:
        return self

    def __exit__(self, *exc) -> None:
        self.release()

    def release(self) -> None:
        park_framebuffer(self.ctx)
        for resource in self._owned:
            resource.release()
        self._owned = []
        self._draws = []
        self._by_size = {}

    def peel(
        self,
        camera: Camera,
        max_layers: int = 256,
        centre: np.ndarray | None = None,
        same_surface: float = 0.0,
        truncate: bool = False,
    ) -> tuple[np.ndarray, np.ndarray]:
        """:func:`peel` of the uploaded objects from ``camera``."""
        called = time.perf_counter()
        drew = self.seconds["draw"]
        try:
            return self._peel(camera, max_layers, centre, same_surface, truncate)
        finally:
            self.seconds["read"] += time.perf_counter() - called - (self.seconds["draw"] - drew)

    def _peel(self, camera, max_layers, centre, same_surface, truncate) -> tuple[np.ndarray, np.ndarray]:
        ctx, prog, touching, draws = self.ctx, self.prog, self.touching, self._draws
        owned: list = []
        size = (camera.resolution, camera.resolution)
        layers, shades = [], []
        try:
            hits, colours, framebuffers = self._targets(size)
            hits[1].write(np.full(size + (4,), -1.0, dtype="f4").tobytes())  # "previous" of the first pass
            t = math.tan(0.5 * camera.fov)
            prog["half_tan"].value = (t, t)
            prog["depth_range"].value = (camera.near, camera.far)
            prog["previous"].value = 1
            if touching:
                prog["pixel_ndc"].value = 2.0 / camera.resolution
                prog["resolution"].value = float(camera.resolution)
                layers_in = 0 if centre is None else int(centre.shape[0])
                stack = np.full((max(layers_in, 1), size[1], size[0]), -1.0, dtype="f4")
                if layers_in:
                    stack[:layers_in] = np.where(np.isfinite(centre), centre, -1.0)[:, ::-1]  # GL rows bottom first
                depths = ctx.texture_array(
                    (size[0], size[1], stack.shape[0]), 1, np.ascontiguousarray(stack).tobytes(), dtype="f4"
                )
                depths.filter = (moderngl.NEAREST, moderngl.NEAREST)
                owned.append(depths)
                depths.use(2)
                prog["centre_depths"].value = 2
                prog["centre_layers"].value = layers_in
                prog["same_surface"].value = float(same_surface)
            ctx.enable(moderngl.DEPTH_TEST)
            ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
            matrices = camera.eye_matrices([origin for _, _, origin, _, _ in draws])
            current = 0
            while True:
                previous = 1 - current
                framebuffers[current].use()
                ctx.viewport = (0, 0, *size)
                # A ray without a surface in this pass has none behind either: r = 2 (beyond any
                # window depth) stops it in the next pass.
                framebuffers[current].clear(
                    2.0, 0.0, 0.0, 0.0, depth=1.0
                )  # both attachments: the colour's r saturates, a = 0
                hits[previous].use(1)
                start = time.perf_counter()
                for (index, obj, _, vao, texture), matrix in zip(draws, matrices):
                    prog["eye_from_local"].write(matrix)
                    prog["object_index"].value = float(index)
                    set_material(prog, obj, texture)
                    vao.render(moderngl.TRIANGLES)
                ctx.finish()
                drawn_at = time.perf_counter()
                self.seconds["draw"] += drawn_at - start
                layer = np.frombuffer(hits[current].read(), dtype="f4").reshape(size[1], size[0], 4)[::-1]
                colour = np.frombuffer(colours[current].read(), dtype=np.uint8).reshape(size[1], size[0], 4)[::-1]
                error = ctx.error
                if error != "GL_NO_ERROR":
                    raise RenderBackendError(f"OpenGL error while peeling depth layers: {error}")
                drawn = layer[..., 3] > 0.0
                if not drawn.any():
                    break
                if len(layers) == max_layers:
                    raise LayerPlanError(
                        f"more than {max_layers} surfaces along one ray of a {size[0]}-pixel layered depth image (raise max_layers)"
                    )
                out = np.full(layer.shape[:2] + (3,), -1.0)
                out[..., 0] = np.where(drawn, layer[..., 1], np.nan)
                out[..., 1] = np.where(drawn, layer[..., 2], -1.0)
                out[..., 2] = np.where(drawn, layer[..., 3] - 1.0, -1.0)
                layers.append(out)
                shades.append(np.where(drawn[..., None], colour, 0).astype(np.uint8))
                if truncate and len(layers) == max_layers:
                    break  # the nearest max_layers are all that was asked for: no pass to look past them
                current = previous
        finally:
            park_framebuffer(ctx)
            for resource in owned:
                resource.release()
        if not layers:
            return np.zeros((0, size[1], size[0], 3)), np.zeros((0, size[1], size[0], 4), dtype=np.uint8)
        return np.stack(layers), np.stack(shades)
