"""The impostor: a header (technique, view cell, reference viewpoint, ...), RGBA atlas pages
(H, W, 4) uint8 and a typed **payload**, the geometry drawn textured from those pages.

This is the in-memory form every technique produces and every consumer (bundle writer, GLB writer,
evaluation renderer, comparison, runtime) reads.  Consumers dispatch on the payload's ``kind``,
never on the technique's name:

``"quads"`` (:class:`QuadPayload`)
    World-space quads (q, 4, 3) float64, each with its own UVs, atlas page and layer: layered and
    environment-map impostors.
``"mesh"`` (:class:`MeshPayload`)
    An indexed triangle mesh: vertices (v, 3) float64 with UVs (v, 2), triangles (t, 3), and per
    triangle an atlas page and a mesh (connected component) label: textured depth meshes.

``"points"`` (:class:`PointPayload`)
    Points (n, 3) float64, each with one sRGB colour and, unless that colour is all it needs, a tile
    of directional colours in an atlas page over the sampling plane's rectangle, and optionally a
    normal each: point-based impostors (seed 001).

``"ldi"`` (:class:`LdiPayload`)
    A layered depth image (seed 004 §4): its camera; its layers are the pages, a colour page and a
    depth page each (:mod:`farfield.core.ldi.pages`), so that a runtime can splat its samples or warp them in
    occlusion-compatible order.

A payload draws and writes itself (:class:`Payload`): besides its arrays (``kind``, ``ARRAYS``,
``arrays()``, ``from_arrays()``, ``check()``, ``world_points()``) and figures (``count``,
``triangle_count``, ``quad_count``, ``point_count``, ``counts()``), each kind gives

* ``glb_parts(impostor, glb)``: its part of the impostor's GLB (primitives, materials, the pages shown
  as images, extensions), built with the writer's helpers (:class:`farfield.core.impostor.glb.GlbBuilder`);
* ``renderer(impostor)``: the renderer that draws it as its runtime does, for the evaluation and the
  comparison (:func:`farfield.core.quality.evaluation.impostor_renderer`);
* ``gbuffer(impostor, normals)``: its G-buffer renderer for the lit evaluation
  (:mod:`farfield.core.quality.lit`; triangle kinds by default: :meth:`draw_objects` with the normal pages;
  points and LDIs their own renderers, each point or sample with its normal);
* ``draw_objects(impostor)``: its runtime draw list, textured alpha-cut triangle objects, one per
  atlas page with geometry (the placement and environment-map runtimes draw these), or None
  when it is not drawn as triangles.

A new payload kind (frame atlases, say) is a frozen dataclass with these members registered with
:func:`register_payload_kind`: the bundle, GLB, evaluation and runtimes then take it as it is.

Conventions:

* Image arrays (layers, tiles, atlas pages) are **top row first**, as PNG and glTF store them.
* Texel rectangles are ``[x0, y0, x1, y1)`` integer texel indices in such an image (x right, y down).
* Quad corners are ordered as the corners of the quad's texel rectangle in its layer image:
  top-left, top-right, bottom-right, bottom-left (:func:`texel_rect_corners`).  A baked layer
  image's x runs along the plan's ``u`` and its y against ``v``, with u x v = the view axis (layered
  and environment-map plans alike), i.e. x runs right to left as seen from the reference
  viewpoint, so seen from there the order is top-right, top-left, bottom-left, bottom-right.  Each corner's UV is in glTF's convention: (0, 0) is the top-left of the page,
  (1, 1) the bottom-right.  Mesh vertices' UVs use the same convention; a mesh's triangles have
  no prescribed winding.  (The GLB writer orients every triangle to face the reference viewpoint.)
* Floating-point arrays are float64 and index arrays int64 in memory; the payload classes convert
  float and integer inputs of other widths on construction (and leave other dtypes for
  :meth:`check` to refuse).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal, Protocol, runtime_checkable

import numpy as np

from farfield.core.errors import BundleFormatError
from farfield.core.layering.plan import LayerPlan


def _canonical(value) -> np.ndarray:
    """``value`` as an array; float arrays as float64, integer arrays as int64, others unchanged."""
    array = np.asarray(value)
    if array.dtype.kind == "f":
        return array.astype(np.float64, copy=False)
    if array.dtype.kind in "iu":
        return array.astype(np.int64, copy=False)
    return array


def _check_arrays(payload, page_count: int) -> dict[str, int]:
    """Check ``payload``'s arrays against its ``ARRAYS`` table; return the sizes of its symbolic axes.

    ``ARRAYS`` lists ``(name, kind, shape)``: kind ``"f"`` (finite floats) or ``"i"`` (integers),
    shape a tuple of ints and axis names; every array naming an axis must agree on its length.
    """
    sizes: dict[str, int] = {}
    for name, kind, shape in payload.stored_arrays():
        array = getattr(payload, name)
        ok = isinstance(array, np.ndarray) and array.ndim == len(shape)
        if ok:
            for axis, length in zip(shape, array.shape):
                if isinstance(axis, str):
                    ok = ok and sizes.setdefault(axis, length) == length
                else:
                    ok = ok and axis == length
        if not ok:
            expected = tuple(sizes.get(a, a) if isinstance(a, str) else a for a in shape)
            raise BundleFormatError(
                f"{payload.kind} payload: {name} has shape {getattr(array, 'shape', None)}, expected {expected}"
            )
        if kind == "f":
            if array.dtype != np.float64 or not np.all(np.isfinite(array)):
                raise BundleFormatError(
                    f"{payload.kind} payload: {name} must be finite floats, got dtype {array.dtype}"
                )
        elif array.dtype != np.int64:
            raise BundleFormatError(f"{payload.kind} payload: {name} must be integers, got dtype {array.dtype}")
    page = getattr(payload, "page", None)
    if page is None:  # a payload without atlas pages (ldi)
        return sizes
    page = page[page != getattr(payload, "NO_PAGE", None)]  # a payload's "no page" value, if it has one
    if page.size and (page.min() < 0 or page.max() >= page_count):
        raise BundleFormatError(
            f"{payload.kind} payload: page spans [{page.min()}, {page.max()}] but there are {page_count} pages"
        )
    return sizes


class _PayloadBase:
    """What the payload kinds share: their arrays by name, and the defaults of the members a kind
    without quads, points or triangles to draw leaves alone."""

    __slots__ = ()
    ARRAYS: ClassVar[tuple]
    # Arrays a payload may keep or not (a channel kept per element, such as points' normals):
    # ``(name, kind, shape)`` as ``ARRAYS``; the field is None where it is not kept, and then it
    # is neither checked nor written, so a payload without it is stored as before it existed.
    OPTIONAL_ARRAYS: ClassVar[tuple] = ()

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]):
        names = [name for name, _, _ in cls.ARRAYS] + [name for name, _, _ in cls.OPTIONAL_ARRAYS if name in arrays]
        return cls(**{name: arrays[name] for name in names})

    def stored_arrays(self) -> tuple:
        """``ARRAYS`` and the optional arrays this payload keeps: what the bundle writes, in its order."""
        return tuple(self.ARRAYS) + tuple(a for a in self.OPTIONAL_ARRAYS if getattr(self, a[0]) is not None)

    def arrays(self) -> dict[str, np.ndarray]:
        """The payload's arrays by name, in the bundle's order."""
        return {name: getattr(self, name) for name, _, _ in self.stored_arrays()}

    @property
    def quad_count(self) -> int:
        """Quads drawn (a quad payload's); 0 for other kinds."""
        return 0

    @property
    def point_count(self) -> int:
        """Points or samples drawn one by one (not as triangles); 0 for triangle kinds."""
        return 0

    def check_pages(self, pages: tuple[np.ndarray, ...]) -> None:
        """Raise :class:`BundleFormatError` unless what the payload reads of the pages themselves
        (their sizes) fits; :meth:`check` has seen their count.  Nothing to check by default."""

    def draw_objects(self, impostor: Impostor) -> list | None:
        """The runtime's draw list (textured triangle objects); None: not drawn as triangles."""
        return None

    def gbuffer(self, impostor: Impostor, normals: bool = True):
        """The G-buffer renderer of the impostor for the lit evaluation (:mod:`farfield.core.quality.lit`):
        a :class:`farfield.core.render.raster.MeshRenderer` made with ``normals=True`` (its
        ``render_normals`` gives colour and world normals), drawing :meth:`draw_objects` with the
        impostor's normal pages as world-space normal maps when ``normals`` and it keeps them, else
        as flat cards, and with ``materials=True`` and its material pages (:func:`with_material_pages`)
        where it keeps them.  A kind not drawn as triangles overrides it, or raises ValueError."""
        from farfield.core.render.raster import MeshRenderer

        objects = self.draw_objects(impostor)
        if objects is None:
            raise ValueError(f"no lit evaluation for a {self.kind!r} payload yet")
        pages = impostor.channels.get("normal") if normals else None
        maps = [pages[page_of(obj)] for obj in objects] if pages is not None else None
        kept = "material" in impostor.channels
        if kept:
            objects = with_material_pages(objects, impostor.channels)
        return MeshRenderer(objects, normals=True, normal_maps=maps, materials=kept)


def with_material_pages(objects: list, channels: dict) -> list:
    """The draw objects (one per atlas page, :func:`page_of`) with their page's material channels as
    their material: the ORM page as ``metallic_roughness_texture`` and ``occlusion_texture`` (factors
    1, occlusion strength 1, ``material_uv`` their ``uv``) and the emissive page, where kept, as
    ``emissive_texture`` (factor 1, 1, 1), for the G-buffer's MeshRenderer."""
    from dataclasses import replace

    out = []
    for obj in objects:
        page = page_of(obj)
        orm = channels["material"][page]
        emissive = channels.get("emissive")
        out.append(replace(
            obj,
            metallic_factor=1.0,
            roughness_factor=1.0,
            metallic_roughness_texture=orm,
            occlusion_texture=orm,
            occlusion_strength=1.0,
            emissive_factor=np.ones(3) if emissive is not None else np.zeros(3),
            emissive_texture=emissive[page] if emissive is not None else None,
            material_uv=obj.uv,
        ))  # fmt: skip
    return out


def page_of(obj) -> int:
    """The atlas page a draw object of :meth:`Payload.draw_objects` shows (its name, ``page<k>``).

    >>> from farfield.core.scene import SceneObject
    >>> page_of(SceneObject("page12", np.eye(3), np.array([[0, 1, 2]])))
    12
    """
    return int(obj.name.removeprefix("page"))


def _page_objects(impostor: Impostor, page_triangles) -> list:
    """Textured alpha-cut (0.5) objects, one per atlas page with geometry: ``page_triangles(selected)``
    gives the (vertices, faces, uv in glTF's convention) of the payload's elements ``selected`` on a page."""
    from farfield.core.scene import SceneObject

    payload = impostor.payload
    objects = []
    for page_index, page in enumerate(impostor.pages):
        sel = np.flatnonzero(payload.page == page_index)
        if sel.size == 0:
            continue
        vertices, faces, uv = page_triangles(sel)
        uv[:, 1] = 1.0 - uv[:, 1]  # glTF (top-left origin) -> scene convention (bottom-left)
        objects.append(
            SceneObject(name=f"page{page_index}", vertices=vertices, faces=faces, uv=uv, texture=page, alpha_cutoff=0.5)
        )
    return objects


def _mesh_renderer(objects: list):
    from farfield.core.render.raster import MeshRenderer

    return MeshRenderer(objects)


@dataclass(frozen=True, slots=True)
class QuadPayload(_PayloadBase):
    """Textured quads: world corners TL, TR, BR, BL of each quad's texel rectangle (module docstring).

    >>> p = QuadPayload.empty()
    >>> p.kind, p.count, p.triangle_count, list(p.arrays())
    ('quads', 0, 0, ['corners', 'uv', 'page', 'layer'])
    """

    corners: np.ndarray  # (q, 4, 3) float64 world
    uv: np.ndarray  # (q, 4, 2) float64 page UV, glTF convention, same corner order
    page: np.ndarray  # (q,) int64 atlas page of each quad
    layer: np.ndarray  # (q,) int64 layer of each quad
    # (q, 2) float64, optional (None: no depth kept): the ray scales s0 < s1 between which each
    # quad's normal-page alpha a (0-255) places its texels' points, V + (P - V) (s0 + a / 255 (s1 - s0))
    # for the reference viewpoint V and the texel's point P on the quad (:mod:`farfield.core.impostor.depth`).
    depth_range: np.ndarray | None = None

    kind: ClassVar[str] = "quads"
    ARRAYS: ClassVar[tuple] = (
        ("corners", "f", ("q", 4, 3)),
        ("uv", "f", ("q", 4, 2)),
        ("page", "i", ("q",)),
        ("layer", "i", ("q",)),
    )
    OPTIONAL_ARRAYS: ClassVar[tuple] = (("depth_range", "f", ("q", 2)),)

    def __post_init__(self) -> None:
        for name, _, _ in self.stored_arrays():
            object.__setattr__(self, name, _canonical(getattr(self, name)))

    @classmethod
    def empty(cls) -> QuadPayload:
        return cls(np.zeros((0, 4, 3)), np.zeros((0, 4, 2)), np.zeros(0, np.int64), np.zeros(0, np.int64))

    @property
    def count(self) -> int:
        """Quads."""
        return int(self.corners.shape[0]) if self.corners.ndim else 0

    @property
    def triangle_count(self) -> int:
        """Triangles drawn: two per quad."""
        return 2 * self.count

    def counts(self) -> dict[str, int]:
        return {"quads": self.count}

    @property
    def quad_count(self) -> int:
        return self.count

    def world_points(self) -> np.ndarray:
        """(4q, 3) float64 every corner, world metres."""
        return self.corners.reshape(-1, 3)

    def check(self, page_count: int) -> None:
        """Raise :class:`BundleFormatError` unless the arrays fit (shapes, dtypes, finite, pages in range)."""
        _check_arrays(self, page_count)

    def glb_parts(self, impostor: Impostor, glb) -> Any:
        """Per page with quads one primitive of two triangles per quad, every page an image and a
        material; with a normal channel, lit materials with tangent-space normal textures."""
        normals = impostor.channels.get("normal")
        if normals is None:
            return glb.textured(glb.quad_pages(self, len(impostor.pages)), impostor.pages)
        if "material" in impostor.channels:  # metallic-roughness and occlusion (and emission) textures too
            material, emissive = impostor.channels["material"], impostor.channels.get("emissive")
            return glb.lit_quads(self, impostor.pages, normals, material, emissive)
        return glb.lit_quads(self, impostor.pages, normals)

    def draw_objects(self, impostor: Impostor) -> list:
        """A page's quads as two triangles each, one after the other (corners 0, 1, 2 and 0, 2, 3)."""

        def triangles(sel: np.ndarray):
            base = 4 * np.arange(sel.size, dtype=np.int64)[:, None]
            faces = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]], axis=1).reshape(-1, 3)  # a quad's two together
            return self.corners[sel].reshape(-1, 3), faces, self.uv[sel].reshape(-1, 2).copy()

        return _page_objects(impostor, triangles)

    def renderer(self, impostor: Impostor):
        """A :class:`farfield.core.render.raster.MeshRenderer` of :meth:`draw_objects`."""
        return _mesh_renderer(self.draw_objects(impostor))


