"""The octahedral impostor's reference runtime: one camera-facing card per part, drawn by a GL
program of its own (``shaders/octahedral.vert``, ``shaders/octahedral.frag``) into (h, w, 4)
uint8 images, top row first, as :class:`farfield.core.render.raster.MeshRenderer` draws geometry.

Per camera: the view direction ``v`` (from the part's centre towards the eye) picks the three
frames around it on the octahedral grid and their barycentric weights
(:func:`farfield.core.techniques.octahedral.mapping.blend_frames`); the card is the square
through the centre perpendicular to the line to the eye, ``r D / sqrt(D² - r²)`` a half side (it
covers the bounding sphere's silhouette from distance ``D``).  Per fragment the eye ray meets
each frame (its card plane, or with depth its height field: the parallax correction; between the
frame's and its opposite frame's surfaces where the grid has one) and the three colours are
blended, cut at a blended alpha of 0.5, and the hit point's depth written.  Where a pixel spans more
than a frame texel (far away), a frame's coverage is tested over the pixel's footprint instead of at
one point: a frame covers the pixel where any of its texels the footprint touches holds the part
(with depth: a surface at the ray's height or above), so a twig thinner than a pixel is not missed;
the card is grown by a pixel so that a part smaller than a pixel still meets a pixel centre.  A G-buffer renderer
blends the frames' normals, and where the impostor keeps them their materials, alike.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import moderngl
import numpy as np

from farfield.core.impostor.impostor import Impostor
from farfield.core.render.context import gl_context
from farfield.core.render.programs import SHADERS, context_cache, linear_texture, park_framebuffer, srgb_texture
from farfield.core.render.raster import Camera, eye_depth
from farfield.core.techniques.octahedral.instancing import grid_rotation
from farfield.core.techniques.octahedral.mapping import blend_frames

HERE = Path(__file__).resolve().parent / "shaders"
# A camera this close to the centre (in radii) or closer sees the card edge-on: it is drawn as a
# square of this many radii, covering every ray that leaves the sphere ahead.
INSIDE_HALF_SIDE = 1e3


def _source(name: str) -> str:
    text = (HERE / name).read_text()
    return text.replace('#include "colour.glsl"', (SHADERS / "colour.glsl").read_text())


def card_program(ctx: moderngl.Context) -> moderngl.Program:
    """The card's program, compiled once per context."""
    cache = context_cache(ctx)
    key = ("program", "octahedral.vert", None, "octahedral.frag", ())
    if key not in cache:
        cache[key] = ctx.program(vertex_shader=_source("octahedral.vert"), fragment_shader=_source("octahedral.frag"))
    return cache[key]


def card_corners(eye: np.ndarray, centre: np.ndarray, radius: float, pixel_angle: float = 0.0) -> np.ndarray:
    """(4, 3) float64 the card's corners relative to ``centre``, seen from ``eye`` (module docstring),
    grown by one pixel (``pixel_angle`` radians at the distance of the centre) so that a part smaller
    than a pixel still reaches every pixel centre its footprint test may cover.

    >>> (card_corners(np.array([0.0, -2.0, 0.0]), np.zeros(3), 1.0) + 0.0).round(4).tolist()[0]
    [-1.1547, 0.0, -1.1547]
    """
    offset = np.asarray(centre, dtype=np.float64) - np.asarray(eye, dtype=np.float64)
    distance = float(np.linalg.norm(offset))
    w = offset / distance
    hint = np.array([0.0, 0.0, 1.0]) if abs(w[2]) < 0.99 else np.array([0.0, 1.0, 0.0])
    a = np.cross(w, hint)
    a /= np.linalg.norm(a)
    b = np.cross(a, w)
    half = (
        radius * distance / math.sqrt(distance**2 - radius**2)
        if distance > radius * 1.0001
        else INSIDE_HALF_SIDE * radius
    ) + distance * pixel_angle
    return half * np.array([-a - b, a - b, a + b, -a + b])


