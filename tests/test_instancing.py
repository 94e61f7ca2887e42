"""Instancing kept from the file to the output (issue 56, item 1): the loader's prototypes and
instances, one bake per prototype, the instanced GLB card."""

from __future__ import annotations

import numpy as np
import pytest

from farfield.core.exchange import load_scene
from farfield.core.scene import Scene, SceneObject, instance_of, prototype_key
from gltf_files import instanced_scene


def test_the_loader_keeps_prototypes_and_their_instances(tmp_path):
    scene = load_scene(instanced_scene(tmp_path / "inst.glb", count=5))
    groups = scene.instances()
    assert sorted(len(v) for v in groups.values()) == [2, 5]  # the quad's two nodes, the box's five instances
    box = next(key for key, found in groups.items() if len(found) == 5)
    assert groups[box] == [(f"box@{i}",) for i in range(5)]
    (local,) = scene.prototype_objects(box)
    by_name = {obj.name: obj for obj in scene.objects}
    for i in range(5):
        obj = by_name[f"box@{i}"]
        assert obj.local is local and obj.prototype == box
        moved = local.vertices @ obj.instance_matrix[:3, :3].T + obj.instance_matrix[:3, 3]
        np.testing.assert_allclose(obj.vertices, moved, atol=1e-12)
        assert obj.texture is local.texture  # shared by reference, never copied per instance
        assert obj.faces is local.faces
    assert by_name["box@3"].instance_matrix[0, 3] == pytest.approx(12.0)


def test_a_scene_without_instancing_is_unchanged():
    tri = SceneObject("t", np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]]), np.array([[0, 1, 2]]))
    plain = Scene((tri,), "plain")
    assert plain.instances() == {} and tri.prototype is None
    key = prototype_key([tri])
    same = Scene((instance_of(tri, "t", np.eye(4), key),), "instanced")
    assert same.content_hash == plain.content_hash  # the hash is of the world content alone


def test_a_stage_that_keeps_some_faces_drops_the_instance():
    quad = SceneObject("q", np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.0]]), np.array([[0, 1, 2], [0, 2, 3]]))
    inst = instance_of(quad, "q@0", np.eye(4), prototype_key([quad]))
    assert inst.with_faces([0]).prototype is None