@dataclass(frozen=True, slots=True)
class MeshPayload(_PayloadBase):
    """An indexed textured triangle mesh (a textured depth mesh's triangles, seed 003).

    A vertex is a (position, UV) pair: a position shared by triangles of two texture charts is two
    vertices.  :meth:`from_triangle_corners` builds one from per-triangle corners.

    >>> corners = np.array([[[0, 0, 5], [1, 0, 5], [1, 1, 5]], [[0, 0, 5], [1, 1, 5], [0, 1, 5]]], float)
    >>> uv = np.array([[[0, 1], [1, 1], [1, 0]], [[0, 1], [1, 0], [0, 0]]], float)
    >>> m = MeshPayload.from_triangle_corners(corners, uv, np.zeros(2, int), np.zeros(2, int))
    >>> m.kind, m.counts(), m.triangles.tolist()
    ('mesh', {'vertices': 4, 'triangles': 2}, [[0, 1, 2], [0, 2, 3]])
    >>> bool(np.array_equal(m.triangle_corners(), corners))
    True
    """

    vertices: np.ndarray  # (v, 3) float64 world
    uv: np.ndarray  # (v, 2) float64 page UV, glTF convention
    triangles: np.ndarray  # (t, 3) int64 vertex indices
    page: np.ndarray  # (t,) int64 atlas page of each triangle
    mesh: np.ndarray  # (t,) int64 mesh (connected component) of each triangle

    kind: ClassVar[str] = "mesh"
    ARRAYS: ClassVar[tuple] = (
        ("vertices", "f", ("v", 3)),
        ("uv", "f", ("v", 2)),
        ("triangles", "i", ("t", 3)),
        ("page", "i", ("t",)),
        ("mesh", "i", ("t",)),
    )

    def __post_init__(self) -> None:
        for name, _, _ in self.ARRAYS:
            object.__setattr__(self, name, _canonical(getattr(self, name)))

    @classmethod
    def empty(cls) -> MeshPayload:
        return cls(
            np.zeros((0, 3)), np.zeros((0, 2)), np.zeros((0, 3), np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64)
        )

    @classmethod
    def from_triangle_corners(cls, corners, uv, page, mesh) -> MeshPayload:
        """The mesh of triangles given by their corners (t, 3, 3) float64 world and corner UVs
        (t, 3, 2), with ``page`` and ``mesh`` (t,) per triangle.

        Corners with bit-equal position and UV become one vertex, numbered in the order of their
        first appearance (triangle by triangle, corner by corner), so the mesh draws exactly the
        given triangles and equal inputs give equal meshes.
        """
        corners = np.asarray(corners, dtype=np.float64).reshape(-1, 3, 3)
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 3, 2)
        t = corners.shape[0]
        if uv.shape[0] != t:
            raise BundleFormatError(f"mesh payload: {t} triangles' corners but {uv.shape[0]} triangles' UVs")
        rows = np.ascontiguousarray(np.concatenate([corners.reshape(-1, 3), uv.reshape(-1, 2)], axis=1))
        if t == 0:
            return cls(np.zeros((0, 3)), np.zeros((0, 2)), np.zeros((0, 3), np.int64), page, mesh)
        keys = rows.view(np.dtype((np.void, rows.dtype.itemsize * 5)))[:, 0]
        _, first, key_of = np.unique(keys, return_index=True, return_inverse=True)
        order = np.argsort(first, kind="stable")  # keys by first appearance
        slot = np.empty(first.size, np.int64)
        slot[order] = np.arange(first.size)
        kept = rows[first[order]]
        return cls(kept[:, :3], kept[:, 3:], slot[key_of.reshape(-1)].reshape(t, 3), page, mesh)

    @property
    def count(self) -> int:
        """Triangles."""
        return int(self.triangles.shape[0]) if self.triangles.ndim else 0

    @property
    def triangle_count(self) -> int:
        return self.count

    def counts(self) -> dict[str, int]:
        return {"vertices": int(self.vertices.shape[0]) if self.vertices.ndim else 0, "triangles": self.count}

    def world_points(self) -> np.ndarray:
        """(v, 3) float64 every vertex, world metres."""
        return self.vertices.reshape(-1, 3)

    def triangle_corners(self) -> np.ndarray:
        """(t, 3, 3) float64 world corners of each triangle."""
        return self.vertices[self.triangles]

    def triangle_uv(self) -> np.ndarray:
        """(t, 3, 2) float64 corner UVs of each triangle."""
        return self.uv[self.triangles]

    def glb_parts(self, impostor: Impostor, glb) -> Any:
        """Per page with triangles one primitive of its indexed triangles, every page an image and a
        material; with a normal channel, lit materials with tangent-space normal textures."""
        normals = impostor.channels.get("normal")
        if normals is None:
            return glb.textured(glb.mesh_pages(self, len(impostor.pages)), impostor.pages)
        if "material" in impostor.channels:  # metallic-roughness and occlusion (and emission) textures too
            material, emissive = impostor.channels["material"], impostor.channels.get("emissive")
            return glb.lit_mesh(self, impostor.pages, normals, material, emissive)
        return glb.lit_mesh(self, impostor.pages, normals)

    def draw_objects(self, impostor: Impostor) -> list:
        """A page's triangles in payload order, with the vertices they use."""

        def triangles(sel: np.ndarray):
            used, faces = np.unique(self.triangles[sel], return_inverse=True)
            return self.vertices[used], faces.reshape(-1, 3), self.uv[used].copy()

        return _page_objects(impostor, triangles)

    def renderer(self, impostor: Impostor):
        """A :class:`farfield.core.render.raster.MeshRenderer` of :meth:`draw_objects`."""
        return _mesh_renderer(self.draw_objects(impostor))

    def check(self, page_count: int) -> None:
        """Raise :class:`BundleFormatError` unless the arrays fit (shapes, dtypes, finite, pages and
        vertex indices in range)."""
        sizes = _check_arrays(self, page_count)
        if self.triangles.size and (self.triangles.min() < 0 or self.triangles.max() >= sizes["v"]):
            raise BundleFormatError(
                f"mesh payload: triangles index [{self.triangles.min()}, {self.triangles.max()}] "
                f"but there are {sizes['v']} vertices"
            )


