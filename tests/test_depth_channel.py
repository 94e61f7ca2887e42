"""The depth channel (issue 55, ``+depth``): quad impostors keep each texel's depth in the normal
page's alpha and each quad's ray scales; decoded, the texels land on the source surface within
half a quantisation step.  Checked against analytic surfaces (a tilted square, by ray-plane
intersection; a sphere) rather than against a farfield renderer, then through the bundle and the
GLB (its own accessors decoded: X = POSITION x scale in the node's frame), and refused where the
geometry is exact."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
import trimesh

from farfield.core.errors import LayerPlanError
from farfield.core.impostor.bundle import read_bundle, write_bundle
from farfield.core.impostor.depth import DEPTH_ATTRIBUTE, DEPTH_EXTENSION, depth_points, quad_texels
from farfield.core.impostor.glb import impostor_glb
from farfield.core.impostor.glb_compression import _COMPONENT_BYTES, _TYPE_COUNT, read_glb
from farfield.core.scene import Scene, SceneObject
from farfield.core.techniques.layered import BakeOptions, bake_layered
from farfield.core.viewcells import BoxCell

CENTRE = np.array([0.0, 0.0, 10.0])
CELL = BoxCell([-0.5, -0.5, -0.5], [0.5, 0.5, 0.5])
HALF = 1.5  # the square's half side
TILT = math.radians(55.0)  # about y: the square spans ~2.5 m of depth, several layers
AXES = np.array([[math.cos(TILT), 0.0, math.sin(TILT)], [0.0, 1.0, 0.0]])  # the square's in-plane axes
NORMAL = np.cross(AXES[0], AXES[1])


def tilted_square() -> Scene:
    corners = CENTRE + np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], float) @ (HALF * AXES)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    return Scene((SceneObject("square", corners, faces, base_color=(0.7, 0.6, 0.5, 1.0), double_sided=True),), "sq")


@pytest.fixture(scope="module")
def square_depth():
    return bake_layered(tilted_square(), CELL, BakeOptions(resolution=96, channels="albedo+normal+depth"))


def plane_check(impostor):
    """Per kept texel whose centre's ray meets the square inside its quad's slab (away from the
    square's edges by a texel): (decoded scale, true scale, quantisation half step, |P - V|)."""
    payload, viewpoint = impostor.payload, impostor.reference_viewpoint
    pages, normal = impostor.pages, impostor.channels["normal"]
    rows = []
    for q in range(payload.count):
        r, c, on_quad = quad_texels(impostor, q)
        page = int(payload.page[q])
        keep = pages[page][r, c, 3] > 0
        ray = on_quad[keep] - viewpoint
        true = ((CENTRE - viewpoint) @ NORMAL) / (ray @ NORMAL)
        hit = viewpoint + ray * true[:, None]
        local = np.abs((hit - CENTRE) @ AXES.T).max(axis=1)
        s0, s1 = payload.depth_range[q]
        texel = np.linalg.norm(on_quad[1] - on_quad[0]) if len(on_quad) > 1 else 0.0
        inside = (true >= s0) & (true <= s1) & (local < HALF - 3.0 * texel * true)
        code = normal[page][r[keep], c[keep], 3].astype(np.float64)
        scale = s0 + code / 255.0 * (s1 - s0)
        length = np.linalg.norm(ray, axis=1)
        rows.append(np.stack([scale, true, np.full(scale.size, (s1 - s0) / 510.0), length], axis=1)[inside])
    return np.concatenate(rows)


def test_depth_places_every_texel_on_a_tilted_square_within_half_a_step(square_depth):
    """Decoded along its ray, every kept texel that shows the square lies within half a
    quantisation step of its analytic intersection (plus float32 rounding), where the flat quad
    leaves it up to half a layer away."""
    impostor = square_depth
    assert impostor.payload.depth_range.shape == (impostor.payload.count, 2)
    assert len({int(layer) for layer in impostor.payload.layer}) >= 3  # the square crosses several slabs
    rows = plane_check(impostor)
    assert len(rows) > 1500
    scale, true, half_step, length = rows.T
    error = np.abs(scale - true) * length  # metres along the ray
    bound = half_step * length + 1e-4
    assert np.all(error <= bound), (error - bound).max()
    flat = np.abs(1.0 - true) * length  # the quad's own point: what a texel without depth shows
    assert np.median(flat) > 20 * np.median(error) and error.max() < 0.01 < flat.max()


def test_depth_points_lie_on_the_sphere():
    """A sphere (its facets 0.8 mm from the analytic one): the decoded points' radial error is
    below a millimetre at the median; the texels at the silhouette and at slab borders (kept by
    the conservative rule) take a neighbouring point's depth, so the largest stays about a texel."""
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    ball = SceneObject(
        "ball", np.asarray(mesh.vertices) + CENTRE, np.asarray(mesh.faces), normals=np.asarray(mesh.vertices)
    )
    impostor = bake_layered(Scene((ball,), "s"), CELL, BakeOptions(resolution=96, channels="albedo+normal+depth"))
    points, quad = depth_points(impostor)
    radial = np.abs(np.linalg.norm(points - CENTRE, axis=1) - 1.0)
    steps = impostor.payload.depth_range[quad] @ [-1.0, 1.0] * np.linalg.norm(points - CENTRE, axis=1).max()
    assert np.median(radial) < 0.002 and np.percentile(radial, 90) < 0.02 and radial.max() < 0.05
    assert np.median(steps) < 1.0  # slabs under a metre: a step under 4 mm


def test_an_impostor_without_depth_has_none(tmp_path):
    """albedo+normal: no ranges, alpha 255 in every tile, no alpha entry, no extension, no attribute."""
    impostor = bake_layered(tilted_square(), CELL, BakeOptions(resolution=64, channels="albedo+normal"))
    assert impostor.payload.depth_range is None
    with pytest.raises(ValueError, match="no depth"):
        depth_points(impostor)
    for q in range(impostor.payload.count):
        r, c, _ = quad_texels(impostor, q)
        assert (impostor.channels["normal"][int(impostor.payload.page[q])][r, c, 3] == 255).all()
    write_bundle(impostor, tmp_path / "b")
    manifest = json.loads((tmp_path / "b" / "manifest.json").read_text())
    assert all("alpha" not in entry for entry in manifest["channels"]["normal"])
    assert "depth_range" not in [a["name"] for a in manifest["payload"]["arrays"]]
    document, _ = read_glb((tmp_path / "b" / "impostor.glb").read_bytes())
    assert DEPTH_EXTENSION not in document.get("extensionsUsed", [])
    assert all(DEPTH_ATTRIBUTE not in p["attributes"] for p in document["meshes"][0]["primitives"])


def _accessor(document: dict, blob: bytes, index: int) -> np.ndarray:
    accessor = document["accessors"][index]
    view = document["bufferViews"][accessor["bufferView"]]
    dtype = {5126: "<f4", 5123: "<u2", 5125: "<u4"}[accessor["componentType"]]
    count, width = accessor["count"], _TYPE_COUNT[accessor["type"]]
    start = view.get("byteOffset", 0) + accessor.get("byteOffset", 0)
    data = np.frombuffer(blob, dtype, count * width, start)
    assert _COMPONENT_BYTES[accessor["componentType"]] * count * width <= view["byteLength"]
    return data.reshape(count, width) if width > 1 else data


def test_the_bundle_and_the_glb_keep_the_depth(square_depth, tmp_path):
    """The bundle round-trips the ranges and says its normal pages' alpha holds depth; the GLB
    (Khronos validator: 0 errors, 0 warnings, by the autouse fixture) uses, not requires, the
    extension, keeps the alpha in its normal textures, and its own POSITION x _DEPTH_RANGE put the
    texels where the bundle does."""
    impostor = square_depth
    write_bundle(impostor, tmp_path / "b")
    manifest = json.loads((tmp_path / "b" / "manifest.json").read_text())
    assert all(entry["alpha"] == "depth" for entry in manifest["channels"]["normal"])
    back = read_bundle(tmp_path / "b")
    assert np.array_equal(back.payload.depth_range, impostor.payload.depth_range)
    assert all(np.array_equal(a, b) for a, b in zip(back.channels["normal"], impostor.channels["normal"]))

    document, blob = read_glb((tmp_path / "b" / "impostor.glb").read_bytes())
    assert DEPTH_EXTENSION in document["extensionsUsed"]
    assert DEPTH_EXTENSION not in document.get("extensionsRequired", [])
    from io import BytesIO

    from PIL import Image

    for material in document["materials"]:
        assert material["extensions"][DEPTH_EXTENSION]["attribute"] == DEPTH_ATTRIBUTE
        image = document["images"][document["textures"][material["normalTexture"]["index"]]["source"]]
        view = document["bufferViews"][image["bufferView"]]
        png = blob[view.get("byteOffset", 0) : view.get("byteOffset", 0) + view["byteLength"]]
        alpha = np.asarray(Image.open(BytesIO(png)).convert("RGBA"))[..., 3]
        page = int(material["name"].removeprefix("atlas-"))
        assert np.array_equal(alpha, impostor.channels["normal"][page][..., 3])
    # Each quad's ray scales on its vertices: decode the quad's centre from the GLB alone (the
    # mean of its four vertices, the tile's centre texel's code at worst half a texel off).
    ranges = {tuple(r) for r in impostor.payload.depth_range.astype("<f4").tolist()}
    for primitive in document["meshes"][0]["primitives"]:
        stored = _accessor(document, blob, primitive["attributes"][DEPTH_ATTRIBUTE])
        assert {tuple(r) for r in stored.tolist()} <= ranges
        position = _accessor(document, blob, primitive["attributes"]["POSITION"])
        assert position.shape[0] == stored.shape[0]
        # X = POSITION x s in the node's frame: every vertex between its quad's slab planes.
        near = position * stored[:, :1] + impostor.reference_viewpoint
        far = position * stored[:, 1:] + impostor.reference_viewpoint
        assert np.all(
            (near - impostor.reference_viewpoint) @ np.array([0, 0, 1.0])
            <= (far - impostor.reference_viewpoint) @ np.array([0, 0, 1.0]) + 1e-6
        )


def test_ktx2_keeps_the_depth_in_uastc(square_depth, tmp_path):
    """A compressed GLB's normal textures with depth stay UASTC, at quality 100: the alpha (the depth)
    within 3 levels at the 99th percentile (at the default quality 50, 20)."""
    pytest.importorskip("alktx2")
    from farfield.core.impostor.glb_compression import compress_glb, decode_ktx2

    packed = compress_glb(impostor_glb(square_depth), "ktx2", "meshopt", codec="etc1s")
    (tmp_path / "packed.glb").write_bytes(packed)  # the validator checks it (autouse fixture)
    document, blob = read_glb(packed)
    assert DEPTH_EXTENSION in document["extensionsUsed"] and DEPTH_EXTENSION not in document["extensionsRequired"]
    material = document["materials"][0]
    texture = document["textures"][material["normalTexture"]["index"]]
    image = document["images"][texture["extensions"]["KHR_texture_basisu"]["source"]]
    assert image["name"].endswith("uastc")
    view = document["bufferViews"][image["bufferView"]]
    decoded = decode_ktx2(blob[view.get("byteOffset", 0) : view.get("byteOffset", 0) + view["byteLength"]])
    page = square_depth.channels["normal"][0]
    inside = square_depth.pages[0][..., 3] > 0
    difference = np.abs(decoded[..., 3].astype(int) - page[..., 3])[inside]
    assert np.median(difference) <= 1 and np.percentile(difference, 99) <= 4 and difference.max() <= 12


@pytest.mark.parametrize("technique", ["tdm", "points", "ldi"])
def test_techniques_with_exact_geometry_refuse_depth(technique):
    from farfield.core.techniques.ldi import LdiOptions
    from farfield.core.techniques.points.technique import PointOptions
    from farfield.core.techniques.tdm.technique import TdmOptions

    options = {"tdm": TdmOptions, "points": PointOptions, "ldi": LdiOptions}[technique]
    with pytest.raises(LayerPlanError, match=f"{technique} keeps? no depth channel .*use albedo\\+normal$"):
        options(channels="albedo+normal+depth")
    with pytest.raises(LayerPlanError, match="use albedo\\+normal\\+material$"):
        options(channels="albedo+normal+material+depth")
    assert options(channels="albedo+normal").channels == "albedo+normal"


def test_envmap_depth_puts_the_far_field_on_its_spheres():
    """An environment map (six faces, 16 layers, the last slab reaching the farthest geometry): the
    decoded texels lie on six spheres (their facets ~9 mm from the analytic ones) at a median of
    about a centimetre, where the quads themselves are ~24 cm off."""
    from farfield.core.techniques.envmap.technique import EnvmapOptions, bake_envmap

    cell = BoxCell.from_center([0.0, 0.0, 0.0], 2.0)
    centres = np.array(
        [(12.0, 0.0, 0.0), (-12.0, 1.0, 0.0), (0.0, 0.0, 12.0), (1.0, -1.0, -12.0), (0.0, 12.0, 0.0), (0.0, -12.0, 2.0)]
    )
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=3.0)
    balls = [SceneObject(f"ball{i}", np.asarray(mesh.vertices) + c, np.asarray(mesh.faces), normals=np.asarray(mesh.vertices) / 3.0)
             for i, c in enumerate(centres)]  # fmt: skip
    impostor = bake_envmap(
        Scene(tuple(balls), "balls"), cell, EnvmapOptions(resolution=64, layers=16, channels="albedo+normal+depth")
    )
    assert impostor.payload.depth_range.shape == (impostor.payload.count, 2)
    points, quad = depth_points(impostor)
    radial = np.abs(np.linalg.norm(points[:, None] - centres[None], axis=2).min(axis=1) - 3.0)
    on_quad = []
    for q in range(impostor.payload.count):
        r, c, at = quad_texels(impostor, q)
        on_quad.append(at[impostor.pages[int(impostor.payload.page[q])][r, c, 3] > 0])
    flat = np.abs(np.linalg.norm(np.concatenate(on_quad)[:, None] - centres[None], axis=2).min(axis=1) - 3.0)
    assert len(points) > 1000 and np.median(radial) < 0.02 and np.median(flat) > 10 * np.median(radial)


