"""The near field of an environment-map view cell: which triangles the runtime draws as geometry.

Seed 002 §3 step 3(d) and §4.1: everything inside the innermost border cube (the near-field cube,
centred on the view cell's reference viewpoint) is drawn as polygons; everything outside it is in
the impostor layers.  The list is stored per object as sorted half-open face-index ranges
``[start, end)``: a building wholly inside is one range, a long road crossing the border a few.

When only some cube faces carry layers (seed 002 §6 recorded the four horizontal ones), the rest
of the world is drawn as geometry too, so that no view from the cell has a hole: the near field
then also holds what lies beyond the cube in the face pyramids of the unrecorded faces (``open``),
the regions where the largest coordinate relative to the centre is that face's.

A triangle is listed when its bounding box meets the closed cube or an open pyramid
(conservative: a few listed triangles may miss both).  The runtime clips what it draws to the cube exactly
(:class:`farfield.core.render.raster.MeshRenderer`'s ``clip``: the GL's clip planes for a closed cube, the
fragment shader's discard where faces are open), and the
layers are clipped to the same cube's faces by the slab recording, so a triangle crossing the
border is drawn inside by the runtime and outside by the layers: nothing twice, nothing lost.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from farfield.core.cube_faces import FACES
from farfield.core.scene import Scene, SceneObject


def face_ranges(selected: np.ndarray) -> list[list[int]]:
    """Half-open ranges ``[start, end)`` of the True runs of an (f,) bool array.

    >>> face_ranges(np.array([1, 1, 0, 1, 0, 0, 1, 1], bool))
    [[0, 2], [3, 4], [6, 8]]
    """
    padded = np.concatenate([[False], np.asarray(selected, dtype=bool), [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return edges.reshape(-1, 2).tolist()


def _boxes_meet_pyramid(lo: np.ndarray, hi: np.ndarray, face: str) -> np.ndarray:
    """(n,) bool: which boxes (n, 3) (relative to the centre) meet the closed pyramid of ``face``,
    ``s p_i >= |p_j|`` for the other two axes j.  Exact for boxes: take the box's largest ``s p_i``
    and, independently, its smallest ``|p_j|``."""
    axis, sign = FACES[face]
    reach = hi[:, axis] if sign > 0 else -lo[:, axis]
    ok = np.ones(lo.shape[0], dtype=bool)
    for j in range(3):
        if j != axis:
            nearest = np.where(
                (lo[:, j] <= 0.0) & (hi[:, j] >= 0.0), 0.0, np.minimum(np.abs(lo[:, j]), np.abs(hi[:, j]))
            )
            ok &= reach >= nearest
    return ok


def _drawn_faces(obj: SceneObject, centre: np.ndarray, half: float, open_faces: tuple[str, ...]) -> np.ndarray:
    """(f,) bool: faces whose bounding box meets the closed cube ``centre ± half`` or an open pyramid."""
    corners = obj.vertices[obj.faces.T] - centre  # (3, f, 3), float64 relative to the centre
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    drawn = np.all((hi >= -half) & (lo <= half), axis=1)
    for face in open_faces:
        drawn |= _boxes_meet_pyramid(lo, hi, face)
    return drawn


@dataclass(frozen=True, slots=True)
class NearField:
    """The near-field cube of one view cell and the triangles inside it, per object."""

    centre: np.ndarray  # (3,) float64 world, the reference viewpoint
    half_size: float  # the near-field cube's half side (seed 002's innermost border distance)
    ranges: dict[str, list[list[int]]]  # object name -> [[start, end), ...] face-index ranges
    open_faces: tuple[str, ...] = ()  # cube faces without layers: drawn as geometry beyond the cube too

    @property
    def clip(self) -> tuple:
        """The renderer's clip for these triangles (:class:`farfield.core.render.raster.MeshRenderer`)."""
        return (self.centre, self.half_size, self.open_faces)

    @property
    def triangle_count(self) -> int:
        return int(sum(end - start for spans in self.ranges.values() for start, end in spans))

    def to_dict(self) -> dict:
        return {
            "centre": np.asarray(self.centre, dtype=np.float64).tolist(),
            "half_size": float(self.half_size),
            "triangles": self.triangle_count,
            "open_faces": list(self.open_faces),
            "objects": [{"name": name, "faces": spans} for name, spans in self.ranges.items()],
        }

    @classmethod
    def from_dict(cls, data: dict) -> NearField:
        ranges = {entry["name"]: [list(map(int, r)) for r in entry["faces"]] for entry in data["objects"]}
        return cls(
            np.asarray(data["centre"], dtype=np.float64),
            float(data["half_size"]),
            ranges,
            tuple(data.get("open_faces", ())),
        )

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


def near_field(scene: Scene, centre, half_size: float, open_faces=()) -> NearField:
    """The triangles of ``scene`` the runtime draws: inside the cube ``centre ± half_size``, and
    beyond it in the pyramids of ``open_faces`` (cube faces without layers, e.g. ``("+y", "-y")``)."""
    centre = np.asarray(centre, dtype=np.float64)
    open_faces = tuple(f for f in FACES if f in set(open_faces))
    ranges = {}
    for obj in scene.objects:
        lo, hi = obj.bounds[0] - centre, obj.bounds[1] - centre
        meets = bool(np.all((hi >= -half_size) & (lo <= half_size)))
        meets = meets or any(bool(_boxes_meet_pyramid(lo[None], hi[None], f)[0]) for f in open_faces)
        spans = face_ranges(_drawn_faces(obj, centre, float(half_size), open_faces)) if meets else []
        if spans:
            ranges[obj.name] = spans
    return NearField(centre, float(half_size), ranges, open_faces)
