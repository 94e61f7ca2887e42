"""The pseudo-leaf cells of an octree over a scene (seed 004 §3.3.1, §5): the unit the primitive-budget
placement counts, culls and replaces with images.

The octree spans the scene's bounding cube; its nodes at ``depth`` (5 by default, "a maximum of
32,768 leaf cells per view", §5) are the *pseudo-leaf cells*.  The paper leaves open how triangles
that straddle cells are assigned.  Here each triangle goes to the cell that holds its centroid,
and the cell's bounds are those of the triangles it holds.  That is the octree cell grown to
contain them (the bounds a straddling triangle would add), then trimmed to what the cell holds.
Either way every triangle lies inside its cell's bounds, so a view that meets none of a cell's
bounds draws none of its triangles, and a count of the cells a frustum meets is conservative.
Empty cells are not kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from farfield.core.placement.hierarchy import PlacementError
from farfield.core.scene import Scene

DEFAULT_DEPTH = 5
MAX_DEPTH = 10  # 2^30 possible cells: the linear key stays within int64


@dataclass(frozen=True)
class OctreeCells:
    """Non-empty pseudo-leaf cells: their bounds, triangle counts and the triangles they hold.

    ``lo[i]``, ``hi[i]`` bound cell ``i``'s triangles (float64, world units); ``triangles[i]`` counts
    them; ``key[i]`` is its (x, y, z) index at ``depth`` in the cube ``cube_lo + [0, cube_size]^3``.
    ``face_cell[k]`` gives, for each face of the scene's object ``k``, the cell that holds it.
    """

    lo: np.ndarray  # (n, 3) float64
    hi: np.ndarray  # (n, 3) float64
    triangles: np.ndarray  # (n,) int64
    key: np.ndarray  # (n, 3) int64
    depth: int
    cube_lo: np.ndarray  # (3,) float64
    cube_size: float
    face_cell: tuple[np.ndarray, ...]  # per scene object: (f,) int64 cell of each face

    @property
    def count(self) -> int:
        return int(self.triangles.size)

    @property
    def total_triangles(self) -> int:
        return int(self.triangles.sum())

    def faces_of(self, cells: np.ndarray) -> list[tuple[int, np.ndarray]]:
        """(object index, face indices) of the scene's triangles held by ``cells`` (indices or a mask)."""
        chosen = np.zeros(self.count, dtype=bool)
        chosen[np.asarray(cells)] = True
        out = []
        for k, owner in enumerate(self.face_cell):
            faces = np.flatnonzero(chosen[owner])
            if faces.size:
                out.append((k, faces))
        return out

    def summary(self) -> dict:
        return {"depth": self.depth, "cells": self.count, "triangles": self.total_triangles,
                "largest_cell_triangles": int(self.triangles.max()), "cube_size": self.cube_size}  # fmt: skip


def octree_cells(scene: Scene, depth: int = DEFAULT_DEPTH) -> OctreeCells:
    """The scene's non-empty pseudo-leaf cells at ``depth`` (seed 004 §5), triangles assigned by centroid.

    Cost: one pass over the triangles and a sort of their cell keys.
    """
    if isinstance(depth, bool) or int(depth) != depth or not 0 <= depth <= MAX_DEPTH:
        raise PlacementError(f"octree depth must be an integer in 0..{MAX_DEPTH}, got {depth!r}")
    depth = int(depth)
    side = 1 << depth
    lo = np.asarray(scene.bounds[0], dtype=np.float64)
    size = float((scene.bounds[1] - scene.bounds[0]).max())
    keys, face_lo, face_hi, counts = [], [], [], []
    for obj in scene.objects:
        corners = obj.vertices[obj.faces]  # (f, 3, 3)
        index = np.floor((corners.mean(axis=1) - lo) / size * side).astype(np.int64)
        np.clip(index, 0, side - 1, out=index)
        keys.append((index[:, 0] * side + index[:, 1]) * side + index[:, 2])
        face_lo.append(corners.min(axis=1))
        face_hi.append(corners.max(axis=1))
        counts.append(obj.triangle_count)
    every_key = np.concatenate(keys)
    unique, inverse = np.unique(every_key, return_inverse=True)
    order = np.argsort(inverse, kind="stable")
    starts = np.searchsorted(inverse[order], np.arange(unique.size))
    cell_lo = np.minimum.reduceat(np.concatenate(face_lo)[order], starts, axis=0)
    cell_hi = np.maximum.reduceat(np.concatenate(face_hi)[order], starts, axis=0)
    triangles = np.bincount(inverse, minlength=unique.size).astype(np.int64)
    key = np.stack([unique // (side * side), (unique // side) % side, unique % side], axis=1)
    owners = tuple(part.astype(np.int64) for part in np.split(inverse, np.cumsum(counts)[:-1]))
    for a in (cell_lo, cell_hi, triangles, key, lo, *owners):
        a.flags.writeable = False
    return OctreeCells(cell_lo, cell_hi, triangles, key, depth, lo, size, owners)
