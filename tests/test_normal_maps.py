"""A source's own normal map (glTF ``normalTexture``): read with its tangents, drawn in the G-buffer
as three.js draws it, and recorded into a lit impostor."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import PIL.Image
import pytest

from farfield.core.exchange import load_scene
from farfield.core.quality.lit import evaluate_lit
from farfield.core.render.raster import Camera, MeshRenderer
from farfield.core.scene import Scene
from farfield.core.techniques.layered import BakeOptions, bake_layered
from farfield.core.viewcells import BoxCell

HELMET = Path(__file__).resolve().parents[2] / "shared" / "scenes" / "damaged_helmet" / "DamagedHelmet.glb"
needs_helmet = pytest.mark.skipif(not HELMET.is_file(), reason=f"needs the shared scene {HELMET}")


def angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.einsum("...i,...i->...", a, b), -1.0, 1.0)))


def unmapped(scene: Scene) -> Scene:
    """The scene with its normal maps left out (vertex normals only)."""
    plain = [replace(o, normal_texture=None, normal_uv=None, tangents=None) for o in scene.objects]
    return Scene(tuple(plain), scene.source)


def helmet_cameras(scene: Scene, resolution: int) -> list[Camera]:
    centre = 0.5 * (scene.bounds[0] + scene.bounds[1])
    size = float(np.max(scene.bounds[1] - scene.bounds[0]))
    eyes = [centre + size * np.array(d) for d in ([0.0, 0.3, 1.6], [1.2, 0.5, 1.0], [-1.3, -0.2, 0.9])]
    return [Camera.look_at(eye, centre, math.radians(40.0), resolution, 0.1 * size, 4.0 * size) for eye in eyes]


@needs_helmet
def test_the_helmets_normal_map_is_read_with_tangents_on_the_front_of_its_normals():
    (helmet,) = load_scene(HELMET).objects
    assert helmet.normal_texture is not None and helmet.normal_texture.shape == (2048, 2048, 4)
    assert helmet.tangents.shape == (len(helmet.vertices), 4)
    assert set(np.unique(helmet.tangents[:, 3])) <= {-1.0, 1.0}
    # Derived tangents are unit and orthogonal to the normals.
    assert np.allclose(np.linalg.norm(helmet.tangents[:, :3], axis=1), 1.0)
    assert np.abs(np.einsum("ij,ij->i", helmet.tangents[:, :3], helmet.normals)).max() < 1e-9


@needs_helmet
def test_three_js_draws_the_helmets_mapped_normals_as_farfields_g_buffer(threejs):
    """three.js (GLTFLoader; derivative tangents where the file has no TANGENT) draws the helmet's
    world normals after its normal map; farfield's G-buffer agrees on the pixels inside both
    silhouettes, far better than without the map."""
    from threejs import decode_normals

    scene = load_scene(HELMET)
    cameras = helmet_cameras(scene, 160)
    theirs = threejs.render(HELMET, cameras, output="normal")
    with (
        MeshRenderer(scene.objects, normals=True) as mapped,
        MeshRenderer(unmapped(scene).objects, normals=True) as plain,
    ):
        for camera, three in zip(cameras, theirs, strict=True):
            image, ours = mapped.render_normals(camera)
            _, flat = plain.render_normals(camera)
            both = (image[..., 3] > 0) & (three[..., 3] > 0)
            inner = both.copy()
            inner[1:-1, 1:-1] &= both[:-2, 1:-1] & both[2:, 1:-1] & both[1:-1, :-2] & both[1:-1, 2:]
            expected = decode_normals(three)[inner]
            error, without = angles(ours[inner], expected), angles(flat[inner], expected)
            print("helmet normals", np.median(error), np.percentile(error, 95), "without the map", np.median(without))
            assert inner.sum() > 3000
            assert np.median(error) <= 1.0 and np.percentile(error, 95) <= 3.0
            assert np.median(without) >= 1.5 * np.median(error)


@needs_helmet
def test_a_lit_layered_impostor_of_the_helmet_keeps_its_mapped_normals():
    scene = load_scene(HELMET)
    lo, hi = scene.bounds
    size = float(np.max(hi - lo))
    cell = BoxCell.from_center(0.5 * (lo + hi) + np.array([0.0, 0.0, 3.0 * size]), 0.2 * size)
    impostor = bake_layered(scene, cell, BakeOptions(resolution=192, channels="albedo+normal"))
    t = evaluate_lit(scene, impostor, random_count=0).totals
    print(t)
    assert t["normal_error_interior_median"] <= 5.0
    # The same impostor's normals against the geometry without its map: the map is what it kept.
    plain = evaluate_lit(unmapped(scene), impostor, random_count=0).totals
    assert plain["normal_error_interior_median"] > 1.5 * t["normal_error_interior_median"]


def bumps(size: int = 32) -> np.ndarray:
    """(size, size, 4) uint8 tangent-space normal map, glTF's image (top row first): X varies
    across, Y down the rows, so a wrong axis, sign or handedness shows."""
    u = (np.arange(size) + 0.5) / size
    x = 0.6 * np.sin(2.0 * np.pi * u)[None, :] * np.ones((size, 1))
    y = 0.5 * np.cos(2.0 * np.pi * u)[:, None] * np.ones((1, size)) + 0.2
    z = np.sqrt(np.clip(1.0 - x * x - y * y, 0.05, 1.0))
    n = np.stack([x, y, z], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    rgba = np.full((size, size, 4), 255, np.uint8)
    rgba[..., :3] = np.round((n * 0.5 + 0.5) * 255.0).astype(np.uint8)
    return rgba


def bumps_file(path: Path, quads) -> Path:
    """A GLB of quads facing +z with the one normal map of :func:`bumps`; ``quads``: (name, corner,
    uv, tangents or None, node spec)."""
    from gltf_files import GltfBuilder

    builder = GltfBuilder()
    texture = builder.texture(builder.image(bumps()))
    material = builder.material(texture=None, normalTexture={"index": texture})
    up = np.tile([0.0, 0.0, 1.0], (4, 1))
    for name, corner, uv, tangents, node in quads:
        builder.quad(name, corner, 1.0, material, uv=uv, normals=up, tangents=tangents, **node)
    return builder.write(path)


def three_and_farfield_normals(threejs, path: Path, camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(pixels both draw, farfield's normals there, three.js's) of the file at ``path``."""
    from threejs import decode_normals

    (three,) = threejs.render(path, [camera], output="normal", mipmaps=False)
    with MeshRenderer(load_scene(path).objects, normals=True) as renderer:
        image, ours = renderer.render_normals(camera)
    both = (image[..., 3] > 0) & (three[..., 3] > 0)
    return both, ours[both], decode_normals(three)[both]


