"""A scene: named objects of (f, 3) int64 triangles over (v, 3) float64 world-space vertices, with colour sources.

A :class:`Scene` is what every later stage (placement, layer recording, evaluation) reads.  It is
immutable (frozen dataclasses over read-only arrays), validated on construction, and identified by
a content hash of its arrays.

Conventions
-----------
* Geometry is float64, in the scene file's units, in world space: node transforms are already
  applied.  Triangles are counter-clockwise seen from their front side (a mirroring node transform
  has its faces reversed on load so that this stays true).
* ``uv`` has its origin at the **bottom-left** corner of the texture image, u to the right and v
  up (the OpenGL / Wavefront OBJ convention; glTF's top-left ``v`` is flipped to ``1 - v`` on load).
* ``texture`` rows are stored **top row first**, as in the image file (PIL / PNG order).  The texel
  for ``(u, v)`` is therefore ``texture[floor((1 - v) * h), floor(u * w)]``; coordinates outside
  ``[0, 1)`` wrap (repeat), the default of glTF samplers and of OBJ viewers.  See
  :func:`sample_texture`.  To upload to GL (whose first row is ``t = 0``) flip the rows,
  ``texture[::-1]``, and use ``uv`` unchanged.
* Colour of a surface point = texture (if any) x vertex colour (if any) x ``base_color``, each
  RGBA in 0..1 (the glTF 2.0 base-colour rule), multiplied in linear light: ``base_color`` is
  **linear**, ``vertex_colors`` and ``texture`` are **sRGB-encoded** (alpha is linear in all
  three).  The loaders convert what a format states or implies (:mod:`farfield.core.exchange.trimesh_scene`,
  :mod:`farfield.core.colour_space`).  The summary names the *dominant* source:
  ``"texture"`` if there is a texture, else ``"vertex"`` if there are vertex colours, else
  ``"material"``.
* ``alpha_cutoff`` is ``None`` for opaque objects (alpha is ignored).  Otherwise a fragment whose
  alpha is below the cutoff is discarded and the rest is opaque (glTF ``alphaMode: MASK``).
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Iterable
from dataclasses import dataclass, field, replace

import numpy as np

from farfield.core.constants import TOL
from farfield.core.errors import DegenerateGeometryError, SceneLoadError

# Version of the content-hash recipe; bump it when the recipe changes so old hashes never collide
# with new ones.
# v2: colours are defined in colour spaces (base_color linear, vertex colours and textures sRGB), so
# equal arrays read under v1 meant other colours.
HASH_VERSION = b"farfield-scene-hash-v3"  # v3: a texture enters its objects' digests as its own digest

# glTF's default baseColorFactor (glTF 2.0, material.pbrMetallicRoughness): opaque white.
DEFAULT_BASE_COLOR = (1.0, 1.0, 1.0, 1.0)
NO_EMISSION = (0.0, 0.0, 0.0)


class SceneWarning(UserWarning):
    """A scene loaded, but with a recoverable problem (e.g. a missing texture file)."""


def _frozen(array: np.ndarray, dtype: type, name: str, obj: str, shape: tuple) -> np.ndarray:
    """A read-only C-contiguous copy of ``array`` as ``dtype``, checked against ``shape``.

    ``shape`` holds ints for fixed sizes and ``None`` for free ones.  An array that is already
    such a copy (read-only, C-contiguous, of ``dtype``, owning its data; e.g. a texture the loader
    decoded once for all the objects that use it) is shared, not copied again.
    """
    try:
        if (
            isinstance(array, np.ndarray)
            and array.dtype == dtype
            and array.flags.c_contiguous
            and not array.flags.writeable
            and array.base is None
        ):
            out = array
        else:
            out = np.array(array, dtype=dtype, copy=True, order="C")
    except (TypeError, ValueError) as error:
        raise SceneLoadError(f"object {obj!r}: {name} is not a {np.dtype(dtype).name} array: {error}") from error
    if out.ndim != len(shape) or any(want is not None and got != want for got, want in zip(out.shape, shape)):
        pretty = "(" + ", ".join("n" if s is None else str(s) for s in shape) + ")"
        raise SceneLoadError(f"object {obj!r}: {name} has shape {out.shape}, expected {pretty}")
    out.flags.writeable = False
    return out


@dataclass(frozen=True, slots=True, eq=False)
class SceneObject:
    """One named triangle mesh in world space with its colour sources.

    Arrays are copied, converted and made read-only on construction; the object is validated
    (finite, in range, at least one triangle) so that an invalid one cannot exist.

    Parameters
    ----------
    name : str
        Unique within its scene.
    vertices : (v, 3) float64
        World-space positions, scene units.
    faces : (f, 3) int64
        Indices into ``vertices``, counter-clockwise front faces; ``f >= 1``.
    uv : (v, 2) float64 or None
        Texture coordinates, origin bottom-left, v up (see the module docstring).
    vertex_colors : (v, 4) uint8 or None
        Per-vertex RGBA, RGB sRGB-encoded.
    base_color : (4,) float64
        Material RGBA factor in 0..1, linear (glTF ``baseColorFactor``; OBJ ``Kd`` decoded from
        sRGB, and ``d``).
    texture : (h, w, 4) uint8 or None
        Base-colour RGBA image, RGB sRGB-encoded, top row first.  Requires ``uv``.
    alpha_cutoff : float or None
        Alpha-mask threshold in 0..1, or None for opaque.
    normals : (v, 3) float64 or None
        World-space unit shading normals per vertex (glTF ``NORMAL``, OBJ ``vn``, PLY ``nx ny nz``),
        on the front side of the counter-clockwise winding; None where the source has none, and
        then each triangle is shaded with its face normal (flat), as glTF prescribes.
    normal_texture : (h, w, 4) uint8 or None
        Tangent-space normal map (glTF ``normalTexture``), RGB linear, ``n * 0.5 + 0.5``, top row
        first: +X along increasing u, +Y up the image (increasing v), +Z along the shading normal.
        Requires ``normal_uv`` and ``tangents``.
    normal_uv : (v, 2) float64 or None
        The normal map's texture coordinates (same convention as ``uv``).
    tangents : (v, 4) float64 or None
        World-space unit tangents (along increasing u of ``normal_uv``) and the handedness ``w`` =
        +-1: the bitangent (up the normal map) is ``cross(normal, tangent) * w`` (glTF ``TANGENT``,
        or derived from the uv where the file has none).
    normal_scale : float
        glTF ``normalTexture.scale``: the map's X and Y are multiplied by it.
    metallic_factor, roughness_factor : float
        glTF ``pbrMetallicRoughness`` factors in 0..1.  The defaults (metallic 0, roughness 1) are a
        matte dielectric, what a format without materials (OBJ without PBR keys, PLY, STL) means; the
        glTF loader sets the file's values (the specification's default there is metallic 1).
    metallic_roughness_texture : (h, w, 4) uint8 or None
        glTF ``metallicRoughnessTexture``, linear, top row first: roughness in G, metallic in B
        (multiplied by the factors).  Requires ``material_uv``.
    occlusion_texture : (h, w, 4) uint8 or None
        glTF ``occlusionTexture``, linear, occlusion in R, top row first.  Requires ``material_uv``.
    occlusion_strength : float
        glTF ``occlusionTexture.strength`` in 0..1: occlusion = 1 + strength * (R - 1).
    emissive_factor : (3,) float64
        glTF ``emissiveFactor``, linear RGB, >= 0 (zeros: no emission).
    emissive_texture : (h, w, 4) uint8 or None
        glTF ``emissiveTexture``, RGB sRGB-encoded, top row first (multiplied by the factor).
        Requires ``material_uv``.
    material_uv : (v, 2) float64 or None
        The texture coordinates the three material textures share (same convention as ``uv``; it
        may be the very array ``uv`` is).  A loader whose file maps them through different sets
        keeps those on the first texture's set and drops the others with a warning.
    double_sided : bool
        Seen from both sides (True, the default for built scenes) or from its front side only
        (False: a viewer behind a triangle's plane does not see it, as an engine culls back faces;
        glTF ``doubleSided: false``, and OBJ/PLY/STL by default, see :mod:`farfield.core.exchange`).
    prototype : str or None
        The object is one instance of a mesh the scene draws several times (glTF nodes sharing a
        mesh, ``EXT_mesh_gpu_instancing``): a key of the mesh's local content (every primitive's
        geometry and material, :func:`prototype_key`), shared by the objects of all its instances.
        None: not instanced.  Set together with ``instance_matrix`` and ``local``.
    instance_matrix : (4, 4) float64 or None
        The instance's local -> world transform: ``vertices`` are ``local.vertices`` moved by it.
    local : SceneObject or None
        This primitive of the prototype in its mesh's own (local) space, one object shared by
        reference by every instance (:meth:`Scene.prototype_objects`).

    Raises
    ------
    DegenerateGeometryError
        No triangles, or non-finite coordinates.
    SceneLoadError
        Wrong shapes, face indices out of range, or coordinates beyond ``TOL.max_coordinate``.
    """

    name: str
    vertices: np.ndarray  # (v, 3) float64, world units
    faces: np.ndarray  # (f, 3) int64
    uv: np.ndarray | None = None  # (v, 2) float64, origin bottom-left
    vertex_colors: np.ndarray | None = None  # (v, 4) uint8 RGBA, sRGB-encoded RGB
    base_color: np.ndarray = DEFAULT_BASE_COLOR  # (4,) float64 RGBA in 0..1, linear
    texture: np.ndarray | None = None  # (h, w, 4) uint8 RGBA, sRGB-encoded RGB, top row first
    alpha_cutoff: float | None = None
    double_sided: bool = True
    normals: np.ndarray | None = None  # (v, 3) float64 unit shading normals, world space
    normal_texture: np.ndarray | None = None  # (h, w, 4) uint8 tangent-space normal map, linear, top row first
    normal_uv: np.ndarray | None = None  # (v, 2) float64 the normal map's uv, origin bottom-left
    tangents: np.ndarray | None = None  # (v, 4) float64 world tangents (xyz unit) and handedness w = +-1
    normal_scale: float = 1.0
    metallic_factor: float = 0.0
    roughness_factor: float = 1.0
    metallic_roughness_texture: np.ndarray | None = None  # (h, w, 4) uint8, linear: G roughness, B metallic
    occlusion_texture: np.ndarray | None = None  # (h, w, 4) uint8, linear: R occlusion
    occlusion_strength: float = 1.0
    emissive_factor: np.ndarray = NO_EMISSION  # (3,) float64 linear RGB
    emissive_texture: np.ndarray | None = None  # (h, w, 4) uint8, sRGB-encoded RGB
    material_uv: np.ndarray | None = None  # (v, 2) float64 the material textures' uv
    prototype: str | None = None  # key of the instanced mesh's local content, None: not instanced
    instance_matrix: np.ndarray | None = field(default=None, repr=False)  # (4, 4) float64 local -> world
    local: SceneObject | None = field(default=None, repr=False)  # this primitive in the prototype's space
    bounds: np.ndarray = field(init=False, repr=False)  # (2, 3) float64: min, max corner

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise SceneLoadError(f"object name must be a non-empty string, got {self.name!r}")
        name = self.name
        set_ = object.__setattr__
        shares_uv = self.material_uv is not None and self.material_uv is self.uv  # kept shared once frozen
        vertices = _frozen(self.vertices, np.float64, "vertices", name, (None, 3))
        faces = _frozen(self.faces, np.int64, "faces", name, (None, 3))
        n = len(vertices)
        set_(self, "vertices", vertices)
        set_(self, "faces", faces)
        if self.uv is not None:
            set_(self, "uv", _frozen(self.uv, np.float64, "uv", name, (n, 2)))
        if self.vertex_colors is not None:
            set_(self, "vertex_colors", _frozen(self.vertex_colors, np.uint8, "vertex_colors", name, (n, 4)))
        set_(self, "base_color", _frozen(self.base_color, np.float64, "base_color", name, (4,)))
        if self.texture is not None:
            texture = _frozen(self.texture, np.uint8, "texture", name, (None, None, 4))
            if texture.shape[0] == 0 or texture.shape[1] == 0:
                raise SceneLoadError(f"object {name!r}: texture has shape {texture.shape}")
            if self.uv is None:
                raise SceneLoadError(f"object {name!r}: has a texture but no uv coordinates")
            set_(self, "texture", texture)
        if self.alpha_cutoff is not None:
            set_(self, "alpha_cutoff", float(self.alpha_cutoff))
        set_(self, "double_sided", bool(self.double_sided))
        if self.normals is not None:
            set_(self, "normals", _unit_normals(self.normals, name, n))
        _check_normal_map(self, name, n)
        if shares_uv:
            set_(self, "material_uv", self.uv)
        _check_material(self, name, n)
        _check_geometry(name, vertices, faces)
        _check_colour(name, self.base_color, self.uv, self.alpha_cutoff)
        _check_instance(self, name)
        bounds = np.stack([vertices.min(axis=0), vertices.max(axis=0)])
        bounds.flags.writeable = False
        set_(self, "bounds", bounds)

    # Fields with one row per vertex: what :meth:`with_faces` compacts.
    PER_VERTEX = ("vertices", "uv", "vertex_colors", "normals", "normal_uv", "tangents", "material_uv")

    def with_faces(self, faces: np.ndarray, name: str | None = None) -> SceneObject:
        """The object of its triangles ``faces`` (indices, a mask or an (f, 3) array of its vertex
        indices), vertices compacted, every per-vertex array, texture and material factor kept.

        >>> o = SceneObject("quad", np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.0]]), np.array([[0, 1, 2], [0, 2, 3]]))
        >>> o.with_faces([1], "half").faces.tolist(), len(o.with_faces([1]).vertices)
        ([[0, 1, 2]], 3)
        """
        chosen = np.asarray(faces)
        triangles = chosen if chosen.ndim == 2 else self.faces[chosen]
        # np.unique(triangles, return_inverse=True) without its sort: the used vertices in index
        # order, and each corner's rank among them
        mask = np.zeros(len(self.vertices), dtype=bool)
        mask[triangles.ravel()] = True
        used = np.flatnonzero(mask)
        inverse = (np.cumsum(mask) - 1)[triangles]
        changes = {"name": self.name if name is None else name, "faces": inverse.reshape(-1, 3)}
        for key in self.PER_VERTEX:
            array = getattr(self, key)
            if array is not None and not (key == "material_uv" and array is self.uv):
                changes[key] = array[used]
        if self.material_uv is not None and self.material_uv is self.uv:
            changes["material_uv"] = changes["uv"]
        return replace(self, **changes, prototype=None, instance_matrix=None, local=None)  # no longer the mesh

    @property
    def triangle_count(self) -> int:
        """Number of triangles, ``f``."""
        return len(self.faces)

    @property
    def colour_source(self) -> str:
        """The dominant colour source: ``"texture"``, ``"vertex"`` or ``"material"``."""
        if self.texture is not None:
            return "texture"
        if self.vertex_colors is not None:
            return "vertex"
        return "material"

    def summary(self) -> dict:
        """JSON-ready description: name, counts, bounds, colour source, alpha cutoff."""
        return {
            "name": self.name,
            "triangles": self.triangle_count,
            "vertices": len(self.vertices),
            "bounds": self.bounds.tolist(),
            "colour_source": self.colour_source,
            "base_color": self.base_color.tolist(),
            "texture_size": None if self.texture is None else [self.texture.shape[1], self.texture.shape[0]],
            "alpha_cutoff": self.alpha_cutoff,
            "double_sided": self.double_sided,
        }


def _check_geometry(name: str, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Raise unless ``faces`` index ``vertices`` and all coordinates are finite and not absurd."""
    if len(faces) == 0:
        raise DegenerateGeometryError(f"object {name!r} has no triangles")
    low, high = int(faces.min()), int(faces.max())
    if low < 0 or high >= len(vertices):
        raise SceneLoadError(
            f"object {name!r}: face index {low if low < 0 else high} out of range for {len(vertices)} vertices"
        )
    bad = ~np.isfinite(vertices).all(axis=1)
    if bad.any():
        raise DegenerateGeometryError(
            f"object {name!r}: {int(bad.sum())} of {len(vertices)} vertices have non-finite (NaN/Inf) coordinates"
        )
    largest = float(np.abs(vertices).max())
    if largest > TOL.max_coordinate:
        raise SceneLoadError(
            f"object {name!r}: coordinate magnitude {largest:.6g} exceeds the limit {TOL.max_coordinate:.6g} "
            "(corrupt file or wrong units?)"
        )


