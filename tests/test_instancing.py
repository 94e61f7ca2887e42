"""Instancing kept from the file to the output (issue 56, item 1): the loader's prototypes and
instances, one bake per prototype, the instanced GLB card."""

from __future__ import annotations

import numpy as np
import pytest
from gltf_files import instanced_scene

from farfield.core.exchange import load_scene
from farfield.core.scene import Scene, SceneObject, instance_of, prototype_key


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
        assert obj.faces is local.faces and obj.uv is local.uv
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


def _instances(count: int) -> Scene:
    """``count`` instances of one flat slab on a grid, turned about z and uniformly scaled."""
    import trimesh
    from scipy.spatial.transform import Rotation

    mesh = trimesh.creation.box(extents=(1.2, 0.15, 0.7))
    local = SceneObject("rock.local", np.asarray(mesh.vertices), np.asarray(mesh.faces),
                        base_color=(0.6, 0.5, 0.4, 1.0))  # fmt: skip
    key = prototype_key([local])
    objects = []
    for i in range(count):
        m = np.eye(4)
        m[:3, :3] = Rotation.from_euler("z", 0.37 * i).as_matrix() * (1.0 + 0.25 * (i % 4))
        m[:3, 3] = (4.0 * (i % 40), 4.0 * (i // 40), 0.0)
        objects.append(instance_of(local, f"rock@{i}", m, key))
    return Scene(tuple(objects), "rocks")


def test_a_thousand_instances_bake_one_octahedral_impostor():
    from dataclasses import replace

    from farfield.core.techniques import get_technique
    from farfield.core.techniques.instances import InstanceBakes
    from farfield.core.techniques.octahedral.instancing import local_cell
    from farfield.core.viewcells import SphereOutsideCell

    scene = _instances(1000)
    octahedral = get_technique("octahedral")
    calls = []
    counted = replace(octahedral, bake=lambda *args: calls.append(args[1]) or octahedral.bake(*args))
    bakes = InstanceBakes(counted)
    options = octahedral.options({"grid": 5, "frame_resolution": 8, "padding": 1})
    impostors = []
    for obj in scene.objects:
        s = np.linalg.norm(obj.instance_matrix[:3, 0])
        cell = SphereOutsideCell(obj.instance_matrix[:3, 3], 2.0 * s)  # beyond the instance's sphere
        assert local_cell(cell, obj.instance_matrix) is not None
        impostors.append(bakes.bake(scene, cell, options, [obj.name]))
    assert bakes.bakes == 1 and len(calls) == 1  # one bake for the thousand instances
    for obj, impostor in zip(scene.objects[:5], impostors[:5]):
        p = impostor.payload
        np.testing.assert_allclose(p.centre, obj.instance_matrix[:3, 3], atol=1e-9)  # the sphere moved with it
        assert impostor.parameters["objects"] == [obj.name] and impostor.pages[0] is impostors[0].pages[0]
        # every instance's vertices lie in its moved sphere
        assert np.linalg.norm(obj.vertices - p.centre, axis=1).max() <= p.radius * (1 + 1e-9)


def test_a_moved_impostor_draws_its_instance_as_the_instance_s_own_bake_does():
    """The prototype's impostor moved by a turned, scaled instance's matrix covers the pixels the
    instance's geometry covers, as closely as the instance's own bake does (the runtime maps the
    view into the turned grid)."""
    import math

    from farfield.core.quality.evaluation import depth_bounds
    from farfield.core.render.raster import Camera, MeshRenderer
    from farfield.core.techniques import get_technique
    from farfield.core.techniques.instances import InstanceBakes
    from farfield.core.viewcells import SphereOutsideCell

    scene = _instances(8)
    octahedral = get_technique("octahedral")
    options = octahedral.options({"grid": 9, "frame_resolution": 48, "channels": "albedo"})
    obj = scene.objects[5]  # turned 1.85 rad about z, scaled 1.25
    m = obj.instance_matrix
    cell = SphereOutsideCell(m[:3, 3], 2.5 * np.linalg.norm(m[:3, 0]))
    moved = InstanceBakes(octahedral).bake(scene, cell, options, [obj.name])
    assert moved.parameters["instance_matrix"] == m.reshape(-1).tolist()
    own = octahedral.bake(scene.subset([obj.name]), cell, options, None, None)
    misses = {}
    for name, impostor in (("moved", moved), ("own", own)):
        centre, radius = impostor.payload.centre, impostor.payload.radius
        eye = centre + 5.0 * radius * np.array([0.62, -0.55, 0.56]) / np.linalg.norm([0.62, -0.55, 0.56])
        near, far = depth_bounds(eye, (centre - eye) / np.linalg.norm(centre - eye), impostor.payload.world_points())
        camera = Camera.look_at(eye, m[:3, 3], math.radians(30.0), 96, near, far)
        with MeshRenderer([obj]) as geometry, impostor.payload.renderer(impostor) as stand_in:
            truth, drawn = geometry.render(camera)[..., 3] > 0, stand_in.render(camera)[..., 3] > 0
        misses[name] = int((truth != drawn).sum()) / int(truth.sum())
    assert misses["moved"] < 1.5 * misses["own"] + 0.01, misses


def test_the_glb_draws_one_card_for_every_instance(tmp_path, gltf_validator, threejs):
    """A prototype's bundle records its instances once; its GLB is one card mesh drawn by
    ``EXT_mesh_gpu_instancing`` (valid: 0 errors, 0 warnings) and three.js draws it where the
    instances' own moved impostors' GLBs draw."""
    import math

    from farfield.core.impostor.bundle import read_bundle, write_bundle
    from farfield.core.impostor.glb import impostor_glb
    from farfield.core.render.raster import Camera
    from farfield.core.techniques import get_technique
    from farfield.core.techniques.instances import bake_prototypes
    from farfield.core.techniques.octahedral.instancing import moved_impostor
    from farfield.core.viewcells import SphereOutsideCell

    scene = _instances(3)
    octahedral = get_technique("octahedral")
    options = octahedral.options({"grid": 5, "frame_resolution": 32, "padding": 1})
    (prototype,) = bake_prototypes(scene, octahedral, SphereOutsideCell([0.0, 0.0, 0.0], 2.0), options)
    write_bundle(prototype, tmp_path / "bundle")
    back = read_bundle(tmp_path / "bundle")
    assert len(back.parameters["instances"]["matrices"]) == 3  # the instance list, once in the manifest
    glb = tmp_path / "instanced.glb"
    glb.write_bytes(impostor_glb(back))
    (report,) = gltf_validator.validate([glb])
    assert report.get("errors") == 0 and report.get("warnings") == 0, report
    eyes = []
    for k, matrix in enumerate(back.parameters["instances"]["matrices"]):
        one = tmp_path / f"instance{k}.glb"
        one.write_bytes(impostor_glb(moved_impostor(back, np.reshape(matrix, (4, 4)))))
        eyes.append(one)
    camera = Camera.look_at([8.0, -3.0, 12.0], [4.0, 0.0, 0.0], math.radians(40.0), 256, 1.0, 60.0)
    (together,) = threejs.render(glb, [camera], mipmaps=False)
    apart = [threejs.render(path, [camera], mipmaps=False)[0] for path in eyes]
    drawn, expected = together[..., 3] > 0, np.any([image[..., 3] > 0 for image in apart], axis=0)
    assert all((image[..., 3] > 0).sum() > 20 for image in apart)
    assert (drawn != expected).sum() <= 0.02 * expected.sum(), int((drawn != expected).sum())


def test_farfield_bake_instances_bakes_a_thousand_instances_once(tmp_path):
    """``farfield bake --instances`` of a glTF of 1,000 ``EXT_mesh_gpu_instancing`` instances of one
    mesh (and a quad mesh two nodes share): one bundle per prototype, each recording its instances."""
    import json

    from click.testing import CliRunner

    from farfield.cli.main import _register, cli
    from farfield.core.impostor.bundle import read_bundle

    _register()
    path = instanced_scene(tmp_path / "many.glb", count=1000, texture=False)
    run = CliRunner().invoke(cli, ["bake", str(path), "--technique", "octahedral", "--instances", "--viewcell",
                                   "outside:0,0,0,3", "--option", "grid=5", "--option", "frame_resolution=8",
                                   "--out", str(tmp_path / "out"), "--json"])  # fmt: skip
    assert run.exit_code == 0, run.output
    written = json.loads(run.output)["prototypes"]
    assert sorted(entry["instances"] for entry in written) == [2, 1000]  # two bakes: the box's and the quad's
    bundles = sorted((tmp_path / "out").iterdir())
    assert len(bundles) == 2
    box = next(read_bundle(b) for b in bundles if len(read_bundle(b).parameters["instances"]["objects"]) == 1000)
    assert box.parameters["instances"]["objects"][999] == ["box@999"]
    refused = CliRunner().invoke(cli, ["bake", str(path), "--technique", "layered", "--instances", "--objects", "box@0",
                                       "--viewcell", "box:-9,-9,5,9,9,6", "--out", str(tmp_path / "no")])  # fmt: skip
    assert refused.exit_code != 0 and "--objects does not apply" in refused.output


def test_placement_counts_every_instance_s_triangles_and_draws():
    from farfield.core.placement.hierarchy import Elements

    scene = _instances(50)
    elements = Elements.of(scene, cluster_triangles=10_000)
    assert elements.count == 50 and int(elements.triangles.sum()) == 50 * 12  # a box's 12 triangles, 50 times
    assert float(elements.draw_calls.sum()) == 50.0
