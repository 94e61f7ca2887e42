"""trimesh.Scene -> (k,) SceneObject: node transforms applied in float64, colour sources taken from trimesh visuals.

Shared by the format modules in :mod:`farfield.core.exchange`.  Each of them parses with trimesh through
:func:`parse` (the one place that turns trimesh's parse exceptions into :class:`SceneLoadError`)
and converts with :func:`objects_from_trimesh`.

Colour rules (see :mod:`farfield.core.scene` for the colour model):

* ``PBRMaterial`` (glTF): ``texture = baseColorTexture``, ``base_color = baseColorFactor``;
  ``alphaMode`` ``MASK`` gives ``alpha_cutoff = alphaCutoff`` (default 0.5), ``BLEND`` is
  approximated as a mask at 0.5 (with a warning: impostors have no blending).
* ``SimpleMaterial`` (OBJ/MTL, textured PLY): ``texture = image`` (``map_Kd``).  With a texture
  the RGB factor is white (``map_Kd`` replaces ``Kd``, as Blender and most viewers draw it; the
  exporters' ``Kd`` of 0.64 or 0.588 would only darken the image), else ``Kd``.  Alpha is ``d``
  (or ``1 - Tr``).  A texture with any alpha below 255 is alpha-cut at 0.5.
* ``ColorVisuals``: vertex colours as they are; face colours become the material colour when
  uniform, else the faces are unshared so that each corner carries its face's colour.
* A texture of a single colour is folded into ``base_color`` (trimesh invents a 2 x 2 grey one
  for uv without a material).  ``uv`` is kept only for textured objects.

Colour spaces (:mod:`farfield.core.colour_space`): ``base_color`` is linear and vertex colours and textures
sRGB-encoded.  glTF states its own (§3.9.2: ``baseColorFactor`` and ``COLOR_0`` linear, textures
sRGB), so with ``linear_colours`` its factor is kept and its ``COLOR_0`` encoded.  OBJ/MTL ``Kd``,
PLY and face colours have no stated space; they are authored and shown as sRGB values (three.js's
MTL, OBJ and PLY loaders read them so), so their factors are decoded and vertex colours kept.
"""

from __future__ import annotations

import io
import os
import struct
import zlib
from collections.abc import Mapping

import numpy as np
import PIL.Image
import trimesh
from trimesh.resolvers import FilePathResolver, Resolver, ZipResolver
from trimesh.visual.material import PBRMaterial, SimpleMaterial

from farfield.core.colour_space import encode_rgba_u8, srgb_to_linear
from farfield.core.errors import SceneLoadError, SceneTooCostlyError
from farfield.core.exchange.limits import TexelBudget
from farfield.core.exchange.normals import repair_normals, transform_normals, uv_tangents
from farfield.core.exchange.references import FileIndex
from farfield.core.scene import SceneObject

# What trimesh's parsers raise on malformed input (measured: IndexError for an empty GLB,
# ValueError for a bad GLB header or PLY, KeyError for a PLY without x, TypeError for non-JSON
# glTF, struct.error for truncated binary, NotImplementedError for a GLB whose version is not 2).
# Caught around the parse call only.
PARSE_ERRORS = (
    ValueError,
    TypeError,
    KeyError,
    IndexError,
    AttributeError,
    NotImplementedError,
    UnboundLocalError,  # trimesh's glTF and PLY readers on some truncated files (found by fuzzing)
    struct.error,
    EOFError,
    OSError,
    UnicodeError,
)

# What PIL raises while decoding a broken image (SyntaxError: "broken PNG file").
IMAGE_ERRORS = (OSError, ValueError, SyntaxError, zlib.error, PIL.Image.DecompressionBombError)

# Alpha-mask threshold for textures with an alpha channel in formats that do not state one (OBJ):
# the glTF 2.0 default alphaCutoff, so both formats cut at the same level.
DEFAULT_ALPHA_CUTOFF = 0.5


