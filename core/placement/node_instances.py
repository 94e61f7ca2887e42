"""Which hierarchy nodes hold exactly one instance of a prototype (issue 56).

A node whose elements are all the elements of the objects of one instance (``Scene.instances()``:
the objects of one prototype with one instance matrix), and nothing else, is that instance: an
impostor of it is the prototype's impostor moved by the instance matrix, where the technique
allows it (octahedral: a similarity, rotation and uniform scale;
:mod:`farfield.core.techniques.octahedral.instancing`).  Every instance of one prototype then
shares one baked atlas: the planner charges it once (:mod:`farfield.core.placement.greedy`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from farfield.core.placement.hierarchy import Elements, Hierarchy
from farfield.core.scene import Scene
from farfield.core.techniques.octahedral.instancing import SIMILARITY_TOL, similarity


@dataclass(frozen=True, slots=True)
class NodeInstance:
    """One node that is one instance: its prototype key, the prototype's local bounds ((2, 3): the
    union of its primitives' bounds in its own space), the instance matrix (local -> world), and
    the matrix's uniform scale and rotation."""

    prototype: str
    local_bounds: np.ndarray
    matrix: np.ndarray
    scale: float
    rotation: np.ndarray

    def keeps_up(self) -> bool:
        """Whether the instance leaves the prototype's +z where it was (a hemisphere bake's need)."""
        return bool(np.allclose(self.rotation[:, 2], (0.0, 0.0, 1.0), atol=SIMILARITY_TOL))

    def world_point(self, local: np.ndarray) -> np.ndarray:
        return self.matrix[:3, :3] @ np.asarray(local, dtype=np.float64) + self.matrix[:3, 3]


def node_instances(scene: Scene, elements: Elements, hierarchy: Hierarchy) -> dict[int, NodeInstance]:
    """Node -> :class:`NodeInstance` for every node that is exactly one instance of a prototype
    whose matrix is a similarity (module docstring); other nodes are left out ({} for a scene
    without instancing)."""
    instances = scene.instances()
    if not instances:
        return {}
    index = {name: i for i, name in enumerate(scene.names)}
    instance_of_object = np.full(scene.object_count, -1, dtype=np.int64)
    found: list[tuple[str, tuple[int, ...]]] = []
    for key, groups in instances.items():
        for names in groups:
            instance_of_object[[index[n] for n in names]] = len(found)
            found.append((key, tuple(index[n] for n in names)))
    # Elements of each instance (an object split into clusters gives several).
    owner = instance_of_object[elements.object_index]
    per_instance = np.bincount(owner[owner >= 0], minlength=len(found))
    out: dict[int, NodeInstance] = {}
    for node in range(hierarchy.count):
        held = owner[hierarchy.elements_of(node)]
        k = int(held[0]) if held.size else -1
        if k < 0 or np.any(held != k) or held.size != per_instance[k]:
            continue
        key, objs = found[k]
        first = scene.objects[objs[0]]
        sim = similarity(first.instance_matrix)
        if sim is None:
            continue
        local = np.stack([scene.objects[o].local.bounds for o in objs])
        bounds = np.stack([local[:, 0].min(axis=0), local[:, 1].max(axis=0)])
        out[node] = NodeInstance(key, bounds, np.asarray(first.instance_matrix, dtype=np.float64), sim[0], sim[1])
    return out
