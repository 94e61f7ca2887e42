"""The object hierarchy of a placement (seed 000 §5.4, Obs. 5.2.1): elements and a bounding-volume hierarchy over them.

An *element* is what the hierarchy clusters: a scene object, or, for an object with more triangles
than ``cluster_triangles``, one of the spatial clusters it is split into (named ``object#k``), so
that a scene of one huge mesh (a scan, a city exported as one object) still gives the placement
something to choose from.  The split is a median split of triangle centroids along the longest
axis of their bounds, repeated until every cluster is small enough; stable sorts make it
deterministic.  A split object's draw call is shared among its clusters (each counts
``1 / clusters``), so drawing all of them costs the object's one call.

The hierarchy is a binary BVH built top-down by the same median split of element centroids; nodes
are numbered in preorder, so node ``i``'s subtree is ``[i, i + size[i])`` and its elements are
``order[start[i]:end[i]]``: ancestor tests and per-node sums are range operations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from farfield.core.errors import FarfieldError
from farfield.core.scene import Scene
from farfield.core.techniques.envmap.near_field import face_ranges

DEFAULT_LEAF_SIZE = 4  # elements per leaf at most
OVERSIZED = 0.5  # an element whose diagonal passes this share of its node's is split off (see Hierarchy.build)
MIN_CLUSTER_TRIANGLES = 64
CLUSTERS_PER_SCENE = 256  # a scene is cut into about this many clusters at least, whatever its objects


class PlacementError(FarfieldError):
    """A placement that cannot be computed from its inputs (bad view space, budget or knobs)."""


def default_cluster_triangles(scene: Scene) -> int:
    """Triangles above which an object is split: ``max(64, total / 256)``.

    >>> from farfield.core.scene import SceneObject
    >>> default_cluster_triangles(Scene.from_objects([SceneObject("t", [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])], "x"))
    64
    """
    return max(MIN_CLUSTER_TRIANGLES, math.ceil(scene.triangle_count / CLUSTERS_PER_SCENE))


def _median_split(centroids: np.ndarray, index: np.ndarray, limit: int) -> list[np.ndarray]:
    """``index`` cut by median splits of ``centroids[index]`` along the longest axis into pieces of at most ``limit``."""
    out, stack = [], [index]
    while stack:
        part = stack.pop()
        c = centroids[part]
        extent = c.max(axis=0) - c.min(axis=0)
        if part.size <= limit or not np.any(extent > 0.0):
            out.append(part)
            continue
        axis = int(np.argmax(extent))
        ordered = part[np.argsort(c[:, axis], kind="stable")]
        half = ordered.size // 2
        stack.append(np.sort(ordered[half:]))  # popped second: low half first in the output
        stack.append(np.sort(ordered[:half]))
    return out


@dataclass(frozen=True, slots=True, eq=False)
class Elements:
    """The placement's unit of geometry: objects, or clusters of the triangles of large ones.

    ``faces[i]`` is None for a whole object, else the (f,) int64 face indices of object
    ``object_index[i]`` it holds.
    """

    names: tuple[str, ...]
    object_index: np.ndarray  # (e,) int64
    faces: tuple[np.ndarray | None, ...]
    bounds: np.ndarray  # (e, 2, 3) float64
    triangles: np.ndarray  # (e,) int64
    draw_calls: np.ndarray  # (e,) float64
    cluster_triangles: int

    @property
    def count(self) -> int:
        return len(self.names)

    @classmethod
    def of(cls, scene: Scene, cluster_triangles: int | None = None) -> Elements:
        """The elements of ``scene``: objects, large ones split into clusters of at most ``cluster_triangles``."""
        limit = default_cluster_triangles(scene) if cluster_triangles is None else int(cluster_triangles)
        if limit < 1:
            raise PlacementError(f"cluster_triangles must be >= 1, got {cluster_triangles!r}")
        names, owner, faces, bounds, tris, calls = [], [], [], [], [], []
        taken = set(scene.names)
        for i, obj in enumerate(scene.objects):
            if obj.triangle_count <= limit:
                names.append(obj.name), owner.append(i), faces.append(None), bounds.append(obj.bounds)
                tris.append(obj.triangle_count), calls.append(1.0)
                continue
            corners = obj.vertices[obj.faces]  # (f, 3, 3)
            pieces = _median_split(corners.mean(axis=1), np.arange(obj.triangle_count), limit)
            for k, piece in enumerate(pieces):
                c = corners[piece].reshape(-1, 3)
                name = f"{obj.name}#{k}"
                while name in taken:  # an object of the scene already has this name
                    name += "'"
                taken.add(name)
                names.append(name), owner.append(i), faces.append(piece)
                bounds.append(np.stack([c.min(axis=0), c.max(axis=0)]))
                tris.append(piece.size), calls.append(1.0 / len(pieces))
        return cls(
            tuple(names),
            np.asarray(owner, dtype=np.int64),
            tuple(faces),
            np.asarray(bounds, dtype=np.float64).reshape(-1, 2, 3),
            np.asarray(tris, dtype=np.int64),
            np.asarray(calls, dtype=np.float64),
            limit,
        )

    def clusters(self, scene: Scene) -> dict[str, dict]:
        """The clusters of split objects, by name: ``object`` (the object's name) and ``faces`` (its
        face-index ranges ``[start, end)``, ascending), for a runtime that draws an object less the
        clusters an impostor replaces (the 3D view).

        >>> from farfield.core.scene import SceneObject
        >>> strip = SceneObject("strip", np.array([[x, y, 0.0] for x in range(9) for y in (0, 1)]), np.array([[2 * i, 2 * i + 2, 2 * i + 1] for i in range(8)]))
        >>> Elements.of(Scene.from_objects([strip], "s"), 4).clusters(Scene.from_objects([strip], "s"))
        {'strip#0': {'object': 'strip', 'faces': [[0, 4]]}, 'strip#1': {'object': 'strip', 'faces': [[4, 8]]}}
        """
        out = {}
        for i, piece in enumerate(self.faces):
            if piece is not None:
                selected = np.zeros(scene.objects[int(self.object_index[i])].triangle_count, dtype=bool)
                selected[piece] = True
                out[self.names[i]] = {
                    "object": scene.objects[int(self.object_index[i])].name,
                    "faces": face_ranges(selected),
                }
        return out

    def split_counts(self, scene: Scene) -> dict[str, int]:
        """Clusters per split object, by the object's name."""
        out: dict[str, int] = {}
        for i, piece in enumerate(self.faces):
            if piece is not None:
                name = scene.objects[int(self.object_index[i])].name
                out[name] = out.get(name, 0) + 1
        return dict(sorted(out.items()))

    def scene_of(self, scene: Scene, indices) -> Scene:
        """The scene of the elements ``indices``: whole objects as they are, clusters as objects of
        their triangles (vertices compacted), named as the elements are."""
        objects = []
        for i in sorted(int(j) for j in indices):
            obj = scene.objects[int(self.object_index[i])]
            piece = self.faces[i]
            if piece is None:
                objects.append(obj)
                continue
            objects.append(obj.with_faces(piece, self.names[i]))
        return Scene.from_objects(objects, scene.source, scene.warnings)