class _NamedZipResolver(ZipResolver):
    """A ZipResolver over an in-memory ``{name: bytes}`` mapping that knows the main file's name;
    references are looked up as :class:`~farfield.core.exchange.references.FileIndex` does."""

    def __init__(self, archive: dict, file_name: str):
        super().__init__(archive=archive)
        self.file_name = file_name
        self._index = FileIndex(archive)

    def get(self, name: str) -> bytes:
        if name is None or name in self.archive:
            return super().get(name)
        key = self._index.find(name.decode("utf-8") if hasattr(name, "decode") else name)
        return super().get(key if key is not None else name)  # else trimesh's own fallbacks, or its KeyError


def asset_resolver(name: str, directory: str | None = None, assets: Mapping[str, bytes] | None = None) -> Resolver:
    """A trimesh resolver for the files a scene refers to (MTL, textures, glTF buffers).

    Parameters
    ----------
    name : str
        The scene file's name; trimesh uses it to name unnamed OBJ objects.
    directory : str or None
        Folder of a scene read from disk; referenced files are looked up there.
    assets : mapping of str to bytes, or None
        Referenced files by relative name, for scenes uploaded as bytes.
    """
    if directory is not None:
        return _ReadOnceFileResolver(os.path.join(directory, name))
    return _NamedZipResolver(dict(assets or {}), name)


class _ReadOnceFileResolver(FilePathResolver):
    """A folder's files, each read once (trimesh reads a texture file again for every material that
    names it: 45 materials of one atlas, 45 reads and 45 copies of its bytes).  A reference not
    found as written is looked up among the folder's files as an upload's are
    (:class:`~farfield.core.exchange.references.FileIndex`), so a scene loads alike from its folder
    and from an upload of it."""

    def __init__(self, source: str):
        super().__init__(source)
        self._read: dict[str, bytes] = {}
        self._index: FileIndex | None = None

    def get(self, name: str) -> bytes:
        if name not in self._read:
            try:
                self._read[name] = super().get(name)
            except OSError:
                if self._index is None:
                    self._index = FileIndex.of_folder(self.parent)
                key = self._index.find(name)
                if key is None:
                    raise
                self._read[name] = super().get(key)
        return self._read[name]


def fetch(resolver: Resolver, name: str) -> bytes | None:
    """The bytes of the referenced file ``name``, or None if the resolver cannot find it."""
    try:
        data = resolver.get(name)
    except (OSError, KeyError, ValueError):
        return None
    return data.encode() if isinstance(data, str) else data


def parse(data: bytes, file_type: str, resolver: Resolver, **kwargs) -> trimesh.Scene:
    """Parse ``data`` with trimesh into a scene graph (no vertex merging: ``process=False``).

    Raises
    ------
    SceneLoadError
        trimesh could not parse the data; the message names the exception.
    """
    try:
        return trimesh.load_scene(io.BytesIO(data), file_type=file_type, resolver=resolver, process=False, **kwargs)
    except PARSE_ERRORS as error:
        raise SceneLoadError(f"could not parse {file_type.upper()} data: {type(error).__name__}: {error}") from error


def check_texels(size: tuple[int, int], max_pixels, name: str, count: bool = False) -> None:
    """Raise :class:`SceneTooCostlyError` when an image of ``size`` (w, h) has more than
    ``max_pixels`` texels (None: no limit), or, ``max_pixels`` a
    :class:`~farfield.core.exchange.limits.TexelBudget`, when it passes that budget (counted
    there where ``count``: the texture kept, :func:`texture_rgba`)."""
    if isinstance(max_pixels, TexelBudget):
        max_pixels.take(size, name, count)
        return
    width, height = (int(v) for v in size)
    if max_pixels is not None and width * height > max_pixels:
        raise SceneTooCostlyError(
            f"{name}: {width} x {height} texels is beyond the limit of {max_pixels:,} texels per texture "
            "(FARFIELD_MAX_SCENE_TEXTURE_PIXELS); scale it down"
        )


# PIL's modes of a greyscale image wider than 8 bits (a 16-bit greyscale PNG opens as "I;16", or "I"
# in older Pillow): PIL's convert("L"/"RGBA") clips their values at 255 instead of scaling them.
_WIDE_GREY = ("I;16", "I;16B", "I;16L", "I;16N", "I")


