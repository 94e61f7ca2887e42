"""Impostors an engine can light: the normal channel from recording to bundle, GLB and the lit
evaluation, checked against analytic normals (a sphere's, by ray intersection: no farfield renderer
on that side) and, in three.js, against a renderer that shares none of farfield's code."""

from __future__ import annotations

import json
import math
import struct
from dataclasses import replace

import numpy as np
import pytest
import trimesh

from farfield.core.errors import BundleFormatError
from farfield.core.impostor.bundle import read_bundle, write_bundle
from farfield.core.impostor.glb import impostor_glb, quad_frames
from farfield.core.impostor.impostor import decode_normals
from farfield.core.quality.lighting import view_directions
from farfield.core.quality.lit import evaluate_lit
from farfield.core.render.raster import Camera, MeshRenderer
from farfield.core.scene import Scene, SceneObject
from farfield.core.techniques.layered import BakeOptions, bake_layered
from farfield.core.viewcells import BoxCell

CENTRE = np.array([0.0, 0.0, 10.0])
CELL = BoxCell([-0.5, -0.5, -0.5], [0.5, 0.5, 0.5])


def sphere(smooth: bool = True, colour=(0.6, 0.5, 0.4, 1.0)) -> Scene:
    """A unit icosphere at CENTRE; smooth: its exact normals as vertex normals, else flat."""
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    normals = np.asarray(mesh.vertices) if smooth else None
    return Scene((SceneObject("ball", np.asarray(mesh.vertices) + CENTRE, np.asarray(mesh.faces), normals=normals,
                              base_color=colour),), "sphere")  # fmt: skip


def sphere_normals(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """(h, w) hit mask and (h, w, 3) unit normals of the unit sphere at CENTRE by ray intersection
    through every pixel centre of ``camera`` (top row first)."""
    r, t = camera.resolution, math.tan(0.5 * camera.fov)
    ys, xs = np.mgrid[0:r, 0:r] + 0.5
    d = (xs / r * 2 - 1)[..., None] * t * camera.right + (1 - ys / r * 2)[..., None] * t * camera.up + camera.forward
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    o = camera.eye - CENTRE
    b = d @ o
    disc = b * b - (o @ o - 1.0)
    hit = disc > 0
    distance = -b - np.sqrt(np.where(hit, disc, 0.0))
    return hit, o + d * distance[..., None]


def angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.einsum("...i,...i->...", a, b), -1.0, 1.0)))


@pytest.fixture(scope="module")
def lit_layered():
    return bake_layered(sphere(), CELL, BakeOptions(resolution=128, channels="albedo+normal"))


def test_the_g_buffer_draws_vertex_normals_flat_normals_and_back_faces_as_the_analytic_sphere():
    camera = Camera.look_at(np.zeros(3), CENTRE, math.radians(20.0), 96, 5.0, 15.0)
    hit, exact = sphere_normals(camera)
    for smooth, median_max in ((True, 0.2), (False, 3.0)):
        with MeshRenderer(sphere(smooth).objects, normals=True) as renderer:
            image, normals = renderer.render_normals(camera)
        covered = (image[..., 3] > 0) & hit
        assert covered.sum() > 2000
        assert np.median(angles(normals[covered], exact[covered])) < median_max, smooth
    # Inside the sphere (double-sided), the back faces show normals reversed: towards the eye.
    inside = Camera.look_at(CENTRE, CENTRE + [0.0, 0.0, 1.0], math.radians(40.0), 32, 0.01, 3.0)
    with MeshRenderer(sphere().objects, normals=True) as renderer:
        _, normals = renderer.render_normals(inside)
    assert np.percentile(angles(normals, view_directions(inside)), 99) < 1.0


def test_a_layered_impostor_keeps_the_normal_its_texel_shows(lit_layered):
    """Every kept texel's normal, from the reference viewpoint: the sphere's normal where the
    texel's centre ray meets it (the front layer's texels; the rim within a texel's slope)."""
    impostor = lit_layered
    assert set(impostor.channels) == {"normal"}
    assert [p.shape for p in impostor.channels["normal"]] == [p.shape for p in impostor.pages]
    stats = impostor.stats["channel_bytes"]
    assert stats["normal"] == stats["albedo"] == impostor.texture_bytes
    normals = np.concatenate([decode_normals(p)[p[..., 3] > 0] for p in impostor.channels["normal"]])
    # The sphere seen from inside the cell: every kept normal faces the cell's side (-z), none the back.
    assert normals.shape[0] > 1000 and (normals[:, 2] < 0.2).mean() > 0.99
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0)