class OctahedralRenderer:
    """An octahedral impostor (payload ``"octahedral"``) uploaded once, drawn from any :class:`Camera`.

    Use as a context manager; ``release()`` frees every GL resource it made.
    """

    def __init__(self, impostor: Impostor, gbuffer: bool = False, normal_pages: bool = True):
        """``gbuffer``: :meth:`render_normals` gives each pixel's world normal beside its colour, the
        blended normal pages' where ``normal_pages`` and the impostor keeps them, else the card's
        (facing the eye: a flat card's, as :mod:`farfield.core.quality.lit` compares); where the
        impostor keeps the material channel, ``materials`` is true and :meth:`render_material`
        gives its blended material pages too (as :meth:`MeshRenderer.render_material
        <farfield.core.render.raster.MeshRenderer.render_material>` gives the geometry's)."""
        payload = impostor.payload
        self.ctx = ctx = gl_context()
        self.payload = payload
        self.prog = card_program(ctx)
        self._owned: list = []
        self.atlases = [srgb_texture(ctx, page) for page in impostor.pages]
        for texture in self.atlases:
            texture.repeat_x = texture.repeat_y = False
        self.use_depth = payload.depth and "normal" in impostor.channels
        blank = np.zeros((1, 1, 4), np.uint8)  # no normal page: never read
        kept = "normal" in impostor.channels
        heights = impostor.channels["normal"] if kept else [blank] * len(impostor.pages)
        self.normals = bool(gbuffer)
        self.normal_mode = (1 if kept and normal_pages else 2) if gbuffer else 0
        self.heights = [linear_texture(ctx, page) for page in heights]
        for texture in self.heights:
            texture.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.sizes = [(float(page.shape[1]), float(page.shape[0])) for page in impostor.pages]
        # The material pages (ORM linear, emission sRGB: sampled as the colour is, bilinear), a black
        # page where nothing emits; the material G-buffer only.
        self.materials = bool(gbuffer) and "material" in impostor.channels
        if self.materials:
            emissive = impostor.channels.get("emissive") or [blank] * len(impostor.pages)
            self.orm = [linear_texture(ctx, page) for page in impostor.channels["material"]]
            self.emission = [srgb_texture(ctx, page) for page in emissive]
        else:
            self.orm, self.emission = [], []
        for texture in self.orm + self.emission:
            texture.repeat_x = texture.repeat_y = False
        # Each frame's opposite frame (direction -d), -1 where none: its depth bounds the columns.
        dots = payload.axes[:, 2] @ payload.axes[:, 2].T if payload.count else np.zeros((0, 0))
        best = np.argmin(dots, axis=1) if payload.count else np.zeros(0, np.int64)
        self.opposite = np.where(dots[np.arange(payload.count), best] < -1.0 + 1e-9, best, -1)
        self.grid_rotation = grid_rotation(payload)  # a moved instance's grid (instancing.py), else None
        self.vbo = ctx.buffer(reserve=4 * 3 * 4)
        self.ibo = ctx.buffer(np.array([0, 1, 2, 0, 2, 3], "<u4").tobytes())
        self.vao = ctx.vertex_array(self.prog, [(self.vbo, "3f", "in_position")], self.ibo)
        self._owned += [*self.atlases, *self.heights, *self.orm, *self.emission, self.vbo, self.ibo, self.vao]
        self._targets: dict[int, tuple] = {}

    def last_depth(self, camera: Camera) -> np.ndarray:
        """(h, w) float64 eye depth the card wrote in the last render from ``camera``
        (:func:`farfield.core.render.raster.eye_depth`)."""
        return eye_depth(self._target(camera.resolution)[1], camera)

    def _target(self, resolution: int):
        if resolution not in self._targets:
            colour = self.ctx.texture((resolution, resolution), 4)
            depth = self.ctx.depth_texture((resolution, resolution))
            targets = [colour] + ([self.ctx.texture((resolution, resolution), 4, dtype="f4")] if self.normals else [])
            if self.materials:  # occlusion, roughness, metallic; linear emission
                targets += [self.ctx.texture((resolution, resolution), 4, dtype="f4") for _ in range(2)]
            fbo = self.ctx.framebuffer(targets, depth)
            self._targets[resolution] = (colour, depth, fbo, *targets[1:])
            self._owned += [*targets, depth, fbo]
        return self._targets[resolution]

    def _draw(self, camera: Camera):
        colour, _, fbo, *_ = self._target(camera.resolution)
        fbo.use()
        self.ctx.viewport = (0, 0, camera.resolution, camera.resolution)
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        self.draw_card(camera)
        return colour

    def draw_card(self, camera: Camera) -> None:
        """Draw the card from ``camera`` into the framebuffer bound now (depth-tested against what
        it holds, nothing cleared): how a placement's runtime draws it among the scene's geometry
        (:class:`farfield.core.placement.runtime.PlacementRenderer`)."""
        p = self.payload
        centre = p.centre
        ctx = self.ctx
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
        view = np.asarray(camera.eye, dtype=np.float64) - centre
        grid_view = view if self.grid_rotation is None else self.grid_rotation.T @ view
        frames, weights = blend_frames(grid_view[None], p.n, p.hemisphere)
        frames, weights = frames[0], weights[0]
        t = math.tan(0.5 * camera.fov)
        self.vbo.write(card_corners(camera.eye, centre, p.radius, 2.0 * t / camera.resolution).astype("<f4").tobytes())
        prog = self.prog
        prog["half_tan"].value = (t, t)
        prog["depth_range"].value = (camera.near, camera.far)
        prog["eye_from_local"].write(camera.eye_matrices([centre])[0])
        prog["eye_local"].value = tuple(float(c) for c in view)
        axes = p.axes[frames]
        prog["f_right"].value = [tuple(map(float, a[0])) for a in axes]
        prog["f_up"].value = [tuple(map(float, a[1])) for a in axes]
        prog["f_dir"].value = [tuple(map(float, a[2])) for a in axes]
        prog["f_origin"].value = [tuple(map(float, p.texel[f])) for f in frames]
        prog["f_weight"].value = [float(w) for w in weights]
        prog["radius"].value = p.radius
        prog["frame_res"].value = float(p.frame_resolution)
        prog["pixel_angle"].value = 2.0 * t / camera.resolution
        pages = [int(p.page[f]) for f in frames]
        prog["f_size"].value = [self.sizes[page] for page in pages]
        prog["use_depth"].value = int(self.use_depth)
        prog["normal_mode"].value = self.normal_mode
        prog["material_mode"].value = int(self.materials)
        for slot, page in enumerate(pages):
            prog[f"atlas{slot}"].value = slot
            self.atlases[page].use(slot)
            prog[f"heights{slot}"].value = 3 + slot
            self.heights[page].use(3 + slot)
            if self.materials:
                prog[f"orm{slot}"].value = 9 + slot
                self.orm[page].use(9 + slot)
                prog[f"emission{slot}"].value = 12 + slot
                self.emission[page].use(12 + slot)
        opposite = [int(self.opposite[f]) for f in frames]
        two_sided = [o >= 0 and self.use_depth for o in opposite]
        prog["o_valid"].value = [int(v) for v in two_sided]
        other = [o if v else f for o, v, f in zip(opposite, two_sided, frames)]
        prog["o_right"].value = [tuple(map(float, p.axes[o, 0])) for o in other]
        prog["o_up"].value = [tuple(map(float, p.axes[o, 1])) for o in other]
        prog["o_origin"].value = [tuple(map(float, p.texel[o])) for o in other]
        prog["o_size"].value = [self.sizes[int(p.page[o])] for o in other]
        for slot, o in enumerate(other):
            prog[f"opposite{slot}"].value = 6 + slot
            self.heights[int(p.page[o])].use(6 + slot)
        self.vao.render(moderngl.TRIANGLES)

    def render(self, camera: Camera) -> np.ndarray:
        """(h, w, 4) uint8 image, top row first; alpha 255 where the impostor shows."""
        colour = self._draw(camera)
        image = np.frombuffer(colour.read(), dtype=np.uint8).reshape(camera.resolution, camera.resolution, 4)
        error = self.ctx.error
        if error != "GL_NO_ERROR":
            from farfield.core.errors import RenderBackendError

            raise RenderBackendError(f"OpenGL error while rendering an octahedral impostor: {error}")
        return image[::-1].copy()

    def render_normals(self, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
        """The (h, w, 4) uint8 image (:meth:`render`) and the (h, w, 3) float32 world normals of the
        same pixels (zero where nothing was drawn), top row first; a renderer made with ``gbuffer=True``."""
        if not self.normals:
            raise ValueError("this renderer was made without normals")
        image = self.render(camera)
        normal = self._targets[camera.resolution][3]
        data = np.frombuffer(normal.read(), dtype=np.float32).reshape(camera.resolution, camera.resolution, 4)
        return image, data[::-1, :, :3].copy()

    def render_material(self, camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The (h, w, 4) uint8 image, (h, w, 3) float32 normals (:meth:`render_normals`) and (h, w, 6)
        float32 material of the same pixels, top row first: occlusion, roughness, metallic, linear
        emitted RGB, the three frames' material pages blended as their colours (zero where nothing
        was drawn); a renderer whose impostor keeps the material channel, made with ``gbuffer=True``."""
        if not self.materials:
            raise ValueError("this renderer was made without materials (a G-buffer of an impostor that keeps them)")
        image, normals = self.render_normals(camera)
        size = camera.resolution
        _, _, _, _, orm, emission = self._targets[size]
        material = np.frombuffer(orm.read(), dtype=np.float32).reshape(size, size, 4)[::-1, :, :3]
        light = np.frombuffer(emission.read(), dtype=np.float32).reshape(size, size, 4)[::-1, :, :3]
        return image, normals, np.concatenate([material, light], axis=-1)

    def frame_seconds(self, camera: Camera) -> float:
        """Seconds to draw one frame from ``camera`` and wait for it (no read-back)."""
        self.ctx.finish()
        start = time.perf_counter()
        self._draw(camera)
        self.ctx.finish()
        return time.perf_counter() - start

    @property
    def triangle_count(self) -> int:
        """Triangles drawn per frame: the card's two."""
        return 2

    def release(self) -> None:
        park_framebuffer(self.ctx)
        for resource in self._owned:
            resource.release()
        self._owned.clear()
        self._targets.clear()

    def __enter__(self) -> OctahedralRenderer:
        return self

    def __exit__(self, *exc) -> None:
        self.release()