@dataclass(frozen=True, slots=True)
class PointPayload(_PayloadBase):
    """Points with directional colours (seed 001 §5.3): ``positions`` (n, 3) float64 world;
    ``colour`` (n, 4) int64 sRGB bytes (alpha: the share of a pixel the part covers there), a
    point's only colour when ``page`` is -1 and its preview colour otherwise; ``page`` (n,) int64 the atlas page of its tile (-1: one colour); ``texel``
    (n, 2) int64 the tile's first texel (x, y) in its page; ``tile`` (2,) texels of a tile along u
    and v; the sampling plane ``plane`` (4,) (normal, offset: normal · x = offset), its in-plane
    axes ``axes`` (2, 3) (u, v) and the ``rectangle`` (2, 2) of plane coordinates (x · u, x · v)
    (lo, hi) the tiles span.  Row r, column c of a tile is the texel at the rectangle's (c + ½) / tu
    along u and (r + ½) / tv along v, where the ray from the eye to the point crosses the plane.

    ``normal`` (n, 3) float64, optional (None: not kept, ``channels="albedo"``): each point's unit
    world shading normal, on the side the view cell sees (:mod:`farfield.core.ldi.normals`).  One
    per point, also for a point with a tile of directional colours: the tile varies the colour
    with the viewing direction, not the normal.

    >>> p = PointPayload.empty()
    >>> p.kind, p.count, p.triangle_count, p.counts()
    ('points', 0, 0, {'points': 0, 'textured': 0})
    """

    positions: np.ndarray
    colour: np.ndarray
    page: np.ndarray
    texel: np.ndarray
    tile: np.ndarray
    plane: np.ndarray
    axes: np.ndarray
    rectangle: np.ndarray
    normal: np.ndarray | None = None
    # (n, 4) int64 bytes, optional (channels albedo+normal+material): each point's glTF ORM packing
    # (occlusion, roughness, metallic, 255) and, where an object of the part emits, its emission
    # sRGB-encoded (:mod:`farfield.core.ldi.materials`)
    material: np.ndarray | None = None
    emissive: np.ndarray | None = None

    kind: ClassVar[str] = "points"
    NO_PAGE: ClassVar[int] = -1
    ARRAYS: ClassVar[tuple] = (
        ("positions", "f", ("n", 3)),
        ("colour", "i", ("n", 4)),
        ("page", "i", ("n",)),
        ("texel", "i", ("n", 2)),
        ("tile", "i", (2,)),
        ("plane", "f", (4,)),
        ("axes", "f", (2, 3)),
        ("rectangle", "f", (2, 2)),
    )
    OPTIONAL_ARRAYS: ClassVar[tuple] = (
        ("normal", "f", ("n", 3)),
        ("material", "i", ("n", 4)),
        ("emissive", "i", ("n", 4)),
    )

    def __post_init__(self) -> None:
        for name, _, _ in self.stored_arrays():
            object.__setattr__(self, name, _canonical(getattr(self, name)))

    @classmethod
    def empty(cls) -> PointPayload:
        return cls(np.zeros((0, 3)), np.zeros((0, 4), np.int64), np.zeros(0, np.int64), np.zeros((0, 2), np.int64),
                   np.array([8, 2]), np.array([0.0, 0.0, 1.0, 0.0]), np.eye(3)[:2], np.array([[0.0, 0.0], [1.0, 1.0]]))  # fmt: skip

    @property
    def count(self) -> int:
        """Points."""
        return int(self.positions.shape[0]) if self.positions.ndim else 0

    @property
    def triangle_count(self) -> int:
        """Triangles drawn: none, points are drawn as points."""
        return 0

    def counts(self) -> dict[str, int]:
        return {"points": self.count, "textured": int((self.page >= 0).sum())}

    def world_points(self) -> np.ndarray:
        """(n, 3) float64 every point, world metres."""
        return self.positions.reshape(-1, 3)

    def check(self, page_count: int) -> None:
        """Raise :class:`BundleFormatError` unless the arrays fit (shapes, dtypes, finite, pages
        in range or -1, colours bytes, a tile of at least one texel, a unit normal)."""
        _check_arrays(self, page_count)
        if self.page.size and self.page.min() < -1:
            raise BundleFormatError(f"points payload: page must be -1 or a page index, got {int(self.page.min())}")
        if self.colour.size and (self.colour.min() < 0 or self.colour.max() > 255):
            raise BundleFormatError("points payload: colour must be bytes, 0-255")
        if self.tile.min() < 1:
            raise BundleFormatError(f"points payload: tile must be at least 1 x 1 texels, got {self.tile.tolist()}")
        if abs(float(np.linalg.norm(self.plane[:3])) - 1.0) > 1e-6 or np.any(self.rectangle[1] <= self.rectangle[0]):
            raise BundleFormatError("points payload: plane needs a unit normal and rectangle lo < hi")
        textured = self.page >= 0
        if textured.any() and self.texel[textured].min() < 0:
            raise BundleFormatError("points payload: a textured point's texel must be >= 0")
        if self.normal is not None and self.count and np.abs(np.linalg.norm(self.normal, axis=1) - 1.0).max() > 1e-6:
            raise BundleFormatError("points payload: every normal must be a unit vector")
        for name in ("material", "emissive"):
            values = getattr(self, name)
            if values is not None and values.size and (values.min() < 0 or values.max() > 255):
                raise BundleFormatError(f"points payload: {name} must be bytes, 0-255")

    @property
    def point_count(self) -> int:
        return self.count

    def check_pages(self, pages: tuple[np.ndarray, ...]) -> None:
        """Every tile inside its page."""
        textured = self.page >= 0
        if self.count and textured.any():
            shapes = np.array([page.shape[1::-1] for page in pages], dtype=np.int64)  # (width, height)
            beyond = self.texel[textured] + self.tile > shapes[self.page[textured]]
            if beyond.any():
                raise BundleFormatError(
                    f"points payload: {int(beyond.any(axis=1).sum())} tiles reach beyond their page"
                )

    def appearance(self, pages: tuple[np.ndarray, ...]):
        """The :class:`farfield.core.render.points.Appearance` of these points' tiles in ``pages``."""
        from farfield.core.render.points import Appearance

        return Appearance(
            pages,
            self.page,
            self.texel,
            (int(self.tile[0]), int(self.tile[1])),
            self.plane[:3],
            float(self.plane[3]),
            self.axes[0],
            self.axes[1],
            self.rectangle[0],
            self.rectangle[1],
        )

    def glb_parts(self, impostor: Impostor, glb) -> Any:
        """One ``POINTS`` primitive with one unlit material (with normals: ``NORMAL`` and a lit
        material); every page an image for the directional colours
        (:data:`farfield.core.impostor.glb.POINT_APPEARANCE`)."""
        return glb.points(self, impostor.pages)

    def renderer(self, impostor: Impostor):
        """A :class:`farfield.core.render.points.PointRenderer`: the points with their directional colours at the baked resolution's pixels."""
        from farfield.core.render.points import PointRenderer

        return PointRenderer(
            self.positions,
            self.colour.astype(np.uint8),
            self.appearance(impostor.pages),
            grid=(impostor.resolution, math.radians(impostor.fov_deg)),
        )

    def gbuffer(self, impostor: Impostor, normals: bool = True):
        """:meth:`renderer` as a G-buffer (``render_normals``): each point's pixels show its ``normal``
        when ``normals`` and it keeps them, else (flat cards) a normal facing the viewer, against
        the camera's forward axis, as a sprite's; with ``materials=True`` and each point's ``material``
        and ``emissive`` bytes where it keeps them (a material G-buffer, ``render_material``)."""
        from farfield.core.render.points import PointRenderer

        kept = self.material is not None
        return PointRenderer(
            self.positions,
            self.colour.astype(np.uint8),
            self.appearance(impostor.pages),
            grid=(impostor.resolution, math.radians(impostor.fov_deg)),
            gbuffer=True,
            normals=self.normal if normals else None,
            materials=self.material.astype(np.uint8) if kept else None,
            emissive=self.emissive.astype(np.uint8) if kept and self.emissive is not None else None,
        )