@dataclass(frozen=True, slots=True, eq=False)
class Hierarchy:
    """A binary BVH over elements, nodes in preorder (see the module docstring)."""

    order: np.ndarray  # (e,) element indices in hierarchy order
    position: np.ndarray  # (e,) inverse of order: element -> position
    lo: np.ndarray  # (n, 3)
    hi: np.ndarray  # (n, 3)
    start: np.ndarray  # (n,) into order
    end: np.ndarray  # (n,)
    size: np.ndarray  # (n,) nodes in the subtree, itself included
    parent: np.ndarray  # (n,) -1 at the root
    depth: np.ndarray  # (n,)
    leaf: np.ndarray  # (n,) bool
    triangles: np.ndarray  # (n,) int64
    draw_calls: np.ndarray  # (n,) float64

    @property
    def count(self) -> int:
        return int(self.lo.shape[0])

    @property
    def diagonal(self) -> np.ndarray:
        """(n,) length of each node's bounding-box diagonal: the node's size."""
        return np.linalg.norm(self.hi - self.lo, axis=1)

    def is_ancestor_or_self(self, a: int, b: int) -> bool:
        """Whether node ``a`` is ``b`` or one of its ancestors."""
        return a <= b < a + int(self.size[a])

    def elements_of(self, node: int) -> np.ndarray:
        return self.order[self.start[node] : self.end[node]]

    @classmethod
    def build(cls, elements: Elements, leaf_size: int = DEFAULT_LEAF_SIZE) -> Hierarchy:
        """Top-down median splits of element centroids along the longest axis (deterministic);
        elements about as large as their node are split off first into a subtree of their own."""
        if leaf_size < 1:
            raise PlacementError(f"leaf_size must be >= 1, got {leaf_size!r}")
        b = elements.bounds
        centroids = 0.5 * (b[:, 0] + b[:, 1])
        diagonal = np.linalg.norm(b[:, 1] - b[:, 0], axis=1)
        order = np.empty(elements.count, dtype=np.int64)
        nodes: list[list] = []  # [start, end, parent, depth]
        filled = 0

        def visit(index: np.ndarray, parent: int, depth: int) -> int:
            nonlocal filled
            me = len(nodes)
            nodes.append([0, 0, parent, depth, 0])
            c = centroids[index]
            extent = c.max(axis=0) - c.min(axis=0)
            # Elements as large as the node itself (a ground plane, a sky dome) go to a subtree of
            # their own, so they do not stretch the bounds of the compact clusters around them
            # (the thesis kept large triangles in interior nodes, §5.8.3).
            big = diagonal[index] > OVERSIZED * np.linalg.norm(b[index, 1].max(axis=0) - b[index, 0].min(axis=0))
            if index.size > leaf_size and 0 < int(big.sum()) < index.size:
                first = filled
                visit(index[big], me, depth + 1)
                visit(index[~big], me, depth + 1)
                nodes[me][0], nodes[me][1] = first, filled
                nodes[me][4] = len(nodes) - me
                return me
            if index.size <= leaf_size or not np.any(extent > 0.0):
                nodes[me][0], nodes[me][1] = filled, filled + index.size
                order[filled : filled + index.size] = index
                filled += index.size
            else:
                axis = int(np.argmax(extent))
                ordered = index[np.argsort(c[:, axis], kind="stable")]
                half = ordered.size // 2
                first = filled
                visit(ordered[:half], me, depth + 1)
                visit(ordered[half:], me, depth + 1)
                nodes[me][0], nodes[me][1] = first, filled
            nodes[me][4] = len(nodes) - me
            return me

        # An explicit recursion: the depth is about log2(elements / leaf_size), well within limits.
        visit(np.arange(elements.count, dtype=np.int64), -1, 0)
        table = np.asarray(nodes, dtype=np.int64)
        start, end, parent, depth, size = table.T
        lo = np.array([b[order[s:e], 0].min(axis=0) for s, e in zip(start, end)])
        hi = np.array([b[order[s:e], 1].max(axis=0) for s, e in zip(start, end)])
        tri_cum = np.concatenate([[0], np.cumsum(elements.triangles[order])])
        call_cum = np.concatenate([[0.0], np.cumsum(elements.draw_calls[order])])
        position = np.empty_like(order)
        position[order] = np.arange(order.size)
        return cls(
            order,
            position,
            lo,
            hi,
            start,
            end,
            size,
            parent,
            depth,
            size == 1,
            tri_cum[end] - tri_cum[start],
            call_cum[end] - call_cum[start],
        )
