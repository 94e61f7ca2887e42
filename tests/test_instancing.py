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


def test_instances_of_moves_every_instance_as_a_validated_object_of_its_own_would_be():
    """All instances at once (the loader's and the forest's path) give what building each instance
    as an object of its own (every field validated) gives: vertices, unit normals moved by the
    inverse transpose, tangents, faces reversed by a mirror; what does not move shared."""
    from farfield.core.exchange.normals import transform_normals, transform_tangents
    from farfield.core.scene import instances_of

    rng = np.random.default_rng(3)
    vertices = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.2]])
    local = SceneObject("q", vertices, np.array([[0, 1, 2], [0, 2, 3]]), uv=rng.random((4, 2)),
                        texture=rng.integers(0, 255, (2, 2, 4), dtype=np.uint8), normals=rng.normal(size=(4, 3)),
                        normal_texture=np.full((1, 1, 4), 128, np.uint8), normal_uv=rng.random((4, 2)),
                        tangents=np.column_stack([rng.normal(size=(4, 3)), np.ones(4)]))  # fmt: skip
    matrices = np.stack([np.eye(4)] * 3)
    matrices[1, :3, :3] = np.diag([2.0, 0.5, 1.0]) @ np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]])
    matrices[2, :3, :3], matrices[2, :3, 3] = np.diag([-1.0, 1.0, 3.0]), (5.0, -2.0, 1.0)  # a mirror
    moved = instances_of(local, ["a", "b", "c"], matrices, "key")
    for obj, m in zip(moved, matrices):
        linear = m[:3, :3]
        mirrored = np.linalg.det(linear) < 0.0
        reference = SceneObject(obj.name, local.vertices @ linear.T + m[:3, 3],
                                local.faces[:, ::-1] if mirrored else local.faces, uv=local.uv, texture=local.texture,
                                normals=transform_normals(local.normals, linear), normal_texture=local.normal_texture,
                                normal_uv=local.normal_uv, tangents=transform_tangents(local.tangents, linear))  # fmt: skip
        for field in ("vertices", "faces", "normals", "tangents", "bounds"):
            np.testing.assert_allclose(getattr(obj, field), getattr(reference, field), rtol=0, atol=1e-15)
        assert obj.texture is local.texture and obj.uv is local.uv and obj.local is local
        assert (obj.faces is local.faces) != mirrored and not obj.vertices.flags.writeable
        assert obj.prototype == "key" and np.array_equal(obj.instance_matrix, m)
    assert Scene(tuple(moved), "m").instances() == {"key": [("a",), ("b",), ("c",)]}


def test_instances_of_refuses_what_a_move_can_break():
    from farfield.core.errors import DegenerateGeometryError, SceneLoadError
    from farfield.core.scene import instances_of

    tri = SceneObject("t", np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]]), np.array([[0, 1, 2]]),
                      normals=np.tile([0.0, 0.0, 1.0], (3, 1)))  # fmt: skip
    far = np.eye(4)
    far[0, 3] = 1e300
    with pytest.raises(SceneLoadError, match="coordinate magnitude"):
        instances_of(tri, ["a", "b"], np.stack([np.eye(4), far]), "k")
    infinite = np.eye(4)
    infinite[1, 1] = np.inf
    with pytest.raises(SceneLoadError, match="'b': instance_matrix is not a finite affine"):
        instances_of(tri, ["a", "b"], np.stack([np.eye(4), infinite]), "k")
    overflow = np.eye(4)  # finite, but a vertex moved by it is not
    overflow[0, 0] = overflow[0, 3] = 1e308
    with pytest.raises(DegenerateGeometryError, match="'b': 1 of 3 vertices have non-finite"):
        instances_of(tri, ["a", "b"], np.stack([np.eye(4), overflow]), "k")
    flat = np.diag([0.0, 1.0, 1.0, 1.0])  # the +z normals become zero
    with pytest.raises(SceneLoadError, match="'b': 3 of 3 normals are zero"):
        instances_of(tri, ["a", "b"], np.stack([np.eye(4), flat]), "k")
    with pytest.raises(SceneLoadError, match="2 names"):
        instances_of(tri, ["a", "b"], np.eye(4)[None], "k")
    assert instances_of(tri, [], np.zeros((0, 4, 4)), "k") == []  # a prototype no tree of a forest drew


def test_a_gltf_instance_whose_move_zeroes_its_normals_is_repaired_with_a_warning(tmp_path):
    """The loader moves an instanced mesh's instances at once; an instance that flattens its normals
    to zero is built on its own instead, repaired as any file's zero normals are."""
    import warnings

    from gltf_files import GltfBuilder

    b = GltfBuilder()
    node = b.quad("leaf", [0, 0, 0], 1.0, b.material(), normals=np.tile([0.0, 0.0, 1.0], (4, 1)))
    spec = {"SCALE": b.accessor(np.array([[1.0, 1.0, 1.0], [0.0, 1.0, 1.0], [2.0, 2.0, 2.0]]), target=None)}
    b.doc["nodes"][node]["extensions"] = {"EXT_mesh_gpu_instancing": {"attributes": spec}}
    b.used.add("EXT_mesh_gpu_instancing")
    with warnings.catch_warnings(record=True):
        warnings.simplefilter("always")
        scene = load_scene(b.write(tmp_path / "flat.glb"))
    by_name = {obj.name: obj for obj in scene.objects}
    assert len(scene.instances()) == 1 and len(next(iter(scene.instances().values()))) == 3
    np.testing.assert_allclose(by_name["leaf@2"].normals, np.tile([0.0, 0.0, 1.0], (4, 1)), atol=1e-7)
    assert np.isfinite(by_name["leaf@1"].normals).all()
    assert any("'leaf@1': 4 of 4 shading normals were zero" in w for w in scene.warnings)
    assert not any("leaf@0" in w or "leaf@2" in w for w in scene.warnings)


def test_farfield_evaluate_checks_a_prototype_bundle_of_bake_instances(tmp_path):
    """A bundle of ``farfield bake --instances`` is its prototype's, in the prototype's own space:
    ``farfield evaluate`` looked for its objects (``box@0.local``) in the scene and refused it (exit
    2, "no object named"), so the promise of an instanced bake could not be checked at all."""
    import json

    from click.testing import CliRunner

    from farfield.cli.main import _register, cli

    _register()
    path = instanced_scene(tmp_path / "few.glb", count=3, texture=False)
    run = CliRunner().invoke(cli, ["bake", str(path), "--technique", "octahedral", "--instances", "--viewcell",
                                   "outside:0,0,0,600", "--option", "grid=5", "--option", "frame_resolution=8",
                                   "--out", str(tmp_path / "out")])  # fmt: skip
    assert run.exit_code == 0, run.output
    for bundle in sorted((tmp_path / "out").iterdir()):
        checked = CliRunner().invoke(cli, ["evaluate", str(bundle), str(path), "--random", "2", "--check", "--json"])
        assert checked.exit_code == 0, checked.output  # beyond the accuracy distance (506 here): the promise holds
        views = json.loads(checked.stdout)["viewpoints"]
        assert views and all(view["stats"]["hole_pixels"] == 0 for view in views)
    both = [str(b) for b in sorted((tmp_path / "out").iterdir())]  # two prototypes: one at a time
    refused = CliRunner().invoke(cli, ["evaluate", *both, str(path)])
    assert refused.exit_code == 2 and "one at a time" in refused.output, refused.output
