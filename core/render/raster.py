"""Plain rasterisation of unlit textured meshes: SceneObjects in, (h, w, 4) uint8 images (top row first) out.

Evaluation and the reference runtime draw the original geometry and the impostor through this same
renderer (same camera, same shading), so differences come from the impostor alone.  Objects are
uploaded once (:class:`MeshRenderer`) and drawn from many cameras; every position is stored
relative to its object's own centre and moved into the camera frame by a float64-built matrix.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import moderngl
import numpy as np

from farfield.core.errors import RenderBackendError, ViewCellError
from farfield.core.render.context import gl_context
from farfield.core.render.programs import linear_texture, material_uniforms, park_framebuffer, program, srgb_texture
from farfield.core.scene import SceneObject
from farfield.core.sidedness import front_winding

GL_CLIP_DISTANCE0 = 0x3000
_CLIP_PLANES = tuple(GL_CLIP_DISTANCE0 + i for i in range(6))


@dataclass(frozen=True, slots=True)
class Camera:
    """A square perspective camera: eye (3,) float64 world; right/up/forward (3,) float64 unit.

    ``offset`` makes it off-axis: the image's centre lies in the direction (offset[0], offset[1], 1)
    of the eye frame (tangents, x right, y up) instead of straight ahead, with the image plane still
    perpendicular to ``forward``; :meth:`window` uses it to draw a part of another camera's image.
    """

    eye: np.ndarray
    right: np.ndarray
    up: np.ndarray
    forward: np.ndarray
    fov: float  # radians, full angle on both axes
    resolution: int
    near: float
    far: float
    offset: tuple[float, float] = (0.0, 0.0)

    @classmethod
    def look_at(cls, eye, target, fov: float, resolution: int, near: float, far: float) -> Camera:
        """A camera at ``eye`` looking at ``target``; world +z is up unless the view is vertical."""
        eye = np.asarray(eye, dtype=np.float64)
        forward = np.asarray(target, dtype=np.float64) - eye
        norm = float(np.linalg.norm(forward))
        if norm == 0.0:
            raise ViewCellError("camera eye and target coincide")
        forward /= norm
        hint = np.array([0.0, 0.0, 1.0]) if abs(forward[2]) < 0.99 else np.array([0.0, 1.0, 0.0])
        right = np.cross(forward, hint)
        right /= np.linalg.norm(right)
        up = np.cross(right, forward)
        if not 0.0 < near < far:
            raise ViewCellError(f"camera needs 0 < near < far, got near={near!r}, far={far!r}")
        return cls(eye, right, up, forward, float(fov), int(resolution), float(near), float(far))

    def window(self, x0: float, y0: float, size: float, resolution: int) -> Camera:
        """The camera drawing the square of this camera's image from pixel (``x0``, ``y0``) (x right,
        y down from the top-left corner, in this camera's pixels) ``size`` pixels wide, with
        ``resolution`` pixels per side: the same eye, orientation, image plane and depth range, a
        narrower off-axis frustum, so its pixels subdivide this camera's exactly.

        >>> c = Camera.look_at(np.zeros(3), np.array([0.0, 1.0, 0.0]), math.radians(90.0), 8, 0.1, 10.0)
        >>> w = c.window(6.0, 2.0, 2.0, 4)
        >>> p = np.array([[0.7, 1.0, 0.3], [0.9, 1.0, 0.1]])  # two points in c's pixels (6..8, 2..4)
        >>> c.project(p).round(3).tolist(), w.project(p).round(3).tolist()
        ([[6.8, 2.8], [7.6, 3.6]], [[1.6, 1.6], [3.2, 3.2]])
        """
        t = math.tan(0.5 * self.fov)
        scale = 2.0 * t / self.resolution  # tangent per pixel of this camera
        half = 0.5 * size * scale
        centre = (self.offset[0] + (x0 + 0.5 * size) * scale - t, self.offset[1] + t - (y0 + 0.5 * size) * scale)
        return Camera(
            self.eye,
            self.right,
            self.up,
            self.forward,
            2.0 * math.atan(half),
            int(resolution),
            self.near,
            self.far,
            centre,
        )

    def eye_matrix(self, origin: np.ndarray) -> np.ndarray:
        """(4, 4) float32 column-major matrix from coordinates relative to ``origin`` to the eye frame
        (sheared for an off-axis camera: x and y less ``offset`` times depth, so the frustum is
        centred)."""
        return np.frombuffer(self.eye_matrices([origin])[0], dtype="<f4").reshape(4, 4)

    def eye_matrices(self, origins) -> list[bytes]:
        """:meth:`eye_matrix` of each of ``origins`` as the bytes a uniform takes, the rotation
        built once for all of them (a renderer's draws each have their own origin).

        >>> c = Camera.look_at(np.zeros(3), np.array([0.0, 0.0, 5.0]), math.radians(60.0), 8, 0.1, 10.0)
        >>> m = np.frombuffer(c.eye_matrices([np.array([1.0, 2.0, 3.0])])[0], dtype="<f4").reshape(4, 4)
        >>> (m.T @ [0.0, 0.0, 0.0, 1.0]).round(6).tolist()  # the origin, in the eye frame
        [-1.0, 2.0, 3.0, 1.0]
        """
        rot = np.stack([self.right, self.up, self.forward])
        if self.offset != (0.0, 0.0):
            rot = np.array([[1.0, 0.0, -self.offset[0]], [0.0, 1.0, -self.offset[1]], [0.0, 0.0, 1.0]]) @ rot
        m = np.eye(4)
        m[:3, :3] = rot
        out = []
        for origin in origins:
            m[:3, 3] = rot @ (np.asarray(origin, dtype=np.float64) - self.eye)
            out.append(m.T.astype("<f4").tobytes())
        return out

    def project(self, points: np.ndarray) -> np.ndarray:
        """(n, 2) float64 pixel coordinates (x right, y down from the top row) of world ``points`` (n, 3)."""
        e = (np.asarray(points, dtype=np.float64) - self.eye) @ np.stack([self.right, self.up, self.forward]).T
        t = math.tan(0.5 * self.fov)
        x = ((e[:, 0] / e[:, 2] - self.offset[0]) / t * 0.5 + 0.5) * self.resolution
        y = (0.5 - (e[:, 1] / e[:, 2] - self.offset[1]) / t * 0.5) * self.resolution
        return np.stack([x, y], axis=1)


def upload(
    ctx: moderngl.Context, prog: moderngl.Program, obj: SceneObject, origin: np.ndarray, textures: dict, owned: list
):
    """(vertex array, texture or None) of ``obj`` for ``prog`` (attributes ``in_position`` relative
    to ``origin``, and ``in_uv`` and ``in_color`` where ``prog`` reads them), its base-colour texture shared through ``textures``
    (id of the array -> GL texture) by objects that share the array; every GL object made is
    appended to ``owned``.

    The geometry as it is: alpha tested texel by texel, no mipmaps (their averaged alpha would thin
    an alpha-cut part with distance, a property of one viewer, not of the part).
    """
    n = obj.vertices.shape[0]
    columns, names, layout = [obj.vertices - origin], ["in_position"], ["3f"]
    if prog.get("in_uv", None) is not None:  # a variant that needs no attribute is not given it
        columns.append(obj.uv if obj.uv is not None else np.zeros((n, 2)))
        names.append("in_uv")
        layout.append("2f")
    if prog.get("in_color", None) is not None:
        columns.append(obj.vertex_colors / 255.0 if obj.vertex_colors is not None else np.ones((n, 4)))
        names.append("in_color")
        layout.append("4f")
    if prog.get("in_normal", None) is not None:
        columns.append(obj.normals)
        names.append("in_normal")
        layout.append("3f")
    if prog.get("in_tangent", None) is not None:
        columns += [obj.normal_uv, obj.tangents]
        names += ["in_normal_uv", "in_tangent"]
        layout += ["2f", "4f"]
    if prog.get("in_material_uv", None) is not None:
        columns.append(obj.material_uv)
        names.append("in_material_uv")
        layout.append("2f")
    data = np.concatenate(columns, axis=1).astype("<f4")
    vbo = ctx.buffer(np.ascontiguousarray(data).tobytes())
    ibo = ctx.buffer(obj.faces.astype("<u4").tobytes())
    vao = ctx.vertex_array(prog, [(vbo, " ".join(layout), *names)], ibo)
    owned += [vbo, ibo, vao]
    texture = None
    if obj.texture is not None:
        texture = textures.get(id(obj.texture))
        if texture is None:
            texture = textures[id(obj.texture)] = srgb_texture(ctx, obj.texture)
            owned.append(texture)
    return vao, texture


def depth_bounds(eye: np.ndarray, forward: np.ndarray, points: np.ndarray) -> tuple[float, float]:
    """A (near, far) pair enclosing ``points`` (n, 3) in front of the camera, with margins."""
    z = (np.asarray(points, dtype=np.float64) - eye) @ forward
    far = float(z.max()) * 1.01
    near = max(float(z.min()) * 0.99, far * 1e-6)
    if not far > 0.0:
        raise ViewCellError("everything to draw lies behind the camera")
    return near, far


def mesh_variant(obj: SceneObject, planes: bool, open_faces: bool) -> tuple[str, ...]:
    """The defines of the ``mesh.vert`` / ``mesh.frag`` variant that draws ``obj``: only what it
    has is computed per vertex and interpolated per fragment (on llvmpipe every varying costs
    each covered pixel), and only an alpha cut or open clip faces discard.

    >>> from dataclasses import replace
    >>> quad = SceneObject("q", np.zeros((3, 3)), np.array([[0, 1, 2]]))
    >>> mesh_variant(quad, planes=True, open_faces=False)
    ('CLIP_PLANES',)
    >>> mesh_variant(replace(quad, vertex_colors=np.zeros((3, 4), np.uint8), alpha_cutoff=0.5), False, False)
    ('VERTEX_COLOURS', 'ALPHA_CUT')
    """
    defines = []
    if obj.vertex_colors is not None:
        defines.append("VERTEX_COLOURS")
    if obj.texture is not None:
        defines.append("TEXTURED")
    if obj.alpha_cutoff is not None:
        defines.append("ALPHA_CUT")
    if planes:
        defines.append("CLIP_PLANES")
    if open_faces:
        defines.append("OPEN_FACES")
    return tuple(defines)


def material_variant(obj: SceneObject) -> tuple[str, ...]:
    """The defines a material G-buffer adds for ``obj``: MATERIAL, and MATERIAL_UV with the map of
    each material texture it has.

    >>> quad = SceneObject("q", np.zeros((3, 3)), np.array([[0, 1, 2]]))
    >>> material_variant(quad)
    ('MATERIAL',)
    """
    maps = tuple(
        define
        for define, key in (
            ("METALLIC_ROUGHNESS_MAP", "metallic_roughness_texture"),
            ("OCCLUSION_MAP", "occlusion_texture"),
            ("EMISSIVE_MAP", "emissive_texture"),
        )
        if getattr(obj, key) is not None
    )
    return ("MATERIAL",) + (("MATERIAL_UV",) + maps if maps else ())


def eye_depth(depth_texture, camera: Camera) -> np.ndarray:
    """(h, w) float64 eye depth of a depth attachment rendered from ``camera`` with mesh.vert's
    projection (top row first; ``camera.far`` where nothing was drawn), undone in float64."""
    window = np.frombuffer(depth_texture.read(), dtype=np.float32).reshape(camera.resolution, camera.resolution)[::-1]
    ndc = window.astype(np.float64) * 2.0 - 1.0
    n, f = camera.near, camera.far
    return 2.0 * f * n / ((f + n) - ndc * (f - n))


class MeshRenderer:
    """Objects uploaded once to the process's context, drawn from any :class:`Camera`.

    Use as a context manager; ``release()`` frees every GL resource it made.
    """

    def __init__(
        self,
        objects: list[SceneObject] | tuple[SceneObject, ...],
        clips=None,
        normals: bool = False,
        normal_maps=None,
        materials: bool = False,
    ):
        """``clips``: per object None or ``(centre (3,), half_size[, open_faces])``: what lies
        outside that cube is not drawn, except in the face pyramids named in ``open_faces`` (e.g.
        ``("+y",)``) (the reference runtime clips near-field geometry this way).  A closed cube is
        cut by the GL's clip planes; with open faces the region is not convex and the fragment
        shader discards instead.

        A one-sided object (``double_sided`` False) is drawn with back faces culled: a triangle
        shows only where the eye is on its front side (:mod:`farfield.core.sidedness`; the front
        winding follows each camera's handedness).

        ``normals=True`` makes a G-buffer renderer: :meth:`render_normals` gives each pixel's world
        shading normal beside its colour (mesh.frag's NORMALS output: the object's vertex normals,
        else its flat normals; ``normal_maps``, per object None or a (h, w, 4) uint8 world-space
        normal texture over its uv, an impostor's normal page, in their place).

        ``materials=True`` (with ``normals``) adds the material G-buffer, :meth:`render_material`:
        each pixel's occlusion, roughness, metallic and linear emission from its object's glTF
        metallic-roughness material (mesh.frag's MATERIAL outputs; the factors times the
        ``metallic_roughness_texture``, ``occlusion_texture`` and ``emissive_texture`` over
        ``material_uv``, sampled trilinearly over mipmaps as an engine samples them; an object
        without material gives 1, its roughness and metallic factors, its emissive factor).

        Objects are drawn in the order given, each with the cheapest variant of ``mesh.vert`` and
        ``mesh.frag`` that draws it (:func:`mesh_variant`: a discard only for an alpha cut or open
        faces, so opaque geometry listed front to back is shaded about once per pixel; no vertex
        colours, texture coordinates or clip distances where the object has none).
        """
        self.ctx = gl_context()
        clips = list(clips) if clips is not None else [None] * len(objects)
        ctx = self.ctx
        self._owned: list = []
        self._draws = []
        uploaded: dict = {}  # objects sharing a texture array (or normal map) share its GL texture
        self.normals = bool(normals)
        self.materials = bool(materials)
        if self.materials and not self.normals:
            raise ValueError("a material G-buffer needs normals=True")
        normal_maps = list(normal_maps) if normal_maps is not None else [None] * len(objects)
        for obj, clip, normal_map in zip(objects, clips, normal_maps, strict=True):
            origin = 0.5 * (obj.bounds[0] + obj.bounds[1])
            opened = tuple(clip[2]) if clip is not None and len(clip) > 2 else ()
            clip_half = float(clip[1]) if clip is not None else 0.0
            planes, open_faces = clip_half > 0.0 and not opened, clip_half > 0.0 and bool(opened)
            defines = mesh_variant(obj, planes, open_faces)
            tangent_map = self.normals and normal_map is None and obj.normals is not None
            tangent_map = tangent_map and obj.normal_texture is not None
            if self.normals:
                if normal_map is not None:
                    defines += ("NORMALS", "WORLD_NORMAL_MAP")
                elif obj.normals is not None:
                    defines += ("NORMALS", "VERTEX_NORMALS") + (("TANGENT_NORMAL_MAP",) if tangent_map else ())
                else:
                    defines += ("NORMALS",)
            if self.materials:
                defines += material_variant(obj)
            prog = program(ctx, "mesh.vert", "mesh.frag", defines=defines)
            vao, texture = upload(ctx, prog, obj, origin, uploaded, self._owned)
            uniforms = {}
            if normal_map is not None:
                if obj.uv is None or "TEXTURED" not in defines:
                    raise ValueError(f"object {obj.name!r}: a normal map needs a textured object")
                normal_texture = self.ctx.texture(
                    (normal_map.shape[1], normal_map.shape[0]), 4, np.ascontiguousarray(normal_map[::-1]).tobytes()
                )
                normal_texture.filter = (moderngl.LINEAR, moderngl.LINEAR)
                self._owned.append(normal_texture)
                uniforms["normal_texture"] = 1
            elif tangent_map:  # the source's own normal map (glTF normalTexture), mipmapped as an engine samples it
                normal_texture = uploaded.get(("normal", id(obj.normal_texture)))
                if normal_texture is None:
                    normal_texture = linear_texture(self.ctx, obj.normal_texture, mipmaps=True)
                    uploaded[("normal", id(obj.normal_texture))] = normal_texture
                    self._owned.append(normal_texture)
                uniforms["tangent_normal_map"] = 1
                uniforms["normal_scale"] = float(obj.normal_scale)
            else:
                normal_texture = None
            if clip_half > 0.0:  # the difference in float64, so large world offsets cancel before narrowing
                uniforms["clip_offset"] = tuple(float(c) for c in origin - np.asarray(clip[0], dtype=np.float64))
            if planes:
                uniforms["plane_half"] = clip_half
            elif open_faces:
                uniforms |= {
                    "clip_half": clip_half,
                    "clip_open_pos": tuple(float(f"+{axis}" in opened) for axis in "xyz"),
                    "clip_open_neg": tuple(float(f"-{axis}" in opened) for axis in "xyz"),
                }
            uniforms |= material_uniforms(prog, obj, texture)
            bound = (texture, normal_texture)
            if self.materials:
                maps = self._material_maps(obj, defines, uploaded)
                uniforms |= {name: unit for unit, (name, found) in enumerate(maps, start=2) if found is not None}
                uniforms |= {
                    "metallic_factor": obj.metallic_factor,
                    "roughness_factor": obj.roughness_factor,
                    "emissive_factor": tuple(float(c) for c in obj.emissive_factor),
                }
                if "OCCLUSION_MAP" in defines:
                    uniforms["occlusion_strength"] = obj.occlusion_strength
                bound = bound + tuple(t for _, t in maps)
            self._draws.append((obj, origin, prog, vao, bound, uniforms, planes, not obj.double_sided))
        self._targets: dict[int, tuple] = {}

    def _material_maps(self, obj: SceneObject, defines: tuple[str, ...], uploaded: dict) -> list:
        """(sampler name, GL texture or None) of units 2, 3, 4: the object's metallic-roughness,
        occlusion and emissive textures (mipmapped; linear, linear, sRGB), shared between objects
        (and between the first two, an ORM image) through ``uploaded``."""
        out = []
        for define, name, key, srgb in (
            ("METALLIC_ROUGHNESS_MAP", "metallic_roughness_map", "metallic_roughness_texture", False),
            ("OCCLUSION_MAP", "occlusion_map", "occlusion_texture", False),
            ("EMISSIVE_MAP", "emissive_map", "emissive_texture", True),
        ):
            if define not in defines:
                out.append((name, None))
                continue
            array = getattr(obj, key)
            found = uploaded.get(("material", srgb, id(array)))
            if found is None:
                found = (srgb_texture if srgb else linear_texture)(self.ctx, array, mipmaps=True)
                uploaded[("material", srgb, id(array))] = found
                self._owned.append(found)
            out.append((name, found))
        return out

    def _target(self, resolution: int):
        if resolution not in self._targets:
            colour = self.ctx.texture((resolution, resolution), 4)
            depth = self.ctx.depth_texture((resolution, resolution))
            targets = [colour] + ([self.ctx.texture((resolution, resolution), 4, dtype="f4")] if self.normals else [])
            if self.materials:
                targets += [self.ctx.texture((resolution, resolution), 4, dtype="f4") for _ in range(2)]
            fbo = self.ctx.framebuffer(targets, depth)
            self._targets[resolution] = (colour, depth, fbo, *targets[1:])
            self._owned += [*targets, depth, fbo]
        return self._targets[resolution]

    def render_normals(self, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
        """The (h, w, 4) uint8 image (:meth:`render`) and the (h, w, 3) float32 world shading normals
        of the same pixels (zero where nothing was drawn), top row first; a renderer made with
        ``normals=True`` only."""
        if not self.normals:
            raise ValueError("this renderer was made without normals")
        image = self.render(camera)
        normal = self._targets[camera.resolution][3]
        data = np.frombuffer(normal.read(), dtype=np.float32).reshape(camera.resolution, camera.resolution, 4)
        return image, data[::-1, :, :3].copy()

    def render_material(self, camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The (h, w, 4) uint8 image and (h, w, 3) float32 normals (:meth:`render_normals`) and the
        (h, w, 6) float32 material of the same pixels, top row first: occlusion, roughness,
        metallic, linear emitted RGB (zero where nothing was drawn); a renderer made with
        ``materials=True`` only (the constructor says what each channel is)."""
        if not self.materials:
            raise ValueError("this renderer was made without materials")
        image, normals = self.render_normals(camera)
        size = camera.resolution
        _, _, _, _, material, emissive = self._targets[size]
        orm = np.frombuffer(material.read(), dtype=np.float32).reshape(size, size, 4)[::-1, :, :3]
        light = np.frombuffer(emissive.read(), dtype=np.float32).reshape(size, size, 4)[::-1, :, :3]
        return image, normals, np.concatenate([orm, light], axis=-1)

    def last_depth(self, camera: Camera) -> np.ndarray:
        """(h, w) float64 eye depth of the last render from ``camera`` (top row first; ``camera.far``
        where nothing was drawn), read back from the depth attachment and mesh.vert's projection
        undone in float64 (call after :meth:`render` or a G-buffer render at that resolution)."""
        return eye_depth(self._target(camera.resolution)[1], camera)

    def render(self, camera: Camera) -> np.ndarray:
        """(h, w, 4) uint8 image, top row first; alpha 255 where something was drawn."""
        colour = self._draw(camera)
        image = np.frombuffer(colour.read(), dtype=np.uint8).reshape(camera.resolution, camera.resolution, 4)
        error = self.ctx.error  # glGetError: reading it clears it, so it is read once
        if error != "GL_NO_ERROR":
            raise RenderBackendError(f"OpenGL error while rendering: {error}")
        return image[::-1].copy()

    def frame_seconds(self, camera: Camera) -> float:
        """Seconds to draw one frame from ``camera`` and wait for the renderer to finish it (no read-back)."""
        self.ctx.finish()
        start = time.perf_counter()
        self._draw(camera)
        self.ctx.finish()
        return time.perf_counter() - start

    @property
    def triangle_count(self) -> int:
        """Triangles drawn per frame."""
        return int(sum(obj.faces.shape[0] for obj, *_ in self._draws))

    def _draw(self, camera: Camera):
        colour, _, fbo, *_ = self._target(camera.resolution)
        ctx = self.ctx
        fbo.use()
        ctx.viewport = (0, 0, camera.resolution, camera.resolution)
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
        t = math.tan(0.5 * camera.fov)
        framed: set[int] = set()  # the programs given this camera (draws may come from other renderers)
        # The planes are on only for the draws cut by a closed cube, whose variant (CLIP_PLANES)
        # alone writes the six clip distances: enabled, they can cost the NVIDIA driver where
        # nothing is cut (an H200 drew the million-triangle benchmark city from one cell's centre
        # in 4.8 ms with them on, 2.1 ms off, in one run, when every draw wrote them).  Other
        # programs of the context write no clip distances, so the planes are off between frames.
        planes = False
        # One-sided objects cull their back faces; the others draw both sides.  The GL decides by
        # the winding in the image, which turns where the eye crosses a triangle's plane, so the
        # front winding is the camera's (a mirroring frame swaps it).
        ctx.front_face = front_winding(camera.right, camera.up, camera.forward)
        culling = False
        # A draw's own work in Python is most of its cost on llvmpipe (18 us before these were
        # hoisted: the eye matrices built one by one, the material's uniforms rebuilt every frame).
        matrices = camera.eye_matrices([origin for _, origin, *_ in self._draws])
        try:
            for (_obj, _origin, prog, vao, bound, uniforms, clipped, one_sided), matrix in zip(self._draws, matrices):
                if id(prog) not in framed:
                    framed.add(id(prog))
                    prog["half_tan"].value = (t, t)
                    prog["depth_range"].value = (camera.near, camera.far)
                prog["eye_from_local"].write(matrix)
                for name, value in uniforms.items():
                    prog[name].value = value
                if clipped != planes:
                    planes = not planes
                    for plane in _CLIP_PLANES:
                        (ctx.enable_direct if planes else ctx.disable_direct)(plane)
                if one_sided != culling:
                    culling = one_sided
                    (ctx.enable if culling else ctx.disable)(moderngl.CULL_FACE)
                for unit, texture in enumerate(bound):  # base colour, normal map, then material maps
                    if texture is not None:
                        texture.use(unit)
                vao.render(moderngl.TRIANGLES)
        finally:
            if planes:
                for plane in _CLIP_PLANES:
                    ctx.disable_direct(plane)
            if culling:
                ctx.disable(moderngl.CULL_FACE)
            ctx.front_face = "ccw"  # the GL default, which every other pass on this context assumes
        return colour

    def release(self) -> None:
        park_framebuffer(self.ctx)
        for resource in self._owned:
            resource.release()
        self._owned.clear()
        self._draws.clear()
        self._targets.clear()

    def __enter__(self) -> MeshRenderer:
        return self

    def __exit__(self, *exc) -> None:
        self.release()