def test_colour_only_bakes_keep_no_channel_and_their_bundles_say_nothing_of_one(tmp_path):
    impostor = bake_layered(sphere(), CELL, BakeOptions(resolution=64))
    assert impostor.channels == {} and "channel_bytes" not in impostor.stats
    paths = write_bundle(impostor, tmp_path / "b")
    assert "channels" not in json.loads(paths.manifest.read_text())
    assert not list(paths.directory.glob("normal-*"))
    document = glb_json(paths.glb.read_bytes())
    assert document["extensionsUsed"] == ["KHR_materials_unlit"]


def test_the_bundle_keeps_the_normal_pages_bit_for_bit_and_refuses_a_broken_entry(lit_layered, tmp_path):
    paths = write_bundle(lit_layered, tmp_path / "b")
    back = read_bundle(paths.directory)
    assert all(np.array_equal(a, b) for a, b in zip(back.channels["normal"], lit_layered.channels["normal"]))
    assert write_bundle(back, tmp_path / "again").manifest.read_bytes() == paths.manifest.read_bytes()
    manifest = json.loads(paths.manifest.read_text())
    manifest["channels"]["normal"][0]["file"] = "../elsewhere.png"
    paths.manifest.write_text(json.dumps(manifest))
    with pytest.raises(BundleFormatError, match="channels.normal"):
        read_bundle(paths.directory)


def glb_json(data: bytes) -> dict:
    length = struct.unpack_from("<I", data, 12)[0]
    return json.loads(data[20 : 20 + length])


def test_the_lit_glb_is_metallic_roughness_with_tangent_space_normals_and_validates(
    lit_layered, tmp_path, gltf_validator
):
    data = impostor_glb(lit_layered)
    path = tmp_path / "lit.glb"
    path.write_bytes(data)
    (report,) = gltf_validator.validate([path])
    assert report.get("errors") == 0 and report.get("warnings") == 0, report
    document = glb_json(data)
    assert "extensionsUsed" not in document  # no unlit material left
    pages = len(lit_layered.pages)
    for material in document["materials"]:
        assert "extensions" not in material and material["normalTexture"]["index"] >= pages
        assert material["pbrMetallicRoughness"]["metallicFactor"] == 0.0
    for primitive in document["meshes"][0]["primitives"]:
        assert {"NORMAL", "TANGENT"} <= set(primitive["attributes"])
    # A quad's tangent frame: T along the page's +x, B up the page, N towards the viewpoint.
    frames = quad_frames(lit_layered.payload, lit_layered.reference_viewpoint)
    assert np.allclose(np.einsum("qij,qkj->qik", frames, frames), np.eye(3), atol=1e-9)
    to_viewpoint = lit_layered.reference_viewpoint - lit_layered.payload.corners[:, 0]
    assert (np.einsum("qi,qi->q", frames[:, 2], to_viewpoint) > 0).all()


def test_the_lit_evaluation_meets_the_normal_and_flat_card_targets_on_a_smooth_sphere(lit_layered):
    result = evaluate_lit(sphere(), lit_layered, random_count=1)
    t = result.totals
    print(json.dumps(t, indent=1))
    assert t["normal_error_median"] <= 5.0 and t["normal_error_interior_p95"] <= 20.0
    assert t["flat_normal_error_median"] > 20.0  # the cards face the viewer, the sphere does not
    assert t["flat_to_lit_least"] >= 2.0
    assert len(t["lights"]) == len(result.lights) == 5
    # A uniform sphere has no unlit error; lit, the error stays within a few levels on average.
    assert all(row["lit_error_mean"] <= 3.0 for row in t["lights"])