# A primitive without TANGENT under a normal map draws a validator warning
# (MESH_PRIMITIVE_GENERATED_TANGENT_SPACE): that quad is written on purpose.
@pytest.mark.invalid_glb
def test_normal_maps_with_given_derived_flipped_rotated_and_mirrored_tangents_draw_as_three_js_draws_them(
    threejs, tmp_path, gltf_validator
):
    """Quads facing +z with one normal map: TANGENT given (w = 1), given with w = -1 over v-flipped
    uv, derived from the uv, and under a rotated node; three.js's world normals against farfield's
    G-buffer of the same file.  Under a mirroring node, farfield turns TANGENT's w (so that the
    bitangent stays up the image, as the tangents derived from the mirrored uv have it); three.js
    does not, and is checked against the derived tangents of the same mirrored quad instead."""
    from gltf_files import SQUARE_UV

    along = np.tile([1.0, 0.0, 0.0, 1.0], (4, 1))
    against = np.tile([1.0, 0.0, 0.0, -1.0], (4, 1))
    flipped_uv = np.column_stack([SQUARE_UV[:, 0], 1.0 - SQUARE_UV[:, 1]])
    spin = {"translation": [1.0, 0.6, 0.0], "rotation": [0.0, 0.0, math.sin(0.3), math.cos(0.3)]}
    path = bumps_file(tmp_path / "bumps.glb", [
        ("given", [-2.7, 0.1, 0.0], SQUARE_UV, along, {}),
        ("flipped", [-1.5, 0.1, 0.0], flipped_uv, against, {}),
        ("derived", [-0.3, 0.1, 0.0], SQUARE_UV, None, {}),
        ("rotated", [0.0, 0.0, 0.0], SQUARE_UV, along, spin),
    ])  # fmt: skip
    (report,) = gltf_validator.validate([path])
    assert {m["code"] for m in report["messages"] if m["severity"] <= 1} == {"MESH_PRIMITIVE_GENERATED_TANGENT_SPACE"}
    assert all(o.normal_texture is not None for o in load_scene(path).objects)
    camera = Camera.look_at(np.array([-0.6, 0.6, 5.0]), np.array([-0.6, 0.6, 0.0]), math.radians(60.0), 256, 1.0, 20.0)
    both, ours, theirs = three_and_farfield_normals(threejs, path, camera)
    error = angles(ours, theirs)
    print("bumps", both.sum(), np.median(error), np.percentile(error, 95))
    assert both.sum() > 5000
    assert np.median(error) <= 1.0 and np.percentile(error, 95) <= 2.0
    assert np.median(angles(ours, np.array([0.0, 0.0, 1.0]))) > 15.0  # the map bends them
    mirror = {"translation": [0.5, 0.1, 0.0], "scale": [-1.0, 1.0, 1.0]}
    derived = bumps_file(tmp_path / "mirrored-derived.glb", [("m", [0.0, 0.0, 0.0], SQUARE_UV, None, mirror)])
    given = bumps_file(tmp_path / "mirrored-given.glb", [("m", [0.0, 0.0, 0.0], SQUARE_UV, along, mirror)])
    near = Camera.look_at(np.array([0.0, 0.6, 2.0]), np.array([0.0, 0.6, 0.0]), math.radians(60.0), 128, 0.5, 10.0)
    both, ours_derived, theirs_derived = three_and_farfield_normals(threejs, derived, near)
    assert both.sum() > 3000 and np.median(angles(ours_derived, theirs_derived)) <= 1.0
    with MeshRenderer(load_scene(given).objects, normals=True) as renderer:
        image, ours_given = renderer.render_normals(near)
    assert np.median(angles(ours_given[both], ours_derived)) <= 1.0