def test_a_pixel_depth_offset_cuts_the_impostor_where_the_plane_cuts_the_sphere():
    """A plane through a sphere, drawn with the impostor from three viewpoints of the cell (CPU ray
    casting, :mod:`farfield.core.render.depth_offset`) against the analytic sphere: with the depth
    channel's pixel depth offset the plane hides the impostor on the pixels where it hides the
    sphere but for a few along the intersection (at most a fifth of those the flat layers miss),
    and the depth of the impostor is a centimetre off where the quads are eleven."""
    from farfield.core.render.depth_offset import camera_rays, impostor_depth
    from farfield.core.render.raster import Camera

    mesh = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    ball = SceneObject(
        "ball", np.asarray(mesh.vertices) + CENTRE, np.asarray(mesh.faces), normals=np.asarray(mesh.vertices)
    )
    impostor = bake_layered(Scene((ball,), "s"), CELL, BakeOptions(resolution=96, channels="albedo+normal+depth"))
    normal = np.array([0.3, 0.8, 0.5]) / np.linalg.norm([0.3, 0.8, 0.5])
    on_plane = CENTRE + [0.0, 0.1, 0.0]
    for eye in ([0.0, 0.0, 0.0], [0.5, 0.5, -0.5], [-0.5, 0.3, 0.5]):
        camera = Camera.look_at(np.array(eye), CENTRE, math.radians(16.0), 128, 0.1, 100.0)
        rays = camera_rays(camera).reshape(-1, 3)
        o = camera.eye - CENTRE
        a, b = np.einsum("ij,ij->i", rays, rays), rays @ o
        disc = b * b - a * (o @ o - 1.0)
        sphere = np.where(disc > 0, (-b - np.sqrt(np.maximum(disc, 0.0))) / a, np.inf).reshape(128, 128)
        plane = (((on_plane - camera.eye) @ normal) / (rays @ normal)).reshape(128, 128)
        plane = np.where(plane > 0, plane, np.inf)
        wrong, error = {}, {}
        for offset in (False, True):
            depth = impostor_depth(impostor, camera, offset)
            both = np.isfinite(sphere) & np.isfinite(depth)
            wrong[offset] = int((((plane < sphere) != (plane < depth)) & both).sum())
            error[offset] = float(np.median(np.abs(depth[both] - sphere[both])))
        assert wrong[True] * 4 < wrong[False] and wrong[False] > 100, wrong
        assert error[True] < 0.015 and error[False] > 0.08, error
    plain = replace(impostor, payload=replace(impostor.payload, depth_range=None))
    with pytest.raises(ValueError, match="no depth"):
        impostor_depth(plain, camera)


