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

**Occluder erosion** (``erosion`` > 0; seed 000 §2.2.2 and §3.4.1 on [Wonk00], Wonka, Wimmer and
Schmalstieg 2000: what a point sees past occluders shrunk by ``e`` is a superset of what every eye
within ``e`` of it sees past the real ones; done in image space on the depth map, after Décoret,
Debunne and Sillion, *Erosion based visibility preprocessing*, EGSR 2003).  Every layer of
occluders erodes, each by its own parallax (a cascade): the first surfaces' depth map of each face
is drawn; a texel at depth ``z`` is *open* where a silhouette (a neighbour of another element that is
farther) lies within the parallax ``e sqrt(1 + x²) / (z - e)`` (tan units, :func:`erosion_radii`) of
it, a square of texels (:func:`past_silhouettes`), and shows something farther than it there.  Then up
to ``peels`` passes draw every element again, keeping per texel the nearest fragment behind the layer
above and not of its element (depth peeling, ``PEEL`` in ``shaders/id_cube.frag``): the next layer's
ids count on the texels open through every layer in front, and the next layer is eroded in turn at
the silhouettes of every layer so far.  So a line of sight past several occluders in a row (slits in
a row, far buildings down a street past corners) opens as far as each occluder's own parallax lets
it, and no farther.  Not strictly conservative: more than ``peels`` layers in an open texel lose the
deeper ones, a feature that covers no texel centre is lost, and an element hidden by another part of
one element (its own silhouette: a hill of one terrain mesh) opens only where the element's texels
neighbour another element's.
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
GUARD = 1.5  # an eroded face spans tan -1.5..1.5 (112.6°): the erosion's neighbourhood past its 90°
PEEL_DEPTH_BIAS = 2.0**-20  # window-depth units: a peeled fragment lies this far behind the layer above


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


def linear_depth(window: np.ndarray, near: float, far: float) -> np.ndarray:
    """Eye-space depth along a face's axis of window depths ``window`` (0..1) of the id cubes' projection.

    >>> linear_depth(np.array([0.0, 1.0]), 0.5, 100.0).round(6).tolist()
    [0.5, 100.0]
    """
    ndc = 2.0 * np.asarray(window, dtype=np.float64) - 1.0
    return 2.0 * far * near / ((far + near) - ndc * (far - near))