def _check_colour(name: str, base_color: np.ndarray, uv: np.ndarray | None, alpha_cutoff: float | None) -> None:
    """Raise unless colour factors lie in 0..1 and the uv are finite."""
    if not (np.isfinite(base_color).all() and base_color.min() >= 0.0 and base_color.max() <= 1.0):
        raise SceneLoadError(f"object {name!r}: base_color {base_color.tolist()} is not RGBA in 0..1")
    if uv is not None and not np.isfinite(uv).all():
        raise SceneLoadError(f"object {name!r}: {int((~np.isfinite(uv)).any(axis=1).sum())} non-finite uv coordinates")
    if alpha_cutoff is not None and not 0.0 <= alpha_cutoff <= 1.0:
        raise SceneLoadError(f"object {name!r}: alpha_cutoff {alpha_cutoff} is not in 0..1")


def _check_instance(obj: SceneObject, name: str) -> None:
    """Freeze and check the instancing fields: ``prototype``, ``instance_matrix`` and ``local``
    together or none.  An object whose triangles or vertices no longer match its ``local`` (a later
    stage kept some of its faces) is no longer an instance: its instancing fields are dropped."""
    parts = (obj.prototype, obj.instance_matrix, obj.local)
    if all(p is None for p in parts):
        return
    set_ = object.__setattr__
    if any(p is None for p in parts) or not isinstance(obj.prototype, str) or not isinstance(obj.local, SceneObject):
        raise SceneLoadError(f"object {name!r}: an instance needs prototype (str), instance_matrix and local together")
    matrix = _frozen(obj.instance_matrix, np.float64, "instance_matrix", name, (4, 4))
    if not np.isfinite(matrix).all() or not np.array_equal(matrix[3], [0.0, 0.0, 0.0, 1.0]):
        raise SceneLoadError(f"object {name!r}: instance_matrix is not a finite affine 4 x 4 matrix")
    if obj.local.faces.shape != obj.faces.shape or obj.local.vertices.shape != obj.vertices.shape:
        for key in ("prototype", "instance_matrix", "local"):
            set_(obj, key, None)
        return
    set_(obj, "instance_matrix", matrix)