def test_depth_changes_nothing_else_and_three_js_draws_the_lit_cards(square_depth, tmp_path, threejs):
    """The same bake without depth: the same colour pages, quads and normals (the normal pages
    differ in alpha alone). three.js, which knows no FARFIELD_impostor_depth, draws both GLBs lit
    alike: the fallback is the lit cards."""
    from farfield.core.quality.lighting import AMBIENT, default_lights
    from farfield.core.render.raster import Camera

    plain = bake_layered(tilted_square(), CELL, BakeOptions(resolution=96, channels="albedo+normal"))
    assert all(np.array_equal(a, b) for a, b in zip(plain.pages, square_depth.pages, strict=True))
    assert all(
        np.array_equal(getattr(plain.payload, n), getattr(square_depth.payload, n))
        for n in ("corners", "uv", "page", "layer")
    )
    for a, b in zip(plain.channels["normal"], square_depth.channels["normal"], strict=True):
        assert np.array_equal(a[..., :3], b[..., :3]) and not np.array_equal(a[..., 3], b[..., 3])
    paths = []
    for name, impostor in (("plain", plain), ("depth", square_depth)):
        paths.append(tmp_path / f"{name}.glb")
        paths[-1].write_bytes(impostor_glb(impostor))
    cameras = [
        Camera.look_at(np.array(eye), CENTRE, math.radians(30.0), 96, 0.1, 100.0)
        for eye in ([0.0, 0.0, 0.0], [0.5, -0.5, 0.5])
    ]
    light = default_lights()[1]
    plain_frames, depth_frames = (
        threejs.render(path, cameras, mipmaps=False, lights=[light], ambient=AMBIENT) for path in paths
    )
    for a, b in zip(plain_frames, depth_frames, strict=True):
        assert (a[..., 3] > 0).sum() > 1000
        assert np.abs(a.astype(int) - b.astype(int)).max() <= 1