@dataclass(frozen=True, slots=True)
class LdiPayload(_PayloadBase):
    """A layered depth image (seed 004 §4) whose layers are the impostor's pages, two per layer
    (colour, then float32 depth as bytes: :mod:`farfield.core.ldi.pages`).  The payload is the LDI's camera:
    ``eye`` (3,), ``axes`` (3, 3) right, up, forward, ``window`` (5,) (tan of the half field of
    view, off-axis offset x, y in tangents, near and far plane depths), ``size`` (3,) (pixels per
    side, layers, samples) and ``quad`` (4, 3) its window on the near plane (top-left, top-right,
    bottom-right, bottom-left seen from the eye: the image quad of §3.3.2, and the GLB's fallback).

    >>> p = LdiPayload.empty()
    >>> p.kind, p.count, p.triangle_count, p.counts()
    ('ldi', 0, 0, {'samples': 0, 'layers': 0})
    """

    eye: np.ndarray
    axes: np.ndarray
    window: np.ndarray
    size: np.ndarray
    quad: np.ndarray

    kind: ClassVar[str] = "ldi"
    ARRAYS: ClassVar[tuple] = (
        ("eye", "f", (3,)),
        ("axes", "f", (3, 3)),
        ("window", "f", (5,)),
        ("size", "i", (3,)),
        ("quad", "f", (4, 3)),
    )

    def __post_init__(self) -> None:
        for name, _, _ in self.ARRAYS:
            object.__setattr__(self, name, _canonical(getattr(self, name)))

    @classmethod
    def empty(cls) -> LdiPayload:
        return cls(
            np.zeros(3),
            np.eye(3),
            np.array([1.0, 0.0, 0.0, 1.0, 2.0]),
            np.array([1, 0, 0]),
            np.array([[-1.0, 1, 1], [1, 1, 1], [1, -1, 1], [-1, -1, 1]]),
        )

    @property
    def count(self) -> int:
        """Samples."""
        return int(self.size[2])

    @property
    def triangle_count(self) -> int:
        """Triangles drawn: none, samples are splatted."""
        return 0

    def counts(self) -> dict[str, int]:
        return {"samples": self.count, "layers": int(self.size[1])}

    def world_points(self) -> np.ndarray:
        """(4, 3) float64 the image quad's corners, world metres (the samples lie behind it, in the pages)."""
        return self.quad.reshape(-1, 3)

    def check(self, page_count: int) -> None:
        """Raise :class:`BundleFormatError` unless the arrays fit (shapes, dtypes, finite, orthonormal
        axes, a window with a positive half tangent and 0 < near < far, two pages per layer)."""
        _check_arrays(self, page_count)
        if not np.allclose(self.axes @ self.axes.T, np.eye(3), atol=1e-6):
            raise BundleFormatError("ldi payload: axes must be orthonormal (right, up, forward)")
        if not (self.window[0] > 0 and 0 < self.window[3] < self.window[4]):
            raise BundleFormatError("ldi payload: window needs a half tangent > 0 and 0 < near < far")
        if self.size[0] < 1 or self.size[1] < 0 or self.size[2] < 0 or page_count != 2 * self.size[1]:
            raise BundleFormatError(
                f"ldi payload: {int(self.size[1])} layers need {2 * int(self.size[1])} pages, got {page_count}"
            )

    @property
    def point_count(self) -> int:
        return self.count

    def glb_parts(self, impostor: Impostor, glb) -> Any:
        """The fallback a glTF viewer shows: the first layer's colour page on the image quad
        (:mod:`farfield.core.ldi.pages`); the samples stay in the bundle.  With a normal channel
        the quad is lit: its first normal page as a tangent-space normal texture (:meth:`GlbBuilder.lit_quads
        <farfield.core.impostor.glb.GlbBuilder.lit_quads>`)."""
        shown = impostor.pages[:1]
        quad = QuadPayload(
            self.quad[None],
            np.array([[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]]),
            np.zeros(1, np.int64),
            np.zeros(1, np.int64),
        )
        normals = impostor.channels.get("normal")
        if normals is not None and shown and "material" in impostor.channels:  # the first layer's material too
            emissive = impostor.channels.get("emissive")
            return glb.lit_quads(quad, shown, normals[:1], impostor.channels["material"][:1], emissive and emissive[:1])
        if normals is not None and shown:
            return glb.lit_quads(quad, shown, normals[:1])
        return glb.textured(glb.quad_pages(quad, len(shown)) if shown else (), shown)

    def renderer(self, impostor: Impostor):
        """A :class:`farfield.core.render.splats.SplatRenderer` of the LDI's samples."""
        from farfield.core.ldi.image import ldi_of
        from farfield.core.render.splats import SplatRenderer

        return SplatRenderer([], [ldi_of(impostor)])

    def gbuffer(self, impostor: Impostor, normals: bool = True):
        """:meth:`renderer` as a G-buffer (``render_normals``): each splat shows its sample's normal
        (the normal channel's page ``2k`` for layer ``k``) when ``normals`` and the impostor keeps
        them, else (flat cards) a normal facing the viewer, as a sprite's; with ``materials`` (a
        material G-buffer, ``render_material``) each sample's bytes of the material (and emissive)
        channel's page ``2k`` where it keeps them."""
        from dataclasses import replace

        from farfield.core.ldi.image import ldi_of
        from farfield.core.render.splats import SplatRenderer

        ldi = ldi_of(impostor)
        materials = None
        if "material" in impostor.channels:
            index = np.argwhere(np.isfinite(ldi.depth))  # the samples' order, as the splats are drawn

            def per_sample(name: str) -> np.ndarray | None:
                pages = impostor.channels.get(name)
                if pages is None:
                    return None
                stacked = np.stack([pages[2 * k] for k in range(ldi.layers)])
                return stacked[index[:, 0], index[:, 1], index[:, 2]]

            materials = (per_sample("material"), per_sample("emissive"))
        pages = impostor.channels.get("normal") if normals else None
        if pages is not None:
            layers = int(self.size[1])
            ldi = replace(
                ldi,
                normal=np.stack([decode_normals(pages[2 * k]) for k in range(layers)]).reshape(ldi.depth.shape + (3,)),
            )
        return SplatRenderer([], [ldi], gbuffer=True, materials=materials)