def test_without_normals_the_lit_impostor_is_a_flat_card(tmp_path):
    impostor = bake_layered(sphere(), CELL, BakeOptions(resolution=64))
    result = evaluate_lit(sphere(), impostor, random_count=0)
    t = result.totals
    assert t["normal_error_median"] == pytest.approx(t["flat_normal_error_median"])
    assert t["flat_to_lit_least"] == pytest.approx(1.0)


def test_a_flat_shaded_source_keeps_its_facets(tmp_path):
    faceted = sphere(smooth=False)
    impostor = bake_layered(faceted, CELL, BakeOptions(resolution=128, channels="albedo+normal"))
    t = evaluate_lit(faceted, impostor, random_count=0).totals
    assert t["normal_error_interior_median"] <= 5.0


def test_a_double_sided_triangle_seen_from_behind_records_its_reversed_normal():
    quad = SceneObject("q", np.array([[-1.0, -1, 10], [1, -1, 10], [1, 1, 10], [-1, 1, 10]]),
                       np.array([[0, 1, 2], [0, 2, 3]]))  # fmt: skip  # front (+z) faces away from the cell
    for sided, expected in ((True, -1.0), (False, 1.0)):
        scene = Scene((replace(quad, double_sided=sided, normals=np.tile([0.0, 0.0, 1.0], (4, 1))),), "q")
        cell = BoxCell([-0.1, -0.1, -0.1], [0.1, 0.1, 0.1]) if sided else BoxCell([-0.1, -0.1, 10.5], [0.1, 0.1, 10.7])
        impostor = bake_layered(scene, cell, BakeOptions(resolution=32, channels="albedo+normal"))
        page = impostor.channels["normal"][0]
        normals = decode_normals(page)[page[..., 3] > 0]
        assert normals.size and np.allclose(normals[:, 2], expected, atol=0.02), sided


def impostor_cameras(impostor, resolution: int) -> list[Camera]:
    """The reference viewpoint and two far corners of the cell, looking at the sphere."""
    points = [impostor.reference_viewpoint, np.array([0.5, 0.5, -0.5]), np.array([-0.5, -0.5, 0.5])]
    return [Camera.look_at(p, CENTRE, math.radians(impostor.fov_deg), resolution, 5.0, 15.0) for p in points]


def test_three_js_reads_the_glbs_tangent_space_normals_and_lights_them_as_the_lit_evaluation(
    lit_layered, tmp_path, threejs
):
    """three.js (GLTFLoader, MeshStandardMaterial: none of farfield's code) draws the lit GLB's
    world normals and its lit colours under each test light; farfield's G-buffer of the bundle,
    shaded by :func:`~farfield.core.quality.lighting.shade`, must agree: the tangent frames, the
    handedness of the TANGENT's w and the normal texture's +Y convention all show here."""
    from threejs import decode_normals as three_normals

    from farfield.core.quality.lighting import AMBIENT, default_lights, shade
    from farfield.core.quality.lit import impostor_gbuffer

    path = tmp_path / "lit.glb"
    path.write_bytes(impostor_glb(lit_layered))
    cameras = impostor_cameras(lit_layered, 160)
    with impostor_gbuffer(lit_layered) as renderer:
        ours = [renderer.render_normals(camera) for camera in cameras]
    theirs = threejs.render(path, cameras, mipmaps=False, output="normal")
    for (image, normals), three in zip(ours, theirs, strict=True):
        both = (image[..., 3] > 0) & (three[..., 3] > 0)
        assert both.sum() > 1000
        error = angles(normals[both], three_normals(three)[both])
        print("normal angle", np.median(error), np.percentile(error, 95))
        assert np.median(error) <= 0.5 and np.percentile(error, 95) <= 2.0
    for light in default_lights():
        lit = threejs.render(path, cameras, mipmaps=False, lights=[light], ambient=AMBIENT)
        for camera, (image, normals), three in zip(cameras, ours, lit, strict=True):
            both = (image[..., 3] > 0) & (three[..., 3] > 0)
            mine = shade(image[..., :3], normals, view_directions(camera), light, AMBIENT)
            difference = np.abs(mine.astype(int) - three[..., :3].astype(int)).max(axis=-1)[both]
            print("lit", light.direction.round(2), difference.mean(), np.percentile(difference, 99))
            assert difference.mean() <= 1.0 and np.percentile(difference, 99) <= 4, light