@pytest.mark.parametrize(
    "case, map_kept, message",
    [
        ("tangent_nan", True, "TANGENT is not 4 finite VEC4 elements; tangents are derived"),
        ("tangent_vec3", True, "TANGENT is not 4 finite VEC4 elements; tangents are derived"),
        ("missing_image", False, "the normal texture is ignored"),
        ("uv_nan", False, "TEXCOORD_1 of its normal texture is not 4 finite pairs; the map is ignored"),
    ],
)
def test_a_normal_map_that_does_not_fit_is_left_out_or_its_tangents_derived_with_a_warning(case, map_kept, message):
    """A normal map only shades: what does not fit costs the map or its given tangents, never the file."""
    from gltf_files import SQUARE_UV, GltfBuilder

    from farfield.core.exchange import load_scene_bytes
    from farfield.core.scene import SceneWarning

    builder = GltfBuilder()
    texture = (
        builder.texture(builder.image(bumps(4))) if case != "missing_image" else builder._add("textures", {"source": 7})
    )
    info = {"index": texture} | ({"texCoord": 1} if case == "uv_nan" else {})
    material = builder.material(normalTexture=info)
    tangents = {"tangent_nan": np.array([[np.nan, 0, 0, 1]] + [[1.0, 0, 0, 1]] * 3),
                "tangent_vec3": np.tile([1.0, 0, 0], (4, 1))}.get(case, np.tile([1.0, 0, 0, 1], (4, 1)))  # fmt: skip
    uv1 = np.array([[np.nan, 0.0], [1, 0], [1, 1], [0, 1]]) if case == "uv_nan" else None
    builder.quad(
        "q", [0, 0, 0], 1.0, material, uv=SQUARE_UV, uv1=uv1, normals=np.tile([0.0, 0, 1], (4, 1)), tangents=tangents
    )
    with pytest.warns(SceneWarning, match=message):
        (obj,) = load_scene_bytes(builder.glb(), "glb", "q.glb").objects
    assert (obj.normal_texture is not None) == map_kept and obj.normals is not None
    if map_kept:
        assert np.isfinite(obj.tangents).all() and set(obj.tangents[:, 3]) <= {-1.0, 1.0}


def test_an_obj_norm_map_draws_as_three_js_draws_it(threejs, tmp_path):
    """MTL's ``norm`` (a tangent-space normal map, as three.js's MTLLoader reads it) over the OBJ's
    ``vt`` with its ``vn``, tangents derived from the uv; a ``bump`` height map is warned about."""
    from threejs import decode_normals

    from farfield.core.scene import SceneWarning

    PIL.Image.fromarray(bumps(32)).save(tmp_path / "bumps.png")
    (tmp_path / "quad.mtl").write_text("newmtl m\nKd 0.8 0.8 0.8\nnorm bumps.png\nbump bumps.png\n")
    (tmp_path / "quad.obj").write_text(
        "mtllib quad.mtl\nv -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 1\n"
        "usemtl m\nf 1/1/1 2/2/1 3/3/1\nf 1/1/1 3/3/1 4/4/1\n"
    )
    with pytest.warns(SceneWarning, match="bump is a height map"):
        scene = load_scene(tmp_path / "quad.obj")
    (obj,) = scene.objects
    assert obj.normal_texture is not None and obj.normal_texture.shape == (32, 32, 4)
    camera = Camera.look_at(np.array([0.0, 0.0, 3.0]), np.zeros(3), math.radians(50.0), 160, 0.5, 10.0)
    (three,) = threejs.render(tmp_path / "quad.obj", [camera], output="normal", mipmaps=False)
    with MeshRenderer(scene.objects, normals=True) as renderer:
        image, ours = renderer.render_normals(camera)
    both = (image[..., 3] > 0) & (three[..., 3] > 0)
    error = angles(ours[both], decode_normals(three)[both])
    print("obj norm", both.sum(), np.median(error), np.percentile(error, 95))
    assert both.sum() > 5000 and np.median(error) <= 1.0 and np.percentile(error, 95) <= 3.0
    assert np.median(angles(ours[both], np.array([0.0, 0.0, 1.0]))) > 15.0  # the map bends them