@runtime_checkable
class Payload(Protocol):
    """What every consumer asks of a payload (the module docstring); the four kinds above have it."""

    kind: ClassVar[str]
    ARRAYS: ClassVar[tuple]

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> Payload: ...
    def arrays(self) -> dict[str, np.ndarray]: ...
    def check(self, page_count: int) -> None: ...
    def check_pages(self, pages: tuple[np.ndarray, ...]) -> None: ...
    def world_points(self) -> np.ndarray: ...
    def counts(self) -> dict[str, int]: ...
    @property
    def count(self) -> int: ...
    @property
    def triangle_count(self) -> int: ...
    @property
    def quad_count(self) -> int: ...
    @property
    def point_count(self) -> int: ...
    def glb_parts(self, impostor: Impostor, glb) -> Any:
        """Its part of the impostor's GLB: a :class:`farfield.core.impostor.glb.GlbParts` built with ``glb``'s helpers."""

    def renderer(self, impostor: Impostor) -> Any:
        """A renderer (``render(camera)``, ``release()``, a context manager) that draws it as its runtime does."""

    def draw_objects(self, impostor: Impostor) -> list | None:
        """Its runtime draw list: textured triangle objects, or None when it is not drawn as triangles."""

    def gbuffer(self, impostor: Impostor, normals: bool = True) -> Any:
        """Its G-buffer renderer for the lit evaluation (``render_normals(camera)``: colour and world normals)."""