def test_a_compressed_lit_glb_keeps_its_normals_in_linear_uastc(lit_layered, tmp_path, gltf_validator, threejs):
    """KTX2 pages: the colour pages in the codec asked for, the normal textures in UASTC with a
    linear transfer function whatever it was; three.js draws the same normals from it."""
    import alktx2
    from glb_validation import problems
    from threejs import decode_normals as three_normals

    from farfield.core.impostor.glb_compression import compress_glb, decode_ktx2, read_glb

    plain = tmp_path / "plain.glb"
    plain.write_bytes(impostor_glb(lit_layered))
    packed = tmp_path / "packed.glb"
    packed.write_bytes(compress_glb(plain.read_bytes(), "ktx2", "meshopt", "etc1s"))
    (report,) = gltf_validator.validate([packed])
    assert problems(report) == []  # beyond the validator not knowing KHR_texture_basisu
    document, blob = read_glb(packed.read_bytes())
    textures = document["textures"]
    normal_sources = {
        textures[m["normalTexture"]["index"]]["extensions"]["KHR_texture_basisu"]["source"]
        for m in document["materials"]
    }
    for index in normal_sources:
        view = document["bufferViews"][document["images"][index]["bufferView"]]
        data = blob[view["byteOffset"] : view["byteOffset"] + view["byteLength"]]
        info = alktx2.inspect_ktx2(data)
        assert info["is_uastc"] and not info["is_srgb"], info
        assert "uastc" in document["images"][index]["name"]
        decoded = decode_ktx2(data)
        assert decoded.shape[0] >= lit_layered.channels["normal"][0].shape[0]
    cameras = impostor_cameras(lit_layered, 128)
    before = threejs.render(plain, cameras, mipmaps=False, output="normal")
    after = threejs.render(packed, cameras, mipmaps=False, output="normal")
    for a, b in zip(before, after, strict=True):
        both = (a[..., 3] > 0) & (b[..., 3] > 0)
        error = angles(three_normals(a)[both], three_normals(b)[both])
        print("ktx2 normals", np.median(error), np.percentile(error, 95))
        assert both.sum() > 500 and np.median(error) <= 1.5 and np.percentile(error, 95) <= 6.0


def test_a_lit_rebake_is_byte_identical(tmp_path):
    first = write_bundle(
        bake_layered(sphere(), CELL, BakeOptions(resolution=64, channels="albedo+normal")), tmp_path / "a"
    )
    again = write_bundle(
        bake_layered(sphere(), CELL, BakeOptions(resolution=64, channels="albedo+normal")), tmp_path / "b"
    )
    for name in ("manifest.json", "payload.bin", "atlas-000.png", "normal-000.png", "impostor.glb"):
        assert (first.directory / name).read_bytes() == (again.directory / name).read_bytes(), name


def test_a_viewpoint_with_nothing_both_cover_is_left_out_of_the_normal_totals():
    from farfield.core.quality.lit import lit_totals

    light = {"lit_error_mean": 1.0, "lit_error_p99": 2.0, "lit_ssim": 1.0, "flat_error_mean": 3.0,
             "flat_error_p99": 4.0, "unlit_error_mean": 1.0, "unlit_error_p99": 2.0}  # fmt: skip
    seen = {"both_pixels": 10, "lights": [light], "normal_error_median": 4.0, "normal_error_p95": 9.0,
            "normal_error_interior_median": 4.0, "normal_error_interior_p95": 9.0, "normal_error_smooth_median": 2.0,
            "normal_error_smooth_p95": 5.0, "smooth_share": 0.5, "flat_normal_error_median": 30.0}  # fmt: skip
    empty = seen | {"both_pixels": 0} | {k: None for k in seen if k.startswith(("normal_error", "flat_normal"))}
    totals = lit_totals([seen, empty], 1)
    assert totals["normal_error_median"] == 4.0 and totals["normal_error_smooth_median"] == 2.0
    assert totals["flat_normal_error_median"] == 30.0 and totals["normal_error_p95"] == 9.0
