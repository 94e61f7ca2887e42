"""Element-id cube maps: which elements of a placement's object hierarchy a point sees, by rasterisation.

From each sample point the six 90° faces of a cube are drawn with the elements' indices as colours
and the depth test on, and read back: the ids left in the image are the elements visible from the
point (seed 000 §2.2.2: point visibility by an item buffer).  One GL context is reused
(:func:`farfield.core.render.context.gl_context`); every element's triangles are uploaded once,
and one instanced draw per pass fills the six faces of a batch of points, laid out as an atlas of
tiles (instance ``k`` draws face ``k % 6`` of point ``k // 6``; the face's frustum is cut by four
clip distances before the clip position moves into its tile, ``shaders/id_cube.vert``).

What occludes: opaque double-sided objects, and opaque one-sided objects from their front (their
back faces are culled, as a runtime draws them).  Objects with an alpha mask or a base colour alpha
below 1 are drawn without writing depth: they are seen where they are in front, but hide nothing
(an item buffer cannot know which texels a mask keeps).  Ids are index + 1 in 24 bits of an RGBA8
colour (exact), so up to 16,777,214 elements.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import moderngl
import numpy as np

from farfield.core.cube_faces import FACES
from farfield.core.errors import FarfieldError
from farfield.core.placement.hierarchy import Elements
from farfield.core.render.context import gl_context
from farfield.core.render.programs import park_framebuffer, program
from farfield.core.scene import Scene

GL_CLIP_DISTANCE0 = 0x3000
MAX_IDS = (1 << 24) - 2
MAX_ATLAS_SIDE = 8192  # texels; llvmpipe and the NVIDIA driver allow 16384
MAX_FACE_RESOLUTION = 1024
MAX_CULL_ENTRIES = 4_000_000  # (point, face, element) frustum tests of one batch
NEAR_SHARE = 1e-4  # near plane at this share of the far distance (24-bit depth)


class VisibilityError(FarfieldError):
    """Visibility that cannot be computed from its inputs."""


def face_frames() -> np.ndarray:
    """(6, 3, 3) float64: rows right, up, forward of each cube face in :data:`FACES` order, all with
    ``right x up = forward`` (one winding for every face, so a single draw may cull back faces).

    >>> f = face_frames()
    >>> bool(np.allclose(np.cross(f[:, 0], f[:, 1]), f[:, 2])), f[1, 2].tolist()
    (True, [-1.0, 0.0, 0.0])
    """
    out = np.zeros((6, 3, 3))
    for k, (axis, sign) in enumerate(FACES.values()):
        out[k, 0, (axis + 1) % 3] = 1.0
        out[k, 1, (axis + 2) % 3] = float(sign)
        out[k, 2, axis] = float(sign)
    return out


def face_resolution_for(resolution: int, fov: float, texel_pixels: float) -> int:
    """Texels per side of a cube face whose texel spans ``texel_pixels`` pixels of the output
    frame (``resolution`` px over ``fov`` radians): ``ceil(resolution * (pi / 2) / fov / texel_pixels)``.
    The pixel angle of the frame is taken at its centre, where it is largest (a gnomonic face's
    texel narrows towards its edges by up to 2x), so the faces' texels are at most this coarse.

    >>> face_resolution_for(128, math.radians(45.0), 2.0)
    128
    """
    if not (math.isfinite(texel_pixels) and texel_pixels > 0.0):
        raise VisibilityError(f"texel_pixels must be > 0, got {texel_pixels!r}")
    return int(min(MAX_FACE_RESOLUTION, max(8, math.ceil(resolution * (0.5 * math.pi) / fov / texel_pixels))))


@dataclass(frozen=True, slots=True)
class PointSight:
    """What each of some points sees, in a flat CSR layout: point ``i``'s elements are
    ``ids[offsets[i]:offsets[i + 1]]`` (sorted) with the cube-map texels each covers in ``texels``."""

    offsets: np.ndarray  # (p + 1,) int64
    ids: np.ndarray  # (total,) int64 element indices
    texels: np.ndarray  # (total,) int64

    def of(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        s, e = int(self.offsets[i]), int(self.offsets[i + 1])
        return self.ids[s:e], self.texels[s:e]


class IdCubeRenderer:
    """Element-id cube maps of ``elements`` of ``scene`` from any points (see the module docstring)."""

    def __init__(self, scene: Scene, elements: Elements, face_resolution: int) -> None:
        if elements.count > MAX_IDS:
            raise VisibilityError(f"{elements.count} elements: an id buffer holds {MAX_IDS} at most")
        self.face = int(face_resolution)
        if not 1 <= self.face <= MAX_FACE_RESOLUTION:
            raise VisibilityError(f"a cube face needs 1..{MAX_FACE_RESOLUTION} texels a side, got {face_resolution!r}")
        self.elements = elements
        self.ctx = ctx = gl_context()
        bounds = np.asarray(scene.bounds, dtype=np.float64)
        self.origin = 0.5 * (bounds[0] + bounds[1])
        self.scene_lo, self.scene_hi = bounds[0], bounds[1]
        # Points per draw: the atlas's height, and the culling's (points, 6, elements) arrays bounded.
        self.batch = max(1, min(MAX_ATLAS_SIDE // self.face, MAX_CULL_ENTRIES // (6 * max(1, elements.count))))
        self.prog = program(ctx, "id_cube.vert", "id_cube.frag")
        self.prog["face_frames"].write(np.ascontiguousarray(face_frames().transpose(0, 2, 1)).astype("f4").tobytes())
        self.instances = ctx.buffer(reserve=self.batch * 6 * 20)  # eye (3 floats), face, row
        self._owned: list = [self.instances]
        b = elements.bounds
        self.centre = 0.5 * (b[:, 0] + b[:, 1])
        self.radius = 0.5 * np.linalg.norm(b[:, 1] - b[:, 0], axis=1)
        # Passes: (vertex array, its elements, their first index and index count, cull back faces, write depth).
        self.passes = []
        groups: dict[tuple[bool, bool], list[int]] = {}
        for i in range(elements.count):
            obj = scene.objects[int(elements.object_index[i])]
            occluder = obj.alpha_cutoff is None and float(obj.base_color[3]) >= 1.0
            groups.setdefault((occluder and not obj.double_sided, occluder), []).append(i)
        for (cull, depth), members in sorted(groups.items(), key=lambda kv: (not kv[0][1], kv[0][0])):
            vertices, indices, counts = [], [], []
            base = 0
            for i in members:  # each element's own vertices (indexed: shared corners are shaded once)
                obj = scene.objects[int(elements.object_index[i])]
                faces = obj.faces if elements.faces[i] is None else obj.faces[elements.faces[i]]
                used, local = np.unique(faces.reshape(-1), return_inverse=True)
                v = (obj.vertices[used] - self.origin).astype(np.float32)
                vertices.append(np.hstack([v, np.full((used.size, 1), i + 1, dtype=np.uint32).view(np.float32)]))
                indices.append(local.astype(np.uint32) + base)
                counts.append(local.size)
                base += used.size
            counts = np.asarray(counts, dtype=np.int64)
            first = np.concatenate([[0], np.cumsum(counts)[:-1]])
            vbo = ctx.buffer(np.concatenate(vertices).tobytes())
            ibo = ctx.buffer(np.concatenate(indices).tobytes())
            vao = ctx.vertex_array(
                self.prog,
                [(vbo, "3f 1u", "in_position", "in_id"), (self.instances, "3f 2f/i", "in_eye", "in_tile")],
                index_buffer=ibo,
                index_element_size=4,
            )
            self._owned += [vbo, ibo, vao]
            self.passes.append((vao, np.asarray(members, dtype=np.int64), first, counts, cull, depth))
        self.commands = None
        side = (6 * self.face, self.batch * self.face)
        self.colour = ctx.renderbuffer(side, 4)
        self.depth = ctx.depth_renderbuffer(side)
        self.fbo = ctx.framebuffer([self.colour], self.depth)
        self._owned += [self.fbo, self.colour, self.depth]

    def see(self, points) -> PointSight:
        """The elements each of ``points`` (k, 3) sees in any direction, with their texel counts."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        offsets, ids, texels = [np.zeros(1, dtype=np.int64)], [], []
        done = 0
        for start in range(0, pts.shape[0], self.batch):
            batch = pts[start : start + self.batch]
            rows = np.concatenate([r.reshape(batch.shape[0], -1) for r in self._draw(batch)], axis=1)
            m = self.elements.count + 1
            counts = np.bincount(
                (np.arange(batch.shape[0], dtype=np.int64)[:, None] * m + rows.reshape(batch.shape[0], -1)).ravel(),
                minlength=batch.shape[0] * m,
            ).reshape(batch.shape[0], m)[:, 1:]  # texels of each element (code 0: nothing)
            point, element = np.nonzero(counts)
            ids.append(element.astype(np.int64))
            texels.append(counts[point, element].astype(np.int64))
            offsets.append(done + np.cumsum(np.bincount(point, minlength=batch.shape[0])))
            done = int(offsets[-1][-1])
        return PointSight(
            np.concatenate(offsets),
            np.concatenate(ids) if ids else np.empty(0, dtype=np.int64),
            np.concatenate(texels) if texels else np.empty(0, dtype=np.int64),
        )

    def _draw(self, batch: np.ndarray) -> list[np.ndarray]:
        """(points, face, 6 * face) uint32 codes (element index + 1; 0 nothing) of the batch's cube
        maps: one image of the occluders, and one of the elements that hide nothing where there are
        any (drawn after the colour alone is cleared, against the occluders' depth)."""
        ctx, prog, n = self.ctx, self.prog, batch.shape[0]
        # Far: the farthest scene corner from any point; near: a share of it (24-bit depth).
        corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)])
        corners = np.where(corners == 0, self.scene_lo, self.scene_hi)
        far = 1.01 * float(np.max(np.linalg.norm(batch[:, None, :] - corners[None], axis=2))) + 1e-9
        prog["depth_range"].value = (NEAR_SHARE * far, far)
        prog["tiles"].value = (6.0, float(self.batch))
        # Instance k: face k % 6 of point k // 6, in row k // 6 of the atlas.
        tiles = np.column_stack([np.tile(np.arange(6), n), np.repeat(np.arange(n), 6)]).astype(np.float64)
        eyes = np.repeat(batch - self.origin, 6, axis=0)
        self.instances.write(np.hstack([eyes, tiles]).astype("f4").tobytes())
        frames = face_frames()
        self.fbo.use()
        ctx.viewport = (0, 0, 6 * self.face, self.batch * self.face)
        self.fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.BLEND | moderngl.CULL_FACE)
        for k in range(4):
            ctx.enable_direct(GL_CLIP_DISTANCE0 + k)
        ctx.front_face = "cw"  # every face frame has right x up = forward: a mirror image
        images = []
        try:
            for vao, members, first, counts, cull, depth in self.passes:
                if not depth and self.fbo.depth_mask:  # the occluders are done: keep their image
                    images.append(self._read(n))
                    self.fbo.depth_mask = False
                    self.fbo.clear(0.0, 0.0, 0.0, 0.0)  # colour alone: the depth mask is off
                # Per face of every point, the elements whose bounding sphere meets its frustum
                # (|x| - z <= r sqrt 2 and |y| - z <= r sqrt 2 in the face's frame).
                d = self.centre[members][None, :, :] - batch[:, None, :]  # (n, m, 3)
                local = np.einsum("fij,nmj->nfmi", frames, d)  # (n, 6, m, 3)
                reach = math.sqrt(2.0) * self.radius[members]
                z = local[..., 2]
                inside = (np.abs(local[..., 0]) - z <= reach) & (np.abs(local[..., 1]) - z <= reach)
                inst, elem = np.nonzero(inside.reshape(6 * n, -1))
                if inst.size == 0:
                    continue
                commands = np.zeros(
                    (inst.size, 5), dtype=np.uint32
                )  # count, instances, first, base vertex, base instance
                commands[:, 0], commands[:, 1], commands[:, 2], commands[:, 4] = counts[elem], 1, first[elem], inst
                if self.commands is None or self.commands.size < commands.nbytes:
                    if self.commands is not None:
                        self._owned.remove(self.commands)
                        self.commands.release()
                    self.commands = ctx.buffer(reserve=max(commands.nbytes, 1 << 16))
                    self._owned.append(self.commands)
                self.commands.write(commands.tobytes())
                (ctx.enable if cull else ctx.disable)(moderngl.CULL_FACE)
                self.fbo.depth_mask = depth
                vao.render_indirect(self.commands, moderngl.TRIANGLES, count=inst.size)
        finally:
            self.fbo.depth_mask = True
            ctx.disable(moderngl.CULL_FACE)
            ctx.front_face = "ccw"
            for k in range(4):
                ctx.disable_direct(GL_CLIP_DISTANCE0 + k)
        images.append(self._read(n))
        return images

    def _read(self, n: int) -> np.ndarray:
        raw = np.frombuffer(self.fbo.read(viewport=(0, 0, 6 * self.face, n * self.face), components=4), dtype=np.uint8)
        rgba = raw.reshape(n, self.face, 6 * self.face, 4).astype(np.uint32)
        return rgba[..., 0] | (rgba[..., 1] << 8) | (rgba[..., 2] << 16)

    def release(self) -> None:
        park_framebuffer(self.ctx)
        for resource in self._owned:
            resource.release()
        self._owned.clear()

    def __enter__(self) -> IdCubeRenderer:
        return self

    def __exit__(self, *exc) -> None:
        self.release()