def eight_bit(image: PIL.Image.Image) -> PIL.Image.Image:
    """``image`` with a 16-bit greyscale one scaled to 8 bits (v / 257, rounded: the PNG
    specification's §13.12 scaling, as browsers decode it), its ``tRNS`` grey value made an alpha
    channel (``LA``); other images as they are.

    >>> import numpy as np
    >>> wide = PIL.Image.frombytes("I;16", (3, 1), np.array([0, 0x8080, 0xFFFF], "<u2").tobytes())
    >>> wide.convert("L").tobytes()[1], eight_bit(wide).getpixel((1, 0))
    (255, 128)
    """
    if image.mode not in _WIDE_GREY:
        return image
    values = np.asarray(image).astype(np.int64)
    grey = PIL.Image.fromarray(np.clip((values + 128) // 257, 0, 255).astype(np.uint8))
    transparent = image.info.get("transparency")
    if isinstance(transparent, int):
        alpha = PIL.Image.fromarray(np.where(values == transparent, 0, 255).astype(np.uint8))
        return PIL.Image.merge("LA", (grey, alpha))
    return grey


def texture_rgba(image: PIL.Image.Image, max_pixels: int | None = None, name: str = "texture") -> np.ndarray:
    """(h, w, 4) uint8 RGBA array of a PIL image, top row first.

    ``max_pixels``: the most texels it may have, checked from its header before it is decoded
    (:attr:`farfield.core.exchange.limits.SceneLimits.texture_pixels`).

    Raises
    ------
    SceneTooCostlyError
        More than ``max_pixels`` texels.
    OSError, ValueError, SyntaxError, zlib.error, PIL.Image.DecompressionBombError
        The image data is broken (PIL decodes lazily, here).
    """
    check_texels(image.size, max_pixels, name, count=True)
    image = eight_bit(image)
    if image.mode != "RGBA":
        image = image.convert("RGBA")
    return np.asarray(image, dtype=np.uint8)


def _rgba_unit(color: np.ndarray | None, srgb: bool) -> np.ndarray:
    """(4,) float64 linear RGBA in 0..1 from trimesh's (4,) uint8 colour (sRGB-encoded RGB when
    ``srgb``); white when None."""
    if color is None:
        return np.ones(4)
    rgba = np.asarray(color, dtype=np.float64) / 255.0
    if srgb:
        rgba[:3] = srgb_to_linear(rgba[:3])
    return rgba


def _mtl_alpha(material: SimpleMaterial) -> float:
    """Opacity from MTL ``d`` (or ``1 - Tr``), 1.0 when absent or unreadable."""
    extra = material.kwargs
    for key, flip in (("d", False), ("tr", True)):
        if key in extra:
            try:
                value = float(np.ravel(extra[key])[0])
            except (TypeError, ValueError, IndexError):
                continue
            return float(np.clip(1.0 - value if flip else value, 0.0, 1.0))
    return 1.0


class _Colours:
    """Colour sources of one object while they are being gathered."""

    __slots__ = ("uv", "vertex_colors", "base_color", "texture", "alpha_cutoff")

    def __init__(self) -> None:
        self.uv: np.ndarray | None = None  # (v, 2) float64
        self.vertex_colors: np.ndarray | None = None  # (v, 4) uint8
        self.base_color: np.ndarray = np.ones(4)  # (4,) float64
        self.texture: np.ndarray | None = None  # (h, w, 4) uint8
        self.alpha_cutoff: float | None = None


class DecodedTexture:
    """A decoded texture and what every object using it needs to know, found once per image."""

    __slots__ = ("rgba", "single", "translucent", "max_alpha")

    def __init__(self, rgba: np.ndarray, single: np.ndarray | None, translucent: bool, max_alpha: int) -> None:
        self.rgba = rgba  # (h, w, 4) uint8, shared by the objects using it
        self.single = single  # (4,) uint8 when every texel has this colour, else None
        self.translucent = translucent  # some texel's alpha is below 255
        self.max_alpha = max_alpha  # the largest alpha of any texel

    @classmethod
    def of(cls, rgba: np.ndarray) -> DecodedTexture:
        rgba = np.array(rgba, dtype=np.uint8, copy=True, order="C")
        rgba.flags.writeable = False  # frozen once: every SceneObject using it shares it (farfield.core.scene._frozen)
        texels = rgba.reshape(-1, 4)
        single = texels[0].copy() if (texels == texels[0]).all() else None
        return cls(rgba, single, bool(rgba[..., 3].min() < 255), int(rgba[..., 3].max()))


def _texture_colours(
    mesh: trimesh.Trimesh, name: str, textures: dict, warnings: list[str], linear: bool, max_pixels: int | None = None
) -> _Colours:
    """Colour sources of a mesh with ``TextureVisuals`` (a material, maybe uv and a texture);
    ``linear``: the file's factors and vertex colours are linear (glTF)."""
    visual = mesh.visual
    material = visual.material
    out = _Colours()
    image = None
    if isinstance(material, PBRMaterial):
        image = material.baseColorTexture
        out.base_color = _rgba_unit(material.baseColorFactor, srgb=not linear)
        mode = material.alphaMode
        if mode == "MASK":
            cutoff = material.alphaCutoff
            out.alpha_cutoff = DEFAULT_ALPHA_CUTOFF if cutoff is None else float(cutoff)
        elif mode == "BLEND":
            out.alpha_cutoff = DEFAULT_ALPHA_CUTOFF
            warnings.append(
                f"object {name!r}: alphaMode BLEND is approximated as an alpha mask at {DEFAULT_ALPHA_CUTOFF}"
            )
    elif isinstance(material, SimpleMaterial):
        image = material.image
        out.base_color = _rgba_unit(material.diffuse, srgb=True)
        if image is not None and "kd" not in material.kwargs:
            out.base_color[:3] = 1.0  # MTL: the texture times Kd; without Kd, the texture as is
        out.base_color[3] = _mtl_alpha(material)
    elif material is not None:
        out.base_color = _rgba_unit(material.main_color, srgb=not linear)

    colors = getattr(visual, "vertex_attributes", {}).get("color")
    if colors is not None and len(colors) == len(mesh.vertices):
        out.vertex_colors = trimesh.visual.color.to_rgba(colors)
        if linear:
            out.vertex_colors = encode_rgba_u8(out.vertex_colors)

    if image is None:
        return out
    uv = visual.uv
    if uv is None or len(uv) != len(mesh.vertices):
        warnings.append(f"object {name!r}: has a texture but no per-vertex uv; using the material colour")
        return out
    key = id(image)
    if key not in textures:
        try:
            textures[key] = DecodedTexture.of(texture_rgba(image, max_pixels, f"object {name!r}'s texture"))
        except IMAGE_ERRORS as error:
            textures[key] = None
            warnings.append(
                f"object {name!r}: texture could not be decoded ({type(error).__name__}: {error}); "
                "using the material colour"
            )
    texture = textures[key]
    if texture is None:
        return out
    if out.alpha_cutoff is None and not isinstance(material, PBRMaterial) and texture.translucent:
        out.alpha_cutoff = DEFAULT_ALPHA_CUTOFF
    if out.alpha_cutoff is not None and texture.max_alpha * out.base_color[3] < 255.0 * out.alpha_cutoff:
        warnings.append(
            f"object {name!r}: no texel of its texture passes its alpha cut ({out.alpha_cutoff:g}); it is invisible"
        )
    if texture.single is not None:
        # One colour (e.g. the 2 x 2 placeholder trimesh gives uv without a material): the same
        # as a material colour, which is cheaper and names the colour source truthfully.
        out.base_color = out.base_color * _rgba_unit(texture.single, srgb=True)
        return out
    out.texture = texture.rgba
    out.uv = np.asarray(uv, dtype=np.float64)
    return out


def file_normals(mesh: trimesh.Trimesh) -> np.ndarray | None:
    """(v, 3) float64 vertex normals the parser read from the file (OBJ ``vn``, PLY ``nx ny nz``), or
    None.  trimesh keeps them in the mesh's cache, and its ``vertex_normals`` property computes
    smooth ones where the file had none, so the cache is asked (as trimesh's own exporters do)."""
    if not isinstance(mesh, trimesh.Trimesh) or "vertex_normals" not in mesh._cache:
        return None
    normals = np.asarray(mesh._cache["vertex_normals"], dtype=np.float64)
    return normals if normals.shape == np.shape(mesh.vertices) else None


def _mesh_colours(
    mesh: trimesh.Trimesh,
    name: str,
    textures: dict,
    warnings: list[str],
    linear: bool,
    max_pixels: int | None = None,
    normals: np.ndarray | None = None,
):
    """(vertices, faces, colours, normals) of a mesh in its own frame; face colours may unshare
    vertices (and ``normals``, (v, 3) per vertex or None, with them).  ``linear``: the file's
    factors and vertex colours are linear (glTF)."""
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    visual = mesh.visual
    if isinstance(visual, trimesh.visual.TextureVisuals):
        return vertices, faces, _texture_colours(mesh, name, textures, warnings, linear, max_pixels), normals
    out = _Colours()
    kind = getattr(visual, "kind", None)
    if kind == "vertex":
        out.vertex_colors = np.asarray(visual.vertex_colors, dtype=np.uint8)
        if linear:
            out.vertex_colors = encode_rgba_u8(out.vertex_colors)
    elif kind == "face":
        face_colors = np.asarray(visual.face_colors, dtype=np.uint8)
        if (face_colors == face_colors[0]).all():
            out.base_color = _rgba_unit(face_colors[0], srgb=not linear)
        else:
            # The model has no face colours: give every face its own three corners.
            vertices = vertices[faces].reshape(-1, 3)
            normals = None if normals is None else normals[faces].reshape(-1, 3)
            faces = np.arange(len(vertices), dtype=np.int64).reshape(-1, 3)
            out.vertex_colors = np.repeat(face_colors, 3, axis=0)
            if linear:
                out.vertex_colors = encode_rgba_u8(out.vertex_colors)
    return vertices, faces, out, normals


def objects_from_trimesh(
    scene: trimesh.Scene,
    rename: Mapping[str, str] | None = None,
    linear_colours: bool = False,
    double_sided: bool = True,
    max_texture_pixels: int | None = None,
    normals: Mapping[str, np.ndarray] | None = None,
    normal_maps: Mapping[str, tuple[np.ndarray, float]] | None = None,
    materials: Mapping[str, dict] | None = None,
) -> tuple[tuple[SceneObject, ...], tuple[str, ...]]:
    """World-space :class:`SceneObject` s, one per geometry node of ``scene``, and warnings.

    Parameters
    ----------
    scene : trimesh.Scene
        As parsed; its geometry is not modified.
    rename : mapping of str to str, or None
        Object name for a node name; nodes not in it keep their node name.
    linear_colours : bool
        The file's colour factors and vertex colours are linear (glTF); otherwise sRGB values
        (OBJ/MTL, PLY, STL).  See the module docstring.
    double_sided : bool
        Every object's sidedness (:attr:`farfield.core.scene.SceneObject.double_sided`): for OBJ,
        PLY and STL, which state none, the loader's ``sides`` option
        (:mod:`farfield.core.sidedness`).
    max_texture_pixels : int or None
        The most texels a texture may have, checked before it is decoded (SceneTooCostlyError).
    normals : mapping of str to (v, 3) float64, or None
        The shading normals the file gives each geometry (by geometry name, in its mesh's vertex
        order; :func:`file_normals`), for the formats that have them; a geometry not in it is
        shaded flat (``normals`` None).  They are moved by the inverse transpose of the node's
        transform and zero or non-finite ones repaired, with one warning per object
        (:mod:`farfield.core.exchange.normals`).

    normal_maps : mapping of str to ((h, w, 4) uint8, float), or None
        A tangent-space normal map (linear, top row first) and its scale per geometry name, over
        the mesh's own texture coordinates (an OBJ's ``norm``); applied where the geometry has
        normals and uv, with tangents derived from them
    materials : mapping of str to dict, or None
        :class:`SceneObject` material fields per geometry name (an OBJ's PBR extension of MTL);
        its textures map through the mesh's own texture coordinates (``material_uv``, the very
        ``uv`` array where that is the same) and are left out, with a warning, without them
        (:func:`farfield.core.exchange.normals.uv_tangents`).

    Returns
    -------
    objects : tuple of SceneObject
        In the scene graph's node order.  Non-triangle geometry (points, lines) and meshes
        without faces are skipped, each with a warning.
    warnings : tuple of str
    """
    rename = rename or {}
    objects: list[SceneObject] = []
    warnings: list[str] = []
    textures: dict = {}  # id(PIL image) -> DecodedTexture or None: an image shared by materials is decoded once
    for node in scene.graph.nodes_geometry:
        transform, geometry_name = scene.graph[node]
        name = rename.get(node, str(node))
        mesh = scene.geometry[geometry_name]
        if not isinstance(mesh, trimesh.Trimesh):
            warnings.append(f"node {name!r}: skipped {type(mesh).__name__} geometry (not triangles)")
            continue
        if len(mesh.faces) == 0:
            warnings.append(f"node {name!r}: skipped a mesh without triangles")
            continue
        given = None if normals is None else normals.get(geometry_name)
        vertices, faces, colours, given = _mesh_colours(
            mesh, name, textures, warnings, linear_colours, max_texture_pixels, given
        )
        if vertices.ndim != 2 or vertices.shape[1] != 3:
            # trimesh keeps OBJ ``v`` lines of two numbers as (v, 2) vertices.
            raise SceneLoadError(f"object {name!r}: vertices have shape {vertices.shape}, expected (v, 3)")
        matrix = np.asarray(transform, dtype=np.float64)
        vertices = trimesh.transformations.transform_points(vertices, matrix)
        if np.linalg.det(matrix[:3, :3]) < 0.0:
            # A mirroring transform turns counter-clockwise faces clockwise; restore the winding.
            faces = faces[:, ::-1]
        if given is not None:
            given, warning = repair_normals(name, vertices, faces, transform_normals(given, matrix[:3, :3]))
            if warning is not None:
                warnings.append(warning)
        mapped = {}
        found_map = None if normal_maps is None else normal_maps.get(geometry_name)
        visual_uv = getattr(mesh.visual, "uv", None)
        if found_map is not None and given is not None and visual_uv is not None and len(visual_uv) == len(vertices):
            map_uv = np.asarray(visual_uv, dtype=np.float64)
            if np.isfinite(map_uv).all():
                mapped = {"normal_texture": found_map[0], "normal_uv": map_uv,
                          "tangents": uv_tangents(vertices, faces, given, map_uv), "normal_scale": found_map[1]}  # fmt: skip
        uv = colours.uv
        shading = dict(materials.get(geometry_name, {})) if materials is not None else {}
        textured = [k for k in ("metallic_roughness_texture", "emissive_texture") if k in shading]
        if textured:
            material_uv = None
            if visual_uv is not None and len(visual_uv) == len(vertices):
                material_uv = np.array(visual_uv, dtype=np.float64, order="C")
            if material_uv is None or not np.isfinite(material_uv).all():
                warnings.append(f"object {name!r}: its material maps need texture coordinates (vt); ignored")
                for k in textured:
                    del shading[k]
            else:
                if uv is not None and np.array_equal(uv, material_uv):
                    uv = material_uv  # one array, as SceneObject shares it
                material_uv.flags.writeable = False
                shading["material_uv"] = material_uv
        objects.append(
            SceneObject(
                name=name,
                vertices=vertices,
                faces=faces,
                uv=uv,
                vertex_colors=colours.vertex_colors,
                base_color=colours.base_color,
                texture=colours.texture,
                alpha_cutoff=colours.alpha_cutoff,
                double_sided=double_sided,
                normals=given,
                **mapped,
                **shading,
            )
        )
    return tuple(objects), tuple(warnings)