def silhouettes(depth: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """The depths seen just past an occluder's silhouette, 0 elsewhere: ``depth`` and ``ids``
    (..., face, face) of the first surfaces; a texel keeps its depth where a neighbour (of the four) is
    nearer and of another element (or the texel is empty, depth 1).  A surface next to more of
    itself (a slanted wall, a box's crease) is no silhouette, so it does not erode into itself.

    >>> d = np.full((1, 4, 4), 0.9, dtype=np.float32); i = np.full((1, 4, 4), 2)
    >>> d[0, :, :2], i[0, :, :2] = 0.5, 1
    >>> silhouettes(d, i)[0].tolist()[0]
    [0.0, 0.0, 0.8999999761581421, 0.0]
    """
    depth = np.asarray(depth, dtype=np.float32)
    out = np.zeros_like(depth)
    for axis in (-1, -2):
        n = depth.shape[axis]
        a = (slice(None),) * (depth.ndim + axis) + (slice(0, n - 1),)
        b = (slice(None),) * (depth.ndim + axis) + (slice(1, n),)
        other = ids[a] != ids[b]
        for far, near in ((b, a), (a, b)):
            edge = other & (depth[near] < depth[far])
            out[far] = np.where(edge, depth[far], out[far])
    return out


RADII = np.unique(np.ceil(np.sqrt(2.0) ** np.arange(0, 25)).astype(np.int64))  # 1, 2, 3, 4, 6, 8, 12, 16, 23, ...


def erosion_radii(depth: np.ndarray, erosion: float, near: float, far: float, guard: float = 1.0) -> np.ndarray:
    """Radii in texels (int64, the shape of ``depth``) of the parallax that an eye within ``erosion``
    of the point may see at each texel of cube faces' window depths ``depth`` (..., face, face) on
    faces spanning tan ``-guard..guard``.  An eye moved by ``d`` (face frame: ``d_r`` right, ``d_f``
    forward) moves a point at tan ``x`` and depth ``z`` by ``(x d_f - d_r) / (z - d_f)`` in tan, at
    most ``e sqrt(1 + x²) / (z - e)`` for ``|d| <= e``; the radius is the larger of the two axes'
    (a square), and the whole face where ``z <= e`` (the eye may reach the surface).

    >>> d = np.full((1, 4, 4), 0.5, dtype=np.float32)
    >>> z = float(linear_depth(0.5, 0.1, 100.0)); round(z, 3), erosion_radii(d, 0.08, 0.1, 100.0)[0].tolist()[1]
    (0.2, [2, 2, 2, 2])
    >>> int(erosion_radii(d, 0.3, 0.1, 100.0).min())  # nearer than the erosion: everything
    4
    """
    depth = np.asarray(depth, dtype=np.float32)
    face = depth.shape[-1]
    t = ((np.arange(face) + 0.5) * (2.0 / face) - 1.0) * guard
    stretch = np.sqrt(1.0 + np.maximum(t[:, None] ** 2, t[None, :] ** 2))
    lever = linear_depth(depth, near, far) - erosion
    with np.errstate(divide="ignore"):
        radius = np.where(lever > 0.0, erosion * face / (2.0 * guard) * stretch / np.maximum(lever, 1e-30), face)
    return np.minimum(np.ceil(radius), face).astype(np.int64)


def past_silhouettes(
    depth: np.ndarray, edges: np.ndarray, erosion: float, near: float, far: float, guard: float = 1.0
) -> np.ndarray:
    """Per texel the farthest of ``edges`` (:func:`silhouettes`' far-side depths, 0 elsewhere) within
    :func:`erosion_radii` texels of it (a square; ``depth`` gives each texel's own depth), radii
    rounded up to :data:`RADII`, one ``scipy.ndimage.maximum_filter`` each.

    >>> e = np.zeros((1, 8, 8), dtype=np.float32); e[0, 4, 4] = 0.9
    >>> r = past_silhouettes(np.full((1, 8, 8), 0.5, dtype=np.float32), e, 0.02, 0.1, 10.0)
    >>> [round(float(v), 2) for v in r[0, 4, [2, 3, 4, 5, 6]]]
    [0.0, 0.9, 0.9, 0.9, 0.0]
    """
    from scipy.ndimage import maximum_filter

    face = depth.shape[-1]
    radius = erosion_radii(depth, erosion, near, far, guard)
    out = np.zeros_like(edges)
    size = (1,) * (depth.ndim - 2)
    low = 0
    for high in RADII.tolist():
        pick = (radius > low) & (radius <= high)
        if np.any(pick):
            wide = maximum_filter(edges, size=(*size, 2 * high + 1, 2 * high + 1), mode="constant", cval=0.0)
            out[pick] = wide[pick]
        low = high
        if low >= face:
            break
    return out


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

    def __init__(
        self, scene: Scene, elements: Elements, face_resolution: int, erosion: float = 0.0, peels: int = 4
    ) -> None:
        if not (math.isfinite(erosion) and erosion >= 0.0):
            raise VisibilityError(f"the occluder erosion must be >= 0, got {erosion!r}")
        if not (isinstance(peels, int) and 0 <= peels <= 16):
            raise VisibilityError(f"peels must be an integer in 0..16, got {peels!r}")
        self.erosion, self.peels = float(erosion), int(peels) if erosion > 0.0 else 0
        if elements.count > MAX_IDS:
            raise VisibilityError(f"{elements.count} elements: an id buffer holds {MAX_IDS} at most")
        if not 1 <= int(face_resolution) <= MAX_FACE_RESOLUTION:
            raise VisibilityError(f"a cube face needs 1..{MAX_FACE_RESOLUTION} texels a side, got {face_resolution!r}")
        # Eroded faces are drawn wider (a guard band of the neighbouring faces' directions, so the
        # erosion near a face's border sees across it), with as many texels per tan unit.
        self.guard = GUARD if self.peels else 1.0
        self.face = int(math.ceil(int(face_resolution) * self.guard))
        self.elements = elements
        self.ctx = ctx = gl_context()
        bounds = np.asarray(scene.bounds, dtype=np.float64)
        self.origin = 0.5 * (bounds[0] + bounds[1])
        self.scene_lo, self.scene_hi = bounds[0], bounds[1]
        # Points per draw: the atlas's height, and the culling's (points, 6, elements) arrays bounded.
        self.batch = max(1, min(MAX_ATLAS_SIDE // self.face, MAX_CULL_ENTRIES // (6 * max(1, elements.count))))
        self.prog = program(ctx, "id_cube.vert", "id_cube.frag")
        self.peel_prog = program(ctx, "id_cube.vert", "id_cube.frag", defines=("PEEL",)) if self.peels else None
        for prog in (self.prog, self.peel_prog):
            if prog is not None:
                prog["face_frames"].write(np.ascontiguousarray(face_frames().transpose(0, 2, 1)).astype("f4").tobytes())
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
            vaos = [
                ctx.vertex_array(
                    prog,
                    [(vbo, "3f 1u", "in_position", "in_id"), (self.instances, "3f 2f/i", "in_eye", "in_tile")],
                    index_buffer=ibo,
                    index_element_size=4,
                )
                for prog in (self.prog, self.peel_prog)
                if prog is not None
            ]
            self._owned += [vbo, ibo, *vaos]
            self.passes.append((vaos, np.asarray(members, dtype=np.int64), first, counts, cull, depth))
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
            rows = np.concatenate([r.reshape(batch.shape[0], -1) for r in self._draw_eroded(batch)], axis=1)
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

    def _draw_eroded(self, batch: np.ndarray) -> list[np.ndarray]:
        """The batch's id images (:meth:`_draw`), and with ``erosion`` the ids of up to ``peels``
        layers behind the first surfaces where an eye near the point may see them (module docstring):
        layer ``k`` is the nearest fragment behind layer ``k - 1`` (not of its element), drawn over
        the whole atlas; its ids count only on texels *open* through every layer in front, and a
        texel stays open through layer ``k`` where a silhouette of any layer so far (:func:`silhouettes`)
        within the layer's own parallax (:func:`past_silhouettes`) shows something farther than it."""
        images, depth, (near, far) = self._draw(batch)
        if not self.peels:
            return images
        n, face = batch.shape[0], self.face

        def tiles(a: np.ndarray) -> np.ndarray:  # (points, face, rows, columns)
            return a.reshape(n, face, 6, face).transpose(0, 2, 1, 3)

        def atlas(a: np.ndarray) -> np.ndarray:
            return np.ascontiguousarray(a.transpose(0, 2, 1, 3).reshape(n, face, 6 * face))

        codes = images[0]
        edges = silhouettes(tiles(depth), tiles(codes))
        reach = atlas(past_silhouettes(tiles(depth), edges, self.erosion, near, far, self.guard))
        alive = (codes != 0) & (reach > depth)  # where a nearby eye may see past the first surface
        if not np.any(alive):
            return images
        textures = [self._texture(depth, "f4"), self._texture(codes, "u4")]
        try:
            self.peel_prog["lower_depth"].value, self.peel_prog["lower_id"].value = 0, 1
            self.peel_prog["depth_bias"].value = PEEL_DEPTH_BIAS
            for k in range(self.peels):
                for unit, texture in enumerate(textures):
                    texture.use(location=unit)
                layer, depth, _ = self._draw(batch, peel=True)
                images += [np.where(alive, image, 0) for image in layer]
                codes = layer[0]
                if k == self.peels - 1:
                    break
                edges = np.maximum(edges, silhouettes(tiles(depth), tiles(codes)))
                reach = atlas(past_silhouettes(tiles(depth), edges, self.erosion, near, far, self.guard))
                alive &= (codes != 0) & (reach > depth)
                if not np.any(alive):
                    break
                textures[0].write(np.ascontiguousarray(depth, dtype=np.float32).tobytes())
                textures[1].write(np.ascontiguousarray(codes, dtype=np.uint32).tobytes())
        finally:
            for texture in textures:
                texture.release()
        return images

    def _texture(self, image: np.ndarray, dtype: str) -> moderngl.Texture:
        """(points, face, 6 * face) ``image`` as a one-channel texture of the atlas (rows as read)."""
        texture = self.ctx.texture(
            (image.shape[2], image.shape[0] * image.shape[1]), 1, np.ascontiguousarray(image, dtype=dtype).tobytes(),
            dtype=dtype,
        )  # fmt: skip
        texture.filter = (moderngl.NEAREST, moderngl.NEAREST)
        return texture

    def _draw(self, batch: np.ndarray, peel: bool = False) -> tuple[list[np.ndarray], np.ndarray, tuple[float, float]]:
        """(points, face, 6 * face) uint32 codes (element index + 1; 0 nothing) of the batch's cube
        maps: one image of the occluders, and one of the elements that hide nothing where there are
        any (drawn after the colour alone is cleared, against the occluders' depth); the occluders'
        (points, face, 6 * face) window depths; and the (near, far) of the projection.  With ``peel``
        the program discards what is not between the bound textures' layer and eroded depth."""
        ctx, n = self.ctx, batch.shape[0]
        prog = self.peel_prog if peel else self.prog
        # Far: the farthest scene corner from any point; near: a share of it (24-bit depth).
        corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)])
        corners = np.where(corners == 0, self.scene_lo, self.scene_hi)
        far = 1.01 * float(np.max(np.linalg.norm(batch[:, None, :] - corners[None], axis=2))) + 1e-9
        prog["depth_range"].value = (NEAR_SHARE * far, far)
        prog["tiles"].value = (6.0, float(self.batch))
        prog["guard"].value = self.guard
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
        images, occluder_depth = [], None
        try:
            for vaos, members, first, counts, cull, depth in self.passes:
                vao = vaos[1 if peel else 0]
                if not depth and self.fbo.depth_mask:  # the occluders are done: keep their image
                    images.append(self._read(n))
                    occluder_depth = self._read_depth(n) if self.peels else None
                    self.fbo.depth_mask = False
                    self.fbo.clear(0.0, 0.0, 0.0, 0.0)  # colour alone: the depth mask is off
                # Per face of every point, the elements whose bounding sphere meets its frustum
                # (|x| - g z <= r sqrt(1 + g²) and the same for y in the face's frame, g the guard).
                d = self.centre[members][None, :, :] - batch[:, None, :]  # (n, m, 3)
                local = np.einsum("fij,nmj->nfmi", frames, d)  # (n, 6, m, 3)
                reach = math.sqrt(1.0 + self.guard**2) * self.radius[members]
                z = self.guard * local[..., 2]
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
        if occluder_depth is None and self.peels:
            occluder_depth = self._read_depth(n)
        images.append(self._read(n))
        return images, occluder_depth, (NEAR_SHARE * far, far)

    def _read_depth(self, n: int) -> np.ndarray:
        raw = self.fbo.read(viewport=(0, 0, 6 * self.face, n * self.face), components=1, attachment=-1, dtype="f4")
        return np.frombuffer(raw, dtype=np.float32).reshape(n, self.face, 6 * self.face)

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
