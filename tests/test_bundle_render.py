"""A baked bundle round trip: the GLB read back by trimesh renders like the impostor it came from."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import scenes
import trimesh

from farfield.core.impostor.bundle import read_bundle, write_bundle
from farfield.core.quality.evaluation import compare_images, impostor_objects
from farfield.core.render.raster import Camera, MeshRenderer, depth_bounds
from farfield.core.scene import SceneObject
from farfield.core.techniques.layered import BakeOptions, bake_layered
from farfield.core.viewcells import BoxCell, box_corners


def glb_objects(path) -> list[SceneObject]:
    """The GLB as drawable objects, world transforms applied by trimesh, textures and UVs kept."""
    loaded = trimesh.load(path, force="scene")
    objects = []
    for name in loaded.graph.nodes_geometry:
        transform, geometry_name = loaded.graph[name]
        mesh = loaded.geometry[geometry_name].copy()
        mesh.apply_transform(transform)
        material = mesh.visual.material
        image = np.asarray(material.baseColorTexture.convert("RGBA"))
        objects.append(
            SceneObject(
                name=f"{name}-{geometry_name}",
                vertices=np.asarray(mesh.vertices, dtype=np.float64),
                faces=np.asarray(mesh.faces, dtype=np.int64),
                uv=np.asarray(mesh.visual.uv, dtype=np.float64),  # trimesh already flips glTF's v
                texture=image,
                alpha_cutoff=0.5,
            )
        )
    return objects


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    scene = scenes.city(buildings=16, seed=3)
    b = scene.bounds
    size = float(np.max(b[1] - b[0]))
    centre = 0.5 * (b[0] + b[1])
    cell = BoxCell.from_center(centre - [1.5 * size, -3.0, 0.0], 0.1 * size)
    impostor = bake_layered(scene, cell, BakeOptions(resolution=192))
    directory = tmp_path_factory.mktemp("bundle") / "city"
    write_bundle(impostor, directory)
    return scene, cell, impostor, directory


def test_glb_renders_like_the_bundle(baked):
    scene, cell, impostor, directory = baked
    from_glb = glb_objects(directory / "impostor.glb")
    assert sum(o.faces.shape[0] for o in from_glb) == 2 * impostor.quad_count
    # World-space quads: every GLB vertex is one of the impostor's quad corners.
    glb_vertices = np.concatenate([o.vertices for o in from_glb])
    corners = impostor.payload.world_points()
    scale = float(np.max(np.abs(corners)))
    for v in glb_vertices[:: max(1, len(glb_vertices) // 200)]:
        assert np.min(np.linalg.norm(corners - v, axis=1)) < 1e-5 * scale
    target = 0.5 * (scene.bounds[0] + scene.bounds[1])
    extent = np.concatenate([box_corners(scene.bounds), corners])
    with MeshRenderer(impostor_objects(read_bundle(directory))) as bundle, MeshRenderer(from_glb) as glb:
        for position in np.concatenate([cell.corners()[:4], cell.sample_random(4, seed=1)]):
            forward = (target - position) / np.linalg.norm(target - position)
            camera = Camera.look_at(position, target, np.radians(45), 192, *depth_bounds(position, forward, extent))
            stats = compare_images(bundle.render(camera), glb.render(camera))
            assert stats["impostor_pixels"] > 100
            assert stats["hole_pixels"] == 0 and stats["bloat_beyond_1px"] == 0
            assert stats["colour_error_p99"] <= 2


def test_read_bundle_equals_the_baked_impostor(baked):
    _, _, impostor, directory = baked
    back = read_bundle(directory)
    assert back.payload.kind == impostor.payload.kind == "quads"
    for name, array in impostor.payload.arrays().items():
        np.testing.assert_array_equal(back.payload.arrays()[name], array)
    assert all(np.array_equal(a, b) for a, b in zip(back.pages, impostor.pages))
    assert back.stats["quads"] == impostor.quad_count


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "farfield.cli.main", *args], capture_output=True, text=True, timeout=300
    )


@pytest.mark.slow
def test_cli_bake_then_evaluate_on_a_shared_scene(tmp_path):
    path = scenes.SHARED_SCENES / "duck" / "duck.obj"
    if not path.exists():
        pytest.skip("../shared/scenes is not beside the checkout")
    out = tmp_path / "duck"
    baked = run_cli(
        "bake", str(path), "--viewcell", "box-center:-8,0.9,0,1", "--resolution", "192", "--out", str(out), "--json"
    )
    assert baked.returncode == 0, baked.stderr
    stats = json.loads(baked.stdout)["stats"]
    assert stats["quads"] > 0 and (out / "manifest.json").exists() and (out / "impostor.glb").exists()
    evaluated = run_cli("evaluate", str(out), str(path), "--random", "4", "--outside", "0", "--json")
    assert evaluated.returncode == 0, evaluated.stderr
    totals = json.loads(evaluated.stdout)["totals"]
    assert totals["viewpoints"] == 13 and totals["hole_pixels"] == 0
    text = run_cli("evaluate", str(out), str(path), "--random", "2")
    assert text.returncode == 0 and "hole pixels" in text.stdout


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["bake", "missing.obj", "--viewcell", "box-center:0,0,0,1", "--out", "x"], "missing.obj"),
        (["bake", "__DUCK__", "--viewcell", "box-center:0,0,0,1", "--out", "x"], "touches or overlaps"),
        (["bake", "__DUCK__", "--viewcell", "box-center:-8,0.9,0,1", "--out", "x", "--grid-cell", "0"], "cell"),
        (["evaluate", "no-such-bundle", "__DUCK__"], "manifest"),
    ],
)
@pytest.mark.slow
def test_cli_errors_are_one_line(args, needle, tmp_path):
    path = scenes.SHARED_SCENES / "duck" / "duck.obj"
    if not path.exists():
        pytest.skip("../shared/scenes is not beside the checkout")
    args = [str(path) if a == "__DUCK__" else (str(tmp_path / a) if a in ("x", "no-such-bundle") else a) for a in args]
    result = run_cli(*args)
    assert result.returncode != 0
    lines = result.stderr.strip().splitlines()
    assert "Traceback" not in result.stderr and len(lines) == 1 and needle in lines[0], result.stderr
    assert not (tmp_path / "x").exists()