# Payload kind -> class: what the bundle reader builds from a manifest's ``payload.kind``.
PAYLOAD_KINDS: dict[str, type] = {}


def register_payload_kind(cls: type) -> type:
    """Add a payload class to :data:`PAYLOAD_KINDS` under its ``kind`` (refusing a kind taken); returns it."""
    if cls.kind in PAYLOAD_KINDS:
        raise ValueError(f"a payload kind {cls.kind!r} is registered already")
    PAYLOAD_KINDS[cls.kind] = cls
    return cls


for _cls in (QuadPayload, MeshPayload, PointPayload, LdiPayload):
    register_payload_kind(_cls)


@dataclass(frozen=True, slots=True)
class Impostor:
    """One impostor of one part for one view cell: a header, atlas pages and a payload."""

    technique: str
    viewcell: dict  # BoxCell.to_dict() / ShaftCell.to_dict()
    reference_viewpoint: np.ndarray  # (3,) float64 world
    resolution: int  # output image pixels per side it was made for
    fov_deg: float  # output field of view it was made for
    pages: tuple[np.ndarray, ...]  # each (H, W, 4) uint8, top row first
    payload: Payload  # the geometry drawn from the pages
    layers: list[dict] = field(default_factory=list)  # per layer: distance, depth range (eye depth), texels kept
    stats: dict = field(default_factory=dict)  # counts, memory, timings per stage
    parameters: dict = field(default_factory=dict)  # every knob that made it
    code_version: str = ""
    # Channels kept beside the colour (:data:`PAGE_CHANNELS`): name -> pages laid out as ``pages``
    # (same count and sizes, the same texel for the same surface point).  Empty: colour only.
    channels: dict = field(default_factory=dict)

    @property
    def quad_count(self) -> int:
        """Quads of a quad payload; 0 for any other payload."""
        return self.payload.quad_count

    @property
    def triangle_count(self) -> int:
        """Triangles drawn: two per quad, one per mesh triangle, none for points."""
        return self.payload.triangle_count

    @property
    def texture_bytes(self) -> int:
        """Uncompressed RGBA bytes of all atlas pages."""
        return int(sum(p.shape[0] * p.shape[1] * 4 for p in self.pages))

    def _quads(self) -> QuadPayload:
        if not isinstance(self.payload, QuadPayload):
            raise AttributeError(f"a {self.technique} impostor has a {self.payload.kind!r} payload, not quads")
        return self.payload

    # Read-only conveniences for quad payloads (layered, envmap); they raise for any other payload.
    @property
    def quad_corners(self) -> np.ndarray:
        return self._quads().corners

    @property
    def quad_uv(self) -> np.ndarray:
        return self._quads().uv

    @property
    def quad_page(self) -> np.ndarray:
        return self._quads().page

    @property
    def quad_layer(self) -> np.ndarray:
        return self._quads().layer


