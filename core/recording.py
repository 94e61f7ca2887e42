"""Gap-free layer recording: a scene and a LayerPlan in, (k, h, w, 4) uint8 RGBA layers out.

Seed 000 §3.3.2.  Every layer is rendered from the plan's reference viewpoint with a frustum that
tightly encloses the part, clipped to the layer's closed depth slab.  Coverage is conservative: a
texel is written when its closed square meets the clipped triangle, not only when its centre is
covered, so sub-texel geometry is never lost and a clipping edge on a border is written into both
adjacent layers with the same texels (the closed slabs share it), diagonals included.  The thesis
did this with explicit clipping, outlines, points and a 2x2 fix-up pass; farfield clips in a
geometry shader and tests the texel square against the clipped polygon exactly in the fragment
shader (shaders/slab.*), which gives the same guarantee in one pass.

Each layer draws only the triangles whose depth range meets its slab: triangles are bucketed once
by layer (cost O(triangles + layers + spans)), never drawn for every layer.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import moderngl
import numpy as np

from core.layers import LayerPlan
from core.render.alpha_mips import max_alpha_levels
from core.render.context import gl_context
from core.render.programs import park_framebuffer, program
from core.scene import Scene, SceneObject

@dataclass(frozen=True, slots=True)
class RecordedLayers:
    """The recorded layers of one plan, nearest first."""

    rgba: np.ndarray  # (k, h, w, 4) uint8; row 0 is the bottom image row (GL order), alpha 255 = covered
    eye_borders: np.ndarray  # (k + 1,) float64 slab borders, eye depth from the reference viewpoint
    drawn_triangles: np.ndarray  # (k,) int64 triangles drawn per layer

    @property
    def coverage(self) -> np.ndarray:
        """(k, h, w) bool: texels written in each layer."""
        return self.rgba[..., 3] > 0


def eye_matrix(plan: LayerPlan, origin: np.ndarray) -> np.ndarray:
    """(4, 4) float32 column-major matrix from object-local coordinates (relative to ``origin``,
    (3,) float64 world) to the plan's eye frame.  Built in float64 so that continental offsets
    cancel before the narrowing."""
    rot = np.stack([plan.u, plan.v, plan.axis])  # (3, 3) float64
    m = np.eye(4)
    m[:3, :3] = rot
    m[:3, 3] = rot @ (origin - plan.reference_viewpoint)
    return m.T.astype("<f4")  # GL expects column-major


def layer_buckets(eye_depth: np.ndarray, faces: np.ndarray, eye_borders: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Group triangles by the layers whose closed slab their depth range meets.

    Parameters
    ----------
    eye_depth : (v,) float64 vertex depths from the reference viewpoint.
    faces : (f, 3) int64.
    eye_borders : (k + 1,) float64 ascending slab borders.

    Returns
    -------
    order : (n,) int64 triangle indices, grouped by layer (a triangle spanning layers repeats).
    offsets : (k + 1,) int64; layer i draws ``order[offsets[i]:offsets[i+1]]``.
    """
    k = eye_borders.shape[0] - 1
    z = eye_depth[faces]
    zmin, zmax = z.min(axis=1), z.max(axis=1)
    first = np.searchsorted(eye_borders[1:], zmin, side="left")
    last = np.searchsorted(eye_borders[:-1], zmax, side="right") - 1
    first, last = np.clip(first, 0, k - 1), np.clip(last, 0, k - 1)
    keep = (zmax >= eye_borders[0]) & (zmin <= eye_borders[-1]) & (first <= last)
    tri = np.flatnonzero(keep)
    spans = (last - first + 1)[tri]
    repeated = np.repeat(tri, spans)
    starts = np.repeat(np.cumsum(spans) - spans, spans)
    layer = np.repeat(first[tri], spans) + (np.arange(repeated.shape[0]) - starts)
    order = np.argsort(layer, kind="stable")
    offsets = np.concatenate([[0], np.cumsum(np.bincount(layer, minlength=k))])
    return repeated[order].astype(np.int64), offsets.astype(np.int64)


