"""What one scene file may cost to load: bounds on its structure, checked before the full parse.

A small file can describe a large amount of work: a 2.3 MB glTF with a 100,000-deep node chain
took 40 s to parse, a 6 MB GLB with 200,000 primitives 28 s and about 2 GB, 10^5 instanced nodes
8 s (issue 24's campaign).  The file size limit does not bound these, so the loaders check the
structure they can read cheaply (a glTF's JSON document) against :class:`SceneLimits` first and
refuse with :class:`farfield.core.errors.SceneTooCostlyError` (HTTP 413), naming the count and the limit.
The service sets the limits from ``FARFIELD_MAX_SCENE_*`` (``service/settings.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

from farfield.core.errors import SceneLoadError, SceneTooCostlyError

# glTF primitive modes (glTF 2.0 §5.24.4): triangles, triangle strip, triangle fan.
_TRIANGLES, _STRIP, _FAN = 4, 5, 6


@dataclass(frozen=True, slots=True)
class SceneLimits:
    """Largest structure a scene file may have; the defaults admit every scene of the test suite and
    of ``../shared/scenes`` with wide margins and keep a load under a few seconds."""

    nodes: int = 50_000  # glTF nodes
    depth: int = 128  # glTF node nesting
    primitives: int = 50_000  # glTF mesh primitives, counted once per instancing node
    accessors: int = 200_000  # glTF accessors
    triangles: int = 50_000_000  # triangles once node instancing is applied
    # Texels of one texture, read from its header before it is decoded: a 421 KB PNG can hold
    # 12000 x 12000 texels that decode to 2.3 GiB (issue 59).  8192 x 8192 passes.
    texture_pixels: int = 1 << 26
    # Texels of all the textures of one scene together (read from their headers as they come):
    # forty 8192 x 8192 textures pass one by one and decode to 10 GiB (issue 59, item 4).
    texture_pixels_total: int = 1 << 28

    def __post_init__(self) -> None:
        for name in (
            "nodes",
            "depth",
            "primitives",
            "accessors",
            "triangles",
            "texture_pixels",
            "texture_pixels_total",
        ):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"scene limit {name} must be a positive integer, got {value!r}")

    def check(self, what: str, count: int, name: str) -> None:
        """Raise :class:`SceneTooCostlyError` when ``count`` of ``what`` exceeds its limit."""
        limit = getattr(self, name)
        if count > limit:
            raise SceneTooCostlyError(
                f"{what}: {count:,} is beyond the limit of {limit:,} (FARFIELD_MAX_SCENE_{name.upper()})"
            )

    def texel_budget(self) -> TexelBudget:
        """A fresh :class:`TexelBudget` of these limits, for one load of one scene."""
        return TexelBudget(self.texture_pixels, self.texture_pixels_total)


class TexelBudget:
    """The texels one scene's load may decode: each texture at most ``per_texture`` and all together
    at most ``total``, checked from each image's header before it is decoded (:meth:`take`).  One
    budget is passed through a load wherever a texture limit goes (the loaders' ``max_pixels``).

    >>> budget = TexelBudget(per_texture=100, total=150)
    >>> budget.take((10, 10), "a")
    >>> try:
    ...     budget.take((10, 6), "b")
    ... except SceneTooCostlyError as error:
    ...     print(error)
    b: the scene's textures reach 160 texels with it, beyond the limit of 150 for all of a scene's textures together (FARFIELD_MAX_SCENE_TEXTURE_PIXELS_TOTAL)
    """

    def __init__(self, per_texture: int | None, total: int | None) -> None:
        self.per_texture, self.total, self.used = per_texture, total, 0

    def take(self, size: tuple[int, int], name: str, count: bool = True) -> None:
        """Count an image of ``size`` (w, h) about to be decoded (``count`` False: only check it,
        for an image read on the way to another that is counted); raise past either limit."""
        width, height = (int(v) for v in size)
        texels = width * height
        if self.per_texture is not None and texels > self.per_texture:
            raise SceneTooCostlyError(
                f"{name}: {width} x {height} texels is beyond the limit of {self.per_texture:,} texels per texture "
                "(FARFIELD_MAX_SCENE_TEXTURE_PIXELS); scale it down"
            )
        if self.total is not None and self.used + texels > self.total:
            raise SceneTooCostlyError(
                f"{name}: the scene's textures reach {self.used + texels:,} texels with it, beyond the limit of "
                f"{self.total:,} for all of a scene's textures together (FARFIELD_MAX_SCENE_TEXTURE_PIXELS_TOTAL)"
            )
        if count:
            self.used += texels


DEFAULT_LIMITS = SceneLimits()


def _list(document: dict, key: str) -> list:
    value = document.get(key, [])
    if not isinstance(value, list):
        raise SceneLoadError(f"glTF '{key}' is a {type(value).__name__}, not an array")
    return value


def _primitive_triangles(primitive: dict, accessors: list) -> int:
    """Triangles one primitive draws, from its accessors' counts (0 for points and lines)."""
    mode = primitive.get("mode", _TRIANGLES)
    index = primitive.get("indices")
    if index is None:
        attributes = primitive.get("attributes")
        index = attributes.get("POSITION") if isinstance(attributes, dict) else None
    count = 0
    if isinstance(index, int) and 0 <= index < len(accessors) and isinstance(accessors[index], dict):
        value = accessors[index].get("count", 0)
        count = value if isinstance(value, int) and value > 0 else 0
    if mode == _TRIANGLES:
        return count // 3
    if mode in (_STRIP, _FAN):
        return max(count - 2, 0)
    return 0


def check_gltf(document: dict, limits: SceneLimits = DEFAULT_LIMITS) -> None:
    """Check a glTF JSON document's structure against ``limits`` without parsing its buffers.

    Counts every node reachable from the document's scenes once per path (how trimesh instances
    them), its nesting depth, the primitives it draws and their triangles.

    Raises
    ------
    SceneTooCostlyError
        A count beyond its limit.
    SceneLoadError
        A node hierarchy with a cycle or a child index out of range.

    >>> doc = {"nodes": [{"children": [1]}, {"mesh": 0}], "scenes": [{"nodes": [0, 0]}],
    ...        "meshes": [{"primitives": [{"indices": 0}]}], "accessors": [{"count": 36}]}
    >>> check_gltf(doc)
    >>> check_gltf(doc, SceneLimits(triangles=20))
    Traceback (most recent call last):
    ...
    farfield.core.errors.SceneTooCostlyError: triangles once node instancing is applied: 24 is beyond the limit of 20 (FARFIELD_MAX_SCENE_TRIANGLES)
    """
    nodes, meshes, accessors = _list(document, "nodes"), _list(document, "meshes"), _list(document, "accessors")
    limits.check("glTF nodes", len(nodes), "nodes")
    limits.check("glTF accessors", len(accessors), "accessors")
    per_mesh = []
    for mesh in meshes:
        primitives = mesh.get("primitives", []) if isinstance(mesh, dict) else []
        primitives = [p for p in primitives if isinstance(p, dict)] if isinstance(primitives, list) else []
        per_mesh.append((len(primitives), sum(_primitive_triangles(p, accessors) for p in primitives)))
    roots = []
    for scene in _list(document, "scenes"):
        listed = scene.get("nodes", []) if isinstance(scene, dict) else []
        roots += [n for n in listed if isinstance(n, int)] if isinstance(listed, list) else []
    if not roots and "scenes" not in document:
        roots = list(range(len(nodes)))  # no scenes: trimesh takes the nodes themselves
    primitives = triangles = visits = 0
    stack = [(root, 1, ()) for root in roots]
    while stack:
        index, depth, path = stack.pop()
        if not isinstance(index, int) or not 0 <= index < len(nodes) or not isinstance(nodes[index], dict):
            raise SceneLoadError(f"glTF node index {index!r} is out of range (the file has {len(nodes)} nodes)")
        if index in path:
            raise SceneLoadError(f"glTF node {index} is its own ancestor (a cycle in the node hierarchy)")
        limits.check("glTF node nesting", depth, "depth")
        visits += 1
        limits.check("glTF nodes once instancing is applied", visits, "nodes")
        node = nodes[index]
        mesh = node.get("mesh")
        if isinstance(mesh, int) and 0 <= mesh < len(per_mesh):
            primitives += per_mesh[mesh][0]
            triangles += per_mesh[mesh][1]
            limits.check("glTF primitives once instancing is applied", primitives, "primitives")
            limits.check("triangles once node instancing is applied", triangles, "triangles")
        children = node.get("children", [])
        if isinstance(children, list):
            # The path is kept only as deep as the limit allows, so this stays linear in nodes x depth.
            stack += [(child, depth + 1, path + (index,)) for child in children]