# The channels a texel can keep beside its colour, each as pages parallel to the colour pages:
# ``normal``, the world-space unit shading normal encoded n * 0.5 + 0.5 in RGB (linear, not sRGB),
# alpha 255 inside a tile (or, where the channel set keeps ``depth``, the texel's depth: see the
# technique's docs).  World space keeps a bundle independent of how its geometry is drawn; the GLB
# writer turns it into each quad's tangent space (:mod:`farfield.core.impostor.glb`).
# ``material``, glTF's packing of occlusion (R), roughness (G) and metallic (B), linear, alpha 255
# inside a tile: one page serves as both the GLB's ``occlusionTexture`` and its
# ``metallicRoughnessTexture``.  ``emissive``, linear emission encoded sRGB in RGB, kept only where
# an object of the part emits (:func:`farfield.core.scene.emits`).
PAGE_CHANNELS = ("normal", "material", "emissive")
# What a technique's ``channels`` option takes: the colour alone (unlit, for baked lighting), with
# normals, and with the glTF material (occlusion, roughness, metallic, emission) and the depth.
ChannelSet = Literal[
    "albedo",
    "albedo+normal",
    "albedo+normal+depth",
    "albedo+normal+material",
    "albedo+normal+material+depth",
]


# The ``channels`` option's help, for every technique (quad techniques keep depth; the others refuse it).
CHANNELS_HELP = (
    "what each texel (point, sample) keeps: albedo (unlit colour, for baked lighting); albedo+normal (world "
    "shading normals too, so that an engine can light the impostor: normal pages); +material (glTF's occlusion, "
    "roughness and metallic, and emission where the part emits: material and emissive pages, what a glTF "
    "metallic-roughness material with maps needs); +depth (layered and envmap: each texel's depth in its slab, "
    "in the normal pages' alpha, for a pixel depth offset)"
)


def channel_names(channels: str) -> frozenset[str]:
    """The names in the channel set ``channels`` (:data:`ChannelSet`).

    >>> sorted(channel_names("albedo+normal+material"))
    ['albedo', 'material', 'normal']
    """
    return frozenset(str(channels).split("+"))


def wants_normals(channels: str) -> bool:
    """Whether the channel set ``channels`` (:data:`ChannelSet`) keeps normals."""
    return "normal" in channel_names(channels)


def wants_material(channels: str) -> bool:
    """Whether the channel set ``channels`` keeps the material (occlusion, roughness, metallic, emission)."""
    return "material" in channel_names(channels)


