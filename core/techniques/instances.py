"""A scene's instances baked once per prototype: the impostor of an instance (a part that is one
instance of a mesh the scene draws several times, :meth:`farfield.core.scene.Scene.instances`) is
its prototype's, baked once in the prototype's local space and moved by the instance's matrix,
for a technique that says how (:class:`~farfield.core.techniques.base.Instancing`: today
``octahedral``); docs/formats.md, "Scene files: instancing".
"""

from __future__ import annotations

import json
from dataclasses import asdict

import numpy as np

from farfield.core.impostor.impostor import Impostor
from farfield.core.scene import Scene
from farfield.core.stage_clock import Progress
from farfield.core.techniques.base import TechniqueDefinition
from farfield.core.viewcells import ViewCell


def instance_index(scene: Scene) -> dict[frozenset, tuple[str, np.ndarray, tuple[str, ...]]]:
    """Every instance of ``scene`` by the set of its object names: (prototype key, (4, 4) instance
    matrix, the instance's object names); built once for a scene whose many instances are looked up
    (:class:`InstanceBakes`), one pass over the objects."""
    by_name = {obj.name: obj for obj in scene.objects}
    return {
        frozenset(instance): (key, by_name[instance[0]].instance_matrix, instance)
        for key, instances in scene.instances().items()
        for instance in instances
    }


def instance_part(
    scene: Scene, names: list[str] | None, index: dict | None = None
) -> tuple[str, np.ndarray, tuple[str, ...]] | None:
    """(prototype key, (4, 4) instance matrix, the instance's object names) when the part of
    ``names`` (None: every object) is exactly one instance of a prototype; else None.  ``index``:
    the scene's :func:`instance_index`, where the caller keeps it."""
    index = instance_index(scene) if index is None else index
    return index.get(frozenset(scene.names if names is None else names))


def prototype_scene(scene: Scene, key: str) -> Scene:
    """The prototype ``key`` of ``scene`` as a scene of its own, in its local space."""
    return Scene(scene.prototype_objects(key), f"{scene.source} (prototype {key[:12]})")


class InstanceBakes:
    """Impostors of instances, one bake per prototype, options and prototype-local view cell.

    :attr:`bakes` counts the bakes it ran; an instance whose cell is not its prototype's
    (:attr:`Instancing.local_cell <farfield.core.techniques.base.Instancing.local_cell>` None), or a
    part that is no instance, is baked as an object of its own and counted too.
    """

    def __init__(self, technique: TechniqueDefinition) -> None:
        self.technique = technique
        self.bakes = 0
        self._prototypes: dict[tuple, Impostor] = {}
        self._index: tuple[Scene, dict] | None = None  # the last scene's instance_index

    def bake(
        self, scene: Scene, cell: ViewCell, options, names: list[str] | None = None, progress: Progress | None = None
    ) -> Impostor:
        """The impostor of the part ``names`` of ``scene`` for ``cell``: its prototype's moved, when
        it is an instance the technique can share, else its own bake."""
        technique = self.technique
        if technique.instancing is not None and (self._index is None or self._index[0] is not scene):
            self._index = (scene, instance_index(scene))
        found = None if technique.instancing is None else instance_part(scene, names, self._index[1])
        local = None if found is None else technique.instancing.local_cell(cell, found[1], options)
        if local is None:
            self.bakes += 1
            return technique.bake(scene, cell, options, names, progress)
        key, matrix, objects = found
        index = (
            key,
            json.dumps(local.to_dict(), sort_keys=True),
            json.dumps(asdict(options), sort_keys=True, default=str),
        )
        if index not in self._prototypes:
            self.bakes += 1
            baked = technique.bake(prototype_scene(scene, key), local, options, None, progress)
            baked.parameters["prototype"] = key
            self._prototypes[index] = baked
        return technique.instancing.moved(self._prototypes[index], matrix, list(objects), scene.content_hash)


def bake_prototypes(
    scene: Scene, technique: TechniqueDefinition, cell: ViewCell, options, progress: Progress | None = None
) -> list[Impostor]:
    """One impostor per prototype of ``scene`` (in scene order), baked in its local space for
    ``cell`` (a view cell in that space), each recording its instances once: ``parameters
    ["instances"]`` = ``{"objects": [[names of instance 0], ...], "matrices": [[16 numbers,
    row-major, local -> world], ...]}``, what :func:`farfield.core.impostor.glb.impostor_glb` writes
    as one card drawn by ``EXT_mesh_gpu_instancing``.  Objects that are not instanced are left out."""
    by_name = {obj.name: obj for obj in scene.objects}
    out = []
    for key, instances in scene.instances().items():
        impostor = technique.bake(prototype_scene(scene, key), cell, options, None, progress)
        impostor.parameters["prototype"] = key
        impostor.parameters["instances"] = {
            "objects": [list(names) for names in instances],
            "matrices": [by_name[names[0]].instance_matrix.reshape(-1).tolist() for names in instances],
        }
        out.append(impostor)
    return out