def prototype_key(locals_: Iterable[SceneObject]) -> str:
    """The prototype key of a mesh of primitives ``locals_`` (in their local space, in order): 32 hex
    digits of a digest of their :func:`object_hash` es.  Equal content gives equal keys, whichever
    file, node or mesh index it came from."""
    digest = hashlib.sha256(HASH_VERSION + b":prototype;")
    memo: dict = {}
    for obj in locals_:
        digest.update(object_hash(obj, memo))
    return digest.hexdigest()[:32]


def instance_of(local: SceneObject, name: str, matrix, prototype: str) -> SceneObject:
    """The instance called ``name`` of ``local`` (a primitive in its prototype's space) moved by
    ``matrix`` (4, 4) local -> world: vertices, normals and tangents moved (normals by the inverse
    transpose), faces reversed under a mirroring matrix; textures, uv and colours shared by reference
    (:func:`instances_of` of one).

    >>> quad = SceneObject("q", np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0.0]]), np.array([[0, 1, 2]]))
    >>> moved = np.eye(4); moved[:3, 3] = (5, 0, 0)
    >>> o = instance_of(quad, "q@1", moved, "k")
    >>> o.vertices[1].tolist(), o.prototype, o.local is quad
    ([6.0, 0.0, 0.0], 'k', True)
    """
    return instances_of(local, [name], np.asarray(matrix, dtype=np.float64)[None], prototype)[0]


