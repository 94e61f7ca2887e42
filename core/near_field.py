"""The near field of an environment-map view cell: which triangles the runtime draws as geometry.

Seed 002 §3 step 3(d) and §4.1: everything inside the innermost border cube (the near-field cube,
centred on the view cell's reference viewpoint) is drawn as polygons; everything outside it is in
the impostor layers.  The list is stored per object as sorted half-open face-index ranges
``[start, end)``: a building wholly inside is one range, a long road crossing the border a few.

A triangle is listed when its bounding box meets the closed cube (conservative: a few listed
triangles may miss the cube).  The runtime clips what it draws to the cube exactly (the mesh
shader discards fragments outside it, :class:`core.render.raster.MeshRenderer`'s ``clip``), and the
layers are clipped to the same cube's faces by the slab recording, so a triangle crossing the
border is drawn inside by the runtime and outside by the layers: nothing twice, nothing lost.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from core.scene import Scene, SceneObject


def face_ranges(selected: np.ndarray) -> list[list[int]]:
    """Half-open ranges ``[start, end)`` of the True runs of an (f,) bool array.

    >>> face_ranges(np.array([1, 1, 0, 1, 0, 0, 1, 1], bool))
    [[0, 2], [3, 4], [6, 8]]
    """
    padded = np.concatenate([[False], np.asarray(selected, dtype=bool), [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return edges.reshape(-1, 2).tolist()


def _faces_in_cube(obj: SceneObject, centre: np.ndarray, half: float) -> np.ndarray:
    """(f,) bool: faces whose bounding box meets the closed cube ``centre ± half`` (float64)."""
    lo_box, hi_box = centre - half, centre + half
    if np.any(obj.bounds[1] < lo_box) or np.any(obj.bounds[0] > hi_box):
        return np.zeros(obj.faces.shape[0], dtype=bool)
    corners = obj.vertices[obj.faces.T]  # (3, f, 3)
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    return np.all((hi >= lo_box) & (lo <= hi_box), axis=1)


@dataclass(frozen=True, slots=True)
class NearField:
    """The near-field cube of one view cell and the triangles inside it, per object."""

    centre: np.ndarray  # (3,) float64 world, the reference viewpoint
    half_size: float  # the near-field cube's half side (seed 002's innermost border distance)
    ranges: dict[str, list[list[int]]]  # object name -> [[start, end), ...] face-index ranges

    @property
    def triangle_count(self) -> int:
        return int(sum(end - start for spans in self.ranges.values() for start, end in spans))

    def to_dict(self) -> dict:
        return {
            "centre": np.asarray(self.centre, dtype=np.float64).tolist(),
            "half_size": float(self.half_size),
            "triangles": self.triangle_count,
            "objects": [{"name": name, "faces": spans} for name, spans in self.ranges.items()],
        }

    @classmethod
    def from_dict(cls, data: dict) -> "NearField":
        ranges = {entry["name"]: [list(map(int, r)) for r in entry["faces"]] for entry in data["objects"]}
        return cls(np.asarray(data["centre"], dtype=np.float64), float(data["half_size"]), ranges)

    def objects(self, scene: Scene) -> list[SceneObject]:
        """The listed triangles of ``scene`` as objects (the runtime's near-field geometry)."""
        by_name = {obj.name: obj for obj in scene.objects}
        out = []
        for name, spans in self.ranges.items():
            obj = by_name[name]
            if len(spans) == 1 and spans[0] == [0, obj.faces.shape[0]]:
                out.append(obj)
                continue
            index = np.concatenate([np.arange(start, end) for start, end in spans])
            out.append(replace(obj, faces=obj.faces[index]))
        return out


def near_field(scene: Scene, centre, half_size: float) -> NearField:
    """The triangles of ``scene`` the runtime draws inside the cube ``centre ± half_size``."""
    centre = np.asarray(centre, dtype=np.float64)
    ranges = {}
    for obj in scene.objects:
        spans = face_ranges(_faces_in_cube(obj, centre, float(half_size)))
        if spans:
            ranges[obj.name] = spans
    return NearField(centre, float(half_size), ranges)