def keeps_material(channels: str, objects) -> bool:
    """Whether a bake with the channel set ``channels`` of ``objects`` records the material pages:
    asked for, and some object has a material other than the matte default
    (:func:`farfield.core.scene.has_material`).  A matte part's pages would hold (1, 1, 0) in every
    texel, which the GLB's default metallic-roughness factors (metallic 0, roughness 1) say already:
    they are left out, as the emissive pages are where nothing emits."""
    from farfield.core.scene import has_material

    return wants_material(channels) and any(has_material(obj) for obj in objects)


def wants_depth(channels: str) -> bool:
    """Whether the channel set ``channels`` keeps each texel's depth."""
    return "depth" in channel_names(channels)


def decode_normals(page: np.ndarray) -> np.ndarray:
    """(..., 3) float64 unit world normals of a normal page's texels (..., 4) uint8 (zero length
    where the texel holds none).

    >>> decode_normals(np.array([[128, 128, 255, 255]], np.uint8)).round(3).tolist()
    [[0.004, 0.004, 1.0]]
    """
    n = np.asarray(page)[..., :3].astype(np.float64) / 127.5 - 1.0
    length = np.linalg.norm(n, axis=-1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0.25)


def encode_normals(normals: np.ndarray) -> np.ndarray:
    """(..., 4) uint8 texels of (..., 3) unit normals: n * 0.5 + 0.5 rounded, alpha 255.

    >>> encode_normals(np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])).tolist()
    [[128, 128, 255, 255], [0, 128, 128, 255]]
    """
    n = np.asarray(normals, dtype=np.float64)
    rgb = np.clip(np.floor((n * 0.5 + 0.5) * 255.0 + 0.5), 0, 255).astype(np.uint8)
    return np.concatenate([rgb, np.full(n.shape[:-1] + (1,), 255, np.uint8)], axis=-1)


def texel_rect_corners(plan: LayerPlan, layer_distance: float, rects: np.ndarray) -> np.ndarray:
    """World corners (q, 4, 3) float64 of texel rectangles (q, 4) int ``[x0, y0, x1, y1)`` on one layer.

    The layer plane lies ``layer_distance`` from the view cell's near border (the plan's t), i.e.
    at eye depth ``t + s`` from the reference viewpoint, and spans the recording frustum.  Image x
    runs along ``plan.u``, image y (top row first) against ``plan.v``.
    """
    rects = np.asarray(rects, dtype=np.float64).reshape(-1, 4)
    res = plan.texture_resolution.astype(np.float64)
    depth = float(layer_distance) + plan.reference_offset
    x = np.stack([rects[:, 0], rects[:, 2], rects[:, 2], rects[:, 0]], axis=1)  # TL TR BR BL
    y = np.stack([rects[:, 1], rects[:, 1], rects[:, 3], rects[:, 3]], axis=1)
    ndc_x = x / res[0] * 2.0 - 1.0
    ndc_y = 1.0 - y / res[1] * 2.0
    ex = ndc_x * plan.frustum_half_tangents[0] * depth
    ey = ndc_y * plan.frustum_half_tangents[1] * depth
    return plan.reference_viewpoint + ex[..., None] * plan.u + ey[..., None] * plan.v + depth * plan.axis


def check_impostor(impostor: Impostor) -> None:
    """Raise unless the impostor's arrays have the shapes and dtypes every writer relies on.

    Parameters
    ----------
    impostor : Impostor
        ``reference_viewpoint`` (3,) finite, every page (H, W, 4) uint8 with H, W >= 1, a payload
        of a kind in :data:`PAYLOAD_KINDS` whose :meth:`check` passes (its float arrays float64
        and finite, its index arrays int64, every page index into ``pages``).

    Raises
    ------
    BundleFormatError
        Naming the first field that does not fit.

    Examples
    --------
    >>> quads = QuadPayload(np.zeros((1, 4, 3)), np.zeros((1, 4, 2)), np.zeros(1, np.int64), np.zeros(1, np.int64))
    >>> bad = Impostor("layered", {}, np.zeros(3), 64, 60.0, (np.zeros((2, 2, 4), np.float32),), quads)
    >>> check_impostor(bad)
    Traceback (most recent call last):
    ...
    farfield.core.errors.BundleFormatError: page 0 is (2, 2, 4) float32, expected (H, W, 4) uint8
    """
    viewpoint = np.asarray(impostor.reference_viewpoint)
    if viewpoint.shape != (3,) or not np.all(np.isfinite(viewpoint)):
        raise BundleFormatError(f"reference_viewpoint must be 3 finite numbers, got {viewpoint!r}")
    for index, page in enumerate(impostor.pages):
        if not isinstance(page, np.ndarray) or page.dtype != np.uint8 or page.ndim != 3 or page.shape[2] != 4:
            shape = getattr(page, "shape", None)
            raise BundleFormatError(
                f"page {index} is {shape} {getattr(page, 'dtype', type(page).__name__)}, expected (H, W, 4) uint8"
            )
        if page.shape[0] < 1 or page.shape[1] < 1:
            raise BundleFormatError(f"page {index} is empty: {page.shape}")
    if not isinstance(impostor.channels, dict):
        raise BundleFormatError(f"channels is a {type(impostor.channels).__name__}, expected a dict")
    for name, pages in impostor.channels.items():
        if name not in PAGE_CHANNELS:
            raise BundleFormatError(f"unknown channel {name!r}; known: {', '.join(PAGE_CHANNELS)}")
        if not isinstance(pages, tuple) or len(pages) != len(impostor.pages):
            raise BundleFormatError(f"channel {name!r} has {len(pages)} pages, the colour {len(impostor.pages)}")
        for index, (page, colour) in enumerate(zip(pages, impostor.pages)):
            if not isinstance(page, np.ndarray) or page.dtype != np.uint8 or page.shape != colour.shape:
                raise BundleFormatError(
                    f"channel {name!r} page {index} is {getattr(page, 'shape', None)} {getattr(page, 'dtype', '')}, "
                    f"expected {colour.shape} uint8 like colour page {index}"
                )
    payload = impostor.payload
    if PAYLOAD_KINDS.get(getattr(payload, "kind", None)) is not type(payload):
        raise BundleFormatError(f"payload is a {type(payload).__name__}, expected one of {sorted(PAYLOAD_KINDS)}")
    payload.check(len(impostor.pages))
    payload.check_pages(impostor.pages)