def instances_of(
    local: SceneObject, names: list[str], matrices: np.ndarray, prototype: str, normals: np.ndarray | None = None
) -> list[SceneObject]:
    """The instances ``names`` of ``local`` moved by ``matrices`` (n, 4, 4), as :func:`instance_of`
    makes each, all at once: the moves are one array operation per field, and only what a move can
    change is checked again (coordinates finite and in range, normals non-zero), the rest being
    ``local``'s, validated when it was made.  So n instances cost their arrays, not n validations
    of every field (a forest of 10,000 trees, an ``EXT_mesh_gpu_instancing`` node).  The instances'
    vertices (and normals, tangents) are read-only views of one array per field.

    ``normals``: (v, 3) local-space normals to move instead of ``local.normals`` (a loader's as
    read, not yet unit; the results are made unit).

    >>> tri = SceneObject("t", np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]]), np.array([[0, 1, 2]]))
    >>> m = np.stack([np.eye(4), np.diag([-1.0, 1.0, 1.0, 1.0])])
    >>> a, b = instances_of(tri, ["a", "b"], m, "k")
    >>> b.vertices[1].tolist(), b.faces.tolist(), a.faces is tri.faces
    ([-1.0, 0.0, 0.0], [[2, 1, 0]], True)

    Raises
    ------
    SceneLoadError
        A name that is no non-empty string, a matrix that is not finite and affine, coordinates
        beyond ``TOL.max_coordinate``, a normal the move makes zero.
    DegenerateGeometryError
        Non-finite coordinates.
    """
    from farfield.core.exchange.normals import normal_matrices, transform_tangents

    if not isinstance(prototype, str) or not isinstance(local, SceneObject):
        raise SceneLoadError("an instance needs prototype (str), instance_matrix and local together")
    for name in names:
        if not isinstance(name, str) or not name:
            raise SceneLoadError(f"object name must be a non-empty string, got {name!r}")
    matrices = np.array(matrices, dtype=np.float64)  # owned: each instance keeps a view
    if matrices.shape != (len(names), 4, 4):
        raise SceneLoadError(f"instances of {local.name!r}: {matrices.shape} matrices for {len(names)} names")
    affine = np.isfinite(matrices).all(axis=(1, 2)) & (matrices[:, 3] == (0.0, 0.0, 0.0, 1.0)).all(axis=1)
    if not affine.all():
        name = names[int(np.argmin(affine))]
        raise SceneLoadError(f"object {name!r}: instance_matrix is not a finite affine 4 x 4 matrix")
    if not names:
        return []
    matrices.flags.writeable = False
    linear = matrices[:, :3, :3]
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is refused below, by name
        vertices = local.vertices @ linear.transpose(0, 2, 1)  # (n, v, 3)
        vertices += matrices[:, None, :3, 3]  # in place: no second (n, v, 3) array at the peak
    vertices.flags.writeable = False
    flat = vertices.reshape(len(names), -1)  # x, y, z of each instance as strided columns: reduced fast
    low = np.stack([flat[:, axis::3].min(axis=1) for axis in range(3)], axis=1)
    high = np.stack([flat[:, axis::3].max(axis=1) for axis in range(3)], axis=1)
    bounds = np.stack([low, high], axis=1)  # (n, 2, 3)
    bounds.flags.writeable = False
    good = np.isfinite(bounds).all(axis=(1, 2)) & (np.abs(bounds).max(axis=(1, 2)) <= TOL.max_coordinate)
    if not good.all():
        i = int(np.argmin(good))
        _check_geometry(names[i], vertices[i], local.faces)  # raises, saying which
    mirrored = np.linalg.det(linear) < 0.0
    reversed_faces = _frozen(local.faces[:, ::-1], np.int64, "faces", local.name, (None, 3)) if mirrored.any() else None
    moved_normals = None
    source = local.normals if normals is None else np.asarray(normals, dtype=np.float64)
    if local.normals is not None and source is not None:
        moved_normals = source @ normal_matrices(linear).transpose(0, 2, 1)  # (n, v, 3)
        step = max(1, 2**18 // max(1, len(source)))  # instances a block: temporaries of about 2**18 vertices
        for start in range(0, len(names), step):
            block = moved_normals[start : start + step]
            with np.errstate(invalid="ignore", over="ignore"):
                length = np.sqrt(np.einsum("nij,nij->ni", block, block))  # as _unit_normals
            bad = ~(np.isfinite(length) & (length > 0.0))
            if bad.any():
                i = int(np.argmax(bad.any(axis=1)))
                count = f"{int(bad[i].sum())} of {bad.shape[1]}"
                raise SceneLoadError(f"object {names[start + i]!r}: {count} normals are zero or not finite")
            block /= length[:, :, None]
        moved_normals.flags.writeable = False
    set_ = object.__setattr__
    shared = [(key, getattr(local, key)) for key in SceneObject.__dataclass_fields__]
    out = []
    for i, name in enumerate(names):
        obj = object.__new__(SceneObject)
        for key, value in shared:
            set_(obj, key, value)
        set_(obj, "name", name)
        set_(obj, "vertices", vertices[i])
        set_(obj, "bounds", bounds[i])
        if mirrored[i]:
            set_(obj, "faces", reversed_faces)
        if moved_normals is not None:
            set_(obj, "normals", moved_normals[i])
        if local.tangents is not None:
            tangents = transform_tangents(local.tangents, linear[i])
            tangents.flags.writeable = False
            set_(obj, "tangents", tangents)
        set_(obj, "prototype", prototype)
        set_(obj, "instance_matrix", matrices[i])
        set_(obj, "local", local)
        out.append(obj)
    return out


def _check_normal_map(obj: SceneObject, name: str, n: int) -> None:
    """Freeze and check a normal map's parts: all of texture, uv and tangents, or none."""
    parts = (obj.normal_texture, obj.normal_uv, obj.tangents)
    if all(p is None for p in parts):
        return
    if any(p is None for p in parts):
        raise SceneLoadError(f"object {name!r}: a normal map needs normal_texture, normal_uv and tangents together")
    set_ = object.__setattr__
    texture = _frozen(obj.normal_texture, np.uint8, "normal_texture", name, (None, None, 4))
    if texture.shape[0] == 0 or texture.shape[1] == 0:
        raise SceneLoadError(f"object {name!r}: normal_texture has shape {texture.shape}")
    uv = _frozen(obj.normal_uv, np.float64, "normal_uv", name, (n, 2))
    tangents = _frozen(obj.tangents, np.float64, "tangents", name, (n, 4))
    if not np.isin(tangents[:, 3], (-1.0, 1.0)).all():  # the handedness is a sign: +-1 (glTF's TANGENT.w)
        tangents = tangents.copy()
        tangents[:, 3] = np.where(tangents[:, 3] < 0.0, -1.0, 1.0)
        tangents.flags.writeable = False
    if not (np.isfinite(uv).all() and np.isfinite(tangents).all()):
        raise SceneLoadError(f"object {name!r}: non-finite normal-map uv or tangents")
    scale = float(obj.normal_scale)
    if not math.isfinite(scale):
        raise SceneLoadError(f"object {name!r}: normal_scale {obj.normal_scale!r} is not finite")
    set_(obj, "normal_texture", texture)
    set_(obj, "normal_uv", uv)
    set_(obj, "tangents", tangents)
    set_(obj, "normal_scale", scale)


def _check_material(obj: SceneObject, name: str, n: int) -> None:
    """Freeze and check the metallic-roughness material: factors in range, textures RGBA8 with ``material_uv``."""
    set_ = object.__setattr__
    for key in ("metallic_factor", "roughness_factor", "occlusion_strength"):
        value = float(getattr(obj, key))
        if not 0.0 <= value <= 1.0:  # NaN fails too
            raise SceneLoadError(f"object {name!r}: {key} {getattr(obj, key)!r} is not in 0..1")
        set_(obj, key, value)
    emissive = _frozen(obj.emissive_factor, np.float64, "emissive_factor", name, (3,))
    if not (np.isfinite(emissive).all() and emissive.min() >= 0.0):
        raise SceneLoadError(f"object {name!r}: emissive_factor {emissive.tolist()} is not finite and >= 0")
    set_(obj, "emissive_factor", emissive)
    textures = ("metallic_roughness_texture", "occlusion_texture", "emissive_texture")
    for key in textures:
        if getattr(obj, key) is not None:
            texture = _frozen(getattr(obj, key), np.uint8, key, name, (None, None, 4))
            if texture.shape[0] == 0 or texture.shape[1] == 0:
                raise SceneLoadError(f"object {name!r}: {key} has shape {texture.shape}")
            set_(obj, key, texture)
    if obj.material_uv is not None:
        uv = (
            obj.material_uv
            if obj.material_uv is obj.uv
            else _frozen(obj.material_uv, np.float64, "material_uv", name, (n, 2))
        )
        if not np.isfinite(uv).all():
            raise SceneLoadError(f"object {name!r}: non-finite material uv")
        set_(obj, "material_uv", uv)
    elif any(getattr(obj, key) is not None for key in textures):
        raise SceneLoadError(f"object {name!r}: a material texture needs material_uv")


def _unit_normals(normals, name: str, n: int) -> np.ndarray:
    """``normals`` (n, 3) as read-only float64 unit vectors; a zero or non-finite one raises."""
    array = np.array(normals, dtype=np.float64)
    if array.shape != (n, 3):
        raise SceneLoadError(f"object {name!r}: normals has shape {array.shape}, expected ({n}, 3)")
    with np.errstate(invalid="ignore", over="ignore"):
        length = np.sqrt(np.einsum("ij,ij->i", array, array))
    bad = ~(np.isfinite(length) & (length > 0.0))
    if bad.any():
        raise SceneLoadError(f"object {name!r}: {int(bad.sum())} of {n} normals are zero or not finite")
    array /= length[:, None]
    array.flags.writeable = False
    return array


def _update_hash(digest: hashlib._Hash, tag: bytes, array: np.ndarray | None) -> None:
    """Feed a tagged array into ``digest``: tag, dtype, shape, then little-endian bytes."""
    digest.update(tag)
    if array is None:
        digest.update(b":none;")
        return
    little = array.astype(array.dtype.newbyteorder("<"), copy=False)
    digest.update(f":{little.dtype.str}:{little.shape};".encode())
    digest.update(np.ascontiguousarray(little).reshape(-1).view(np.uint8))  # the same bytes as tobytes(), not copied


def _texture_digest(texture: np.ndarray | None, memo: dict | None) -> np.ndarray | None:
    """A texture as the 32 bytes of its own tagged digest, so a texture many objects share is
    hashed once per :func:`content_hash` (``memo``: id -> digest while the objects are alive)."""
    if texture is None:
        return None
    found = None if memo is None else memo.get(id(texture))
    if found is None:
        inner = hashlib.sha256(HASH_VERSION + b":texture;")
        _update_hash(inner, b"texels", texture)
        found = np.frombuffer(inner.digest(), dtype=np.uint8)
        if memo is not None:
            memo[id(texture)] = found
    return found


def object_hash(obj: SceneObject, memo: dict | None = None) -> bytes:
    """SHA-256 digest (32 bytes) of one object's geometry, colour arrays and sidedness, name left
    out (the texture by its digest, :func:`_texture_digest`)."""
    digest = hashlib.sha256(HASH_VERSION)
    # Adding 0.0 maps -0.0 to +0.0, so equal coordinates give equal bytes.
    _update_hash(digest, b"vertices", obj.vertices + 0.0)
    _update_hash(digest, b"faces", obj.faces)
    _update_hash(digest, b"uv", None if obj.uv is None else obj.uv + 0.0)
    _update_hash(digest, b"vertex_colors", obj.vertex_colors)
    _update_hash(digest, b"base_color", obj.base_color + 0.0)
    _update_hash(digest, b"texture", _texture_digest(obj.texture, memo))
    cutoff = None if obj.alpha_cutoff is None else np.array([obj.alpha_cutoff], dtype=np.float64)
    _update_hash(digest, b"alpha_cutoff", cutoff)
    if not obj.double_sided:
        # Only a one-sided object adds a tag, so the hashes of double-sided objects stay as they were.
        digest.update(b"one-sided;")
    if obj.normals is not None:  # likewise: objects without shading normals hash as they did
        _update_hash(digest, b"normals", obj.normals + 0.0)
    if obj.normal_texture is not None:
        _update_hash(digest, b"normal_texture", _texture_digest(obj.normal_texture, memo))
        _update_hash(digest, b"normal_uv", obj.normal_uv + 0.0)
        _update_hash(digest, b"tangents", obj.tangents + 0.0)
        _update_hash(digest, b"normal_scale", np.array([obj.normal_scale], dtype=np.float64))
    if has_material(obj):  # likewise: a matte dielectric without material textures hashes as it did
        factors = [obj.metallic_factor, obj.roughness_factor, obj.occlusion_strength, *obj.emissive_factor]
        _update_hash(digest, b"material", np.array(factors, dtype=np.float64) + 0.0)
        _update_hash(digest, b"metallic_roughness", _texture_digest(obj.metallic_roughness_texture, memo))
        _update_hash(digest, b"occlusion", _texture_digest(obj.occlusion_texture, memo))
        _update_hash(digest, b"emissive", _texture_digest(obj.emissive_texture, memo))
        _update_hash(digest, b"material_uv", None if obj.material_uv is None else obj.material_uv + 0.0)
    return digest.digest()


def has_material(obj: SceneObject) -> bool:
    """Whether ``obj`` has more material than the default matte dielectric (metallic 0, roughness 1,
    no occlusion, no emission, no material texture)."""
    return (
        obj.metallic_factor != 0.0
        or obj.roughness_factor != 1.0
        or obj.metallic_roughness_texture is not None
        or obj.occlusion_texture is not None
        or obj.emissive_texture is not None
        or bool(obj.emissive_factor.any())
    )


def emits(obj: SceneObject) -> bool:
    """Whether ``obj`` emits light (a non-zero ``emissive_factor``; glTF multiplies the texture by it)."""
    return bool(obj.emissive_factor.any())


def content_hash(objects: Iterable[SceneObject]) -> str:
    """SHA-256 hex digest of the objects' geometry and colour arrays, independent of order and names.

    The digest is taken over the sorted per-object digests (:func:`object_hash`).  Names, object
    order and the source file name are left out, so the same content read from another path, from
    uploaded bytes, or through another version of the parser's node order has the same hash.
    ``-0.0`` is hashed as ``0.0``.

    Parameters
    ----------
    objects : iterable of SceneObject

    Returns
    -------
    str
        64 hex digits.
    """
    digest = hashlib.sha256(HASH_VERSION + b":scene;")
    objects = list(objects)  # alive while ``memo`` keys their textures by id
    memo: dict = {}
    for part in sorted(object_hash(obj, memo) for obj in objects):
        digest.update(part)
    return digest.hexdigest()


@dataclass(frozen=True, slots=True, eq=False)
class Scene:
    """Named objects in world space, validated, with bounds and a content hash.

    Build one with ``Scene(objects, source)`` or :meth:`from_objects`; the derived fields
    (``content_hash``, ``bounds``, ``triangle_count``) are computed on construction.  Compare
    scenes by ``content_hash`` (geometry and colour only: not names, order or source).

    Parameters
    ----------
    objects : tuple of SceneObject
        At least one; names unique.
    source : str
        Where the scene came from (a file name), for messages only; not part of the hash.
    warnings : tuple of str
        Recoverable problems met while loading (missing textures, skipped geometry).

    Raises
    ------
    DegenerateGeometryError
        No objects, or the scene's largest extent is below ``TOL.min_extent``.
    SceneLoadError
        Duplicate object names.
    """

    objects: tuple[SceneObject, ...]
    source: str
    warnings: tuple[str, ...] = ()
    content_hash: str = field(init=False)  # 64 hex digits, see content_hash()
    bounds: np.ndarray = field(init=False, repr=False)  # (2, 3) float64: min, max corner
    triangle_count: int = field(init=False)

    def __post_init__(self) -> None:
        objects = tuple(self.objects)
        object.__setattr__(self, "objects", objects)
        object.__setattr__(self, "warnings", tuple(str(w) for w in self.warnings))
        if not objects:
            raise DegenerateGeometryError("scene has no triangles (no objects)")
        names = [obj.name for obj in objects]
        if len(set(names)) != len(names):
            duplicates = sorted({n for n in names if names.count(n) > 1})
            raise SceneLoadError(f"duplicate object names: {', '.join(map(repr, duplicates))}")
        corners = np.stack([obj.bounds for obj in objects])  # (k, 2, 3)
        bounds = np.stack([corners[:, 0].min(axis=0), corners[:, 1].max(axis=0)])
        bounds.flags.writeable = False
        extent = float((bounds[1] - bounds[0]).max())
        if extent <= TOL.min_extent:
            raise DegenerateGeometryError(
                f"scene has zero extent: largest side {extent:.6g} <= {TOL.min_extent:.6g} "
                f"(all vertices at {bounds[0].tolist()})"
            )
        object.__setattr__(self, "bounds", bounds)
        object.__setattr__(self, "triangle_count", sum(obj.triangle_count for obj in objects))
        object.__setattr__(self, "content_hash", content_hash(objects))

    @classmethod
    def from_objects(cls, objects: Iterable[SceneObject], source: str, warnings: Iterable[str] = ()) -> Scene:
        """A validated scene of ``objects`` (any iterable) named ``source``."""
        return cls(tuple(objects), source, tuple(warnings))

    @property
    def object_count(self) -> int:
        """Number of objects."""
        return len(self.objects)

    @property
    def names(self) -> tuple[str, ...]:
        """Object names, in scene order."""
        return tuple(obj.name for obj in self.objects)

    @property
    def extents(self) -> np.ndarray:
        """(3,) float64 size of the bounding box, scene units."""
        return self.bounds[1] - self.bounds[0]

    def instances(self) -> dict[str, list[tuple[str, ...]]]:
        """The scene's instancing: each prototype key (:attr:`SceneObject.prototype`) -> its
        instances, each the names of its objects (one per primitive of the mesh), in scene order.
        Objects of one prototype with equal instance matrices are one instance.  Objects that are
        not instanced are left out; a scene without instancing gives ``{}``.

        >>> tri = SceneObject("t", np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]]), np.array([[0, 1, 2]]))
        >>> key = prototype_key([tri])
        >>> far = np.eye(4); far[:3, 3] = 3.0
        >>> scene = Scene((instance_of(tri, "t@0", np.eye(4), key), instance_of(tri, "t@1", far, key)), "demo")
        >>> scene.instances() == {key: [("t@0",), ("t@1",)]}
        True
        """
        grouped: dict[str, dict[bytes, list[str]]] = {}
        for obj in self.objects:
            if obj.prototype is not None:
                grouped.setdefault(obj.prototype, {}).setdefault(obj.instance_matrix.tobytes(), []).append(obj.name)
        return {key: [tuple(names) for names in by_matrix.values()] for key, by_matrix in grouped.items()}

    def prototype_objects(self, key: str) -> tuple[SceneObject, ...]:
        """The objects of prototype ``key`` in its local space (one per primitive of its mesh, those
        of its first instance), shared by reference with every instance.

        Raises
        ------
        SceneLoadError
            The scene has no prototype ``key``.
        """
        found = self.instances().get(key)
        if not found:
            raise SceneLoadError(f"{self.source}: no prototype {key!r}")
        by_name = {obj.name: obj for obj in self.objects}
        return tuple(by_name[name].local for name in found[0])

    def subset(self, names: Iterable[str]) -> Scene:
        """The scene restricted to the objects called ``names`` (kept in scene order).

        Raises
        ------
        SceneLoadError
            If ``names`` is empty or names an object the scene does not have.
        """
        wanted = list(dict.fromkeys(names))
        if not wanted:
            raise SceneLoadError(f"{self.source}: no object names given to select")
        known = set(self.names)
        unknown = [n for n in wanted if n not in known]
        if unknown:
            named = ", ".join(map(repr, unknown[:5])) + (f" and {len(unknown) - 5:,} more" if len(unknown) > 5 else "")
            raise SceneLoadError(
                f"{self.source}: no object named {named} of the {len(wanted):,} asked for "
                f"(the scene has {self.object_count} objects, e.g. {', '.join(map(repr, self.names[:5]))})"
            )
        chosen = set(wanted)
        return Scene(tuple(obj for obj in self.objects if obj.name in chosen), self.source, self.warnings)

    def summary(self) -> dict:
        """JSON-ready description of the scene and each object (see ``farfield inspect --json``)."""
        return {
            "source": self.source,
            "content_hash": self.content_hash,
            "object_count": self.object_count,
            "triangle_count": self.triangle_count,
            "bounds": self.bounds.tolist(),
            "extents": self.extents.tolist(),
            "objects": [obj.summary() for obj in self.objects],
            "warnings": list(self.warnings),
        }


def sample_texture(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Nearest texel of ``texture`` at each ``uv``, with repeat wrapping: the uv convention, executable.

    Parameters
    ----------
    texture : (h, w, c) array
        Image, top row first.
    uv : (n, 2) float64
        Texture coordinates, origin bottom-left, v up.

    Returns
    -------
    (n, c) array of ``texture.dtype``

    Examples
    --------
    >>> tex = np.array([[[1], [2]], [[3], [4]]])  # top row 1 2, bottom row 3 4
    >>> sample_texture(tex, np.array([[0.25, 0.25], [0.75, 0.75], [1.75, -0.75]])).ravel().tolist()
    [3, 2, 4]
    """
    uv = np.asarray(uv, dtype=np.float64)
    h, w = texture.shape[:2]
    wrapped = uv - np.floor(uv)  # repeat: into [0, 1)
    col = np.minimum((wrapped[:, 0] * w).astype(np.int64), w - 1)
    row = np.minimum(((1.0 - wrapped[:, 1]) * h).astype(np.int64), h - 1)
    return texture[row, col]