def _object_buffers(ctx: moderngl.Context, obj: SceneObject, origin: np.ndarray):
    local = (obj.vertices - origin).astype("<f4")
    uv = (obj.uv if obj.uv is not None else np.zeros((obj.vertices.shape[0], 2))).astype("<f4")
    if obj.vertex_colors is not None:
        colour = obj.vertex_colors.astype("<f4") / 255.0
    else:
        colour = np.ones((obj.vertices.shape[0], 4), dtype="<f4")
    interleaved = np.concatenate([local, uv, colour], axis=1)
    vbo = ctx.buffer(np.ascontiguousarray(interleaved).tobytes())
    texture = alpha = None
    if obj.texture is not None:
        image = np.ascontiguousarray(obj.texture[::-1])  # top row first -> GL's bottom row first
        texture = ctx.texture((image.shape[1], image.shape[0]), 4, image.tobytes())
        if obj.alpha_cutoff is not None:
            levels = max_alpha_levels(obj.texture[..., 3])
            alpha = ctx.texture((levels[0].shape[1], levels[0].shape[0]), 1, dtype="f1")
            alpha.build_mipmaps(0, len(levels) - 1)
            for level, data in enumerate(levels):
                alpha.write(np.ascontiguousarray(data[::-1]).tobytes(), level=level)
            alpha.filter = (moderngl.NEAREST_MIPMAP_NEAREST, moderngl.NEAREST)
    return vbo, texture, alpha


def record_layers(
    scene: Scene,
    plan: LayerPlan,
    conservative: bool = True,
    on_layer: Callable[[int], None] | None = None,
) -> RecordedLayers:
    """Record every layer of ``plan`` from the objects of ``scene`` on the process's EGL context.

    ``conservative=False`` uses the standard "texel centre inside" rule instead; it exists to show
    (in tests) the holes the conservative rule prevents.  ``on_layer(i)`` is called after layer i.
    """
    ctx = gl_context()
    prog = program(ctx, "slab.vert", "slab.frag", "slab.geom")
    res_x, res_y = (int(r) for r in plan.texture_resolution)
    k = plan.count
    eye_borders = plan.borders + plan.reference_offset
    slabs = eye_borders.astype("<f4")
    prog["half_tan"].value = tuple(float(x) for x in plan.frustum_half_tangents)
    prog["resolution"].value = (float(res_x), float(res_y))
    prog["conservative"].value = bool(conservative)
    out = np.zeros((k, res_y, res_x, 4), dtype=np.uint8)
    drawn = np.zeros(k, dtype=np.int64)

    colour = ctx.texture((res_x, res_y), 4)
    depth = ctx.depth_texture((res_x, res_y))
    fbo = ctx.framebuffer([colour], depth)
    owned = [colour, depth, fbo]
    try:
        fbo.use()
        ctx.viewport = (0, 0, res_x, res_y)
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
        draws = []
        for obj in scene.objects:
            origin = 0.5 * (obj.bounds[0] + obj.bounds[1])
            eye_depth = (obj.vertices - plan.reference_viewpoint) @ plan.axis
            order, offsets = layer_buckets(eye_depth, obj.faces, eye_borders)
            if order.size == 0:
                continue
            vbo, texture, alpha = _object_buffers(ctx, obj, origin)
            ibo = ctx.buffer(obj.faces[order].astype("<u4").tobytes())
            vao = ctx.vertex_array(prog, [(vbo, "3f 2f 4f", "in_position", "in_uv", "in_color")], ibo)
            owned += [vbo, ibo, vao] + [t for t in (texture, alpha) if t is not None]
            draws.append((obj, eye_matrix(plan, origin), offsets, vao, texture, alpha))
        for i in range(k):
            fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
            prog["slab"].value = (float(slabs[i]), float(slabs[i + 1]))
            for obj, matrix, offsets, vao, texture, alpha in draws:
                count = int(offsets[i + 1] - offsets[i])
                if count == 0:
                    continue
                prog["eye_from_local"].write(matrix.tobytes())
                prog["base_color"].value = tuple(float(c) for c in obj.base_color)
                prog["alpha_cutoff"].value = float(obj.alpha_cutoff) if obj.alpha_cutoff is not None else -1.0
                prog["has_texture"].value = texture is not None
                if texture is not None:
                    texture.use(0)
                    prog["base_texture"].value = 0
                prog["has_alpha_mip"].value = alpha is not None
                if alpha is not None:
                    alpha.use(1)
                    prog["alpha_mip"].value = 1
                    prog["alpha_mip_size"].value = (float(alpha.width), float(alpha.height))
                    prog["alpha_mip_levels"].value = int(np.log2(max(alpha.width, alpha.height))) + 1
                    prog["texture_size"].value = (float(texture.width), float(texture.height))
                vao.render(moderngl.TRIANGLES, vertices=3 * count, first=3 * int(offsets[i]))
                drawn[i] += count
            out[i] = np.frombuffer(colour.read(), dtype=np.uint8).reshape(res_y, res_x, 4)
            if on_layer is not None:
                on_layer(i)
    finally:
        park_framebuffer(ctx)
        for resource in owned:
            resource.release()
    return RecordedLayers(out, eye_borders, drawn)
