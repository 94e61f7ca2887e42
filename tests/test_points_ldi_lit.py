"""Point-based and LDI impostors an engine can light: each point and each LDI sample keeps its world
shading normal (``channels="albedo+normal"``), through the bundle, the GLB and the lit evaluation,
checked against a sphere's analytic normals and, in three.js, against a renderer that shares none of
farfield's code."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
from test_lit_impostors import CELL, CENTRE, angles, glb_json, sphere

from farfield.core.errors import BundleFormatError, ConflictError
from farfield.core.impostor.bundle import check_destination, read_bundle, write_bundle
from farfield.core.impostor.glb import POINT_APPEARANCE, impostor_glb
from farfield.core.impostor.impostor import decode_normals
from farfield.core.ldi.image import ldi_of
from farfield.core.quality.lit import evaluate_lit, impostor_gbuffer
from farfield.core.render.raster import Camera
from farfield.core.techniques.ldi import LdiOptions, bake_ldi
from farfield.core.techniques.points.technique import PointOptions, bake_points

POINTS = dict(resolution=96, min_views=16, max_views=16)  # a small bake: the sphere is one colour
LDI = dict(resolution=96)


@pytest.fixture(scope="module")
def lit_points():
    return bake_points(sphere(), CELL, PointOptions(**POINTS, channels="albedo+normal"))


@pytest.fixture(scope="module")
def lit_ldi():
    return bake_ldi(sphere(), CELL, LdiOptions(**LDI, channels="albedo+normal"))


def outward(positions: np.ndarray) -> np.ndarray:
    """The unit sphere's normal at ``positions`` (n, 3) on it: its vertex normals are its vertex
    positions, so a point on a facet interpolates to exactly this direction."""
    d = positions - CENTRE
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def ldi_normals(impostor) -> tuple[np.ndarray, np.ndarray]:
    """((m, 3) world positions, (m, 3) decoded normals) of an LDI impostor's samples."""
    ldi = ldi_of(impostor)
    positions, index = ldi.samples()
    pages = impostor.channels["normal"]
    normals = np.stack([decode_normals(pages[2 * k]) for k in range(ldi.layers)])[index[:, 0], index[:, 1], index[:, 2]]
    return positions, normals


def test_each_point_keeps_the_normal_of_the_sphere_where_it_lies(lit_points):
    payload = lit_points.payload
    assert payload.normal.shape == (payload.count, 3) and payload.normal.dtype == np.float64
    assert np.allclose(np.linalg.norm(payload.normal, axis=1), 1.0)
    error = angles(payload.normal, outward(payload.positions))
    # All but the rim: a double-sided rim facet whose back faces the whole cell keeps its reversed
    # normal (glTF's double-sided rule), and a conservative sample there can be the only point of a
    # silhouette window the cover must fill (3.9 % of the points since the cover of
    # core/techniques/points/cover.py; 0.4 % when only the points that won a pixel stayed).
    assert np.median(error) < 0.01 and (error < 0.1).mean() > 0.95, np.percentile(error, [50, 99])
    assert (error[error >= 0.1] > 170.0).all()
    stats = lit_points.stats
    assert stats["channel_bytes"] == {
        "albedo": stats["geometry_bytes"] + stats["texture_bytes"],
        "normal": 12 * payload.count,
    }


def test_a_flat_shaded_source_gives_its_points_the_facet_normals():
    faceted = sphere(smooth=False)
    impostor = bake_points(faceted, CELL, PointOptions(**POINTS, channels="albedo+normal"))
    payload = impostor.payload
    (ball,) = faceted.objects
    corners = ball.vertices[ball.faces]
    face = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    face /= np.linalg.norm(face, axis=1, keepdims=True)
    # A point's facets: those near it (centroid within a facet's size) whose plane it lies in (two
    # or more for a point on an edge); its normal is one of theirs.
    near = np.linalg.norm(payload.positions[:, None] - corners.mean(axis=1)[None], axis=2) < 0.1
    off_plane = np.abs(np.einsum("fi,nfi->nf", face, payload.positions[:, None] - corners[None, :, 0]))
    on = near & (off_plane < 1e-4)  # float32 depths
    assert on.any(axis=1).all()
    error = np.where(on, angles(payload.normal[:, None], face[None]), np.inf).min(axis=1)
    assert (error < 0.01).mean() > 0.95, np.percentile(error, [50, 99])  # the rim's, as above


def test_each_ldi_sample_keeps_its_normal_in_a_page_beside_its_colour(lit_ldi):
    pages, normal = lit_ldi.pages, lit_ldi.channels["normal"]
    assert [p.shape for p in normal] == [p.shape for p in pages]
    for k in range(len(pages) // 2):
        assert np.array_equal(normal[2 * k][..., 3] > 0, pages[2 * k][..., 3] > 0)  # a normal where a sample is
        assert not normal[2 * k + 1].any()  # the depth pages have none
    positions, normals = ldi_normals(lit_ldi)
    error = angles(normals, outward(positions))
    assert positions.shape[0] == lit_ldi.payload.count
    assert np.median(error) < 0.5 and np.percentile(error, 99.9) < 1.5, np.percentile(error, [50, 99.9])
    layers, side = lit_ldi.payload.size[1], lit_ldi.payload.size[0]
    assert lit_ldi.stats["channel_bytes"] == {
        "albedo": lit_ldi.stats["texture_bytes"],
        "normal": layers * side * side * 4,
    }


@pytest.mark.parametrize(
    "bake, options", [(bake_points, PointOptions(**POINTS)), (bake_ldi, LdiOptions(**LDI))], ids=["points", "ldi"]
)
def test_the_normals_change_no_byte_of_what_a_colour_only_bake_writes(bake, options, tmp_path):
    """A colour-only bake keeps no normal, and a bake with normals, its normals taken away, writes
    the colour-only bundle byte for byte: the normals perturb nothing else."""
    plain = bake(sphere(), CELL, options)
    lit = bake(sphere(), CELL, replace(options, channels="albedo+normal"))
    assert plain.channels == {} and "channel_bytes" not in plain.stats
    assert getattr(plain.payload, "normal", None) is None
    stripped = replace(
        lit,
        payload=replace(lit.payload, normal=None) if hasattr(lit.payload, "normal") else lit.payload,
        channels={},
        stats={k: v for k, v in lit.stats.items() if k not in ("channel_bytes", "splat_normal_bytes")},
        parameters=lit.parameters | {"channels": "albedo"},
    )
    a, b = write_bundle(plain, tmp_path / "plain"), write_bundle(stripped, tmp_path / "stripped")
    names = sorted(p.name for p in a.directory.iterdir())
    assert names == sorted(p.name for p in b.directory.iterdir())
    for name in names:
        assert (a.directory / name).read_bytes() == (b.directory / name).read_bytes(), name
    manifest = json.loads(a.manifest.read_text())
    assert "normal" not in [entry["name"] for entry in manifest["payload"]["arrays"]] and "channels" not in manifest


def test_the_point_bundle_keeps_the_normals_bit_for_bit_and_refuses_a_misplaced_entry(lit_points, tmp_path):
    paths = write_bundle(lit_points, tmp_path / "b")
    manifest = json.loads(paths.manifest.read_text())
    names = [entry["name"] for entry in manifest["payload"]["arrays"]]
    assert names[-1] == "normal" and names[:-1] == [name for name, _, _ in type(lit_points.payload).ARRAYS]
    back = read_bundle(paths.directory)
    assert np.array_equal(back.payload.normal, lit_points.payload.normal)
    assert write_bundle(back, tmp_path / "again").payload.read_bytes() == paths.payload.read_bytes()
    manifest["payload"]["arrays"].insert(0, manifest["payload"]["arrays"].pop())  # the normals first
    paths.manifest.write_text(json.dumps(manifest))
    with pytest.raises(BundleFormatError, match="then any of"):
        read_bundle(paths.directory)


def test_the_ldi_bundle_keeps_the_normal_pages_and_a_rebake_may_replace_it(lit_ldi, tmp_path):
    back = read_bundle(write_bundle(lit_ldi, tmp_path / "b").directory)
    assert all(np.array_equal(a, b) for a, b in zip(back.channels["normal"], lit_ldi.channels["normal"], strict=True))
    check_destination(tmp_path / "b")  # normal-NNN.png are a bundle's files: --out may name it again
    (tmp_path / "b" / "notes.txt").write_text("mine")
    with pytest.raises(ConflictError, match="notes.txt"):
        check_destination(tmp_path / "b")


def test_the_lit_point_glb_has_normals_and_a_lit_material_and_validates(lit_points, tmp_path, gltf_validator):
    data = impostor_glb(lit_points)
    path = tmp_path / "points.glb"
    path.write_bytes(data)
    (report,) = gltf_validator.validate([path])
    assert report.get("errors") == 0 and report.get("warnings") == 0, report
    document = glb_json(data)
    assert document["extensionsUsed"] == [POINT_APPEARANCE]  # no unlit material
    (material,) = document["materials"]
    assert "extensions" not in material
    assert material["pbrMetallicRoughness"]["metallicFactor"] == 0.0
    assert material["pbrMetallicRoughness"]["roughnessFactor"] == 1.0
    (primitive,) = document["meshes"][0]["primitives"]
    assert primitive["mode"] == 0 and "NORMAL" in primitive["attributes"]
    accessor = document["accessors"][primitive["attributes"]["NORMAL"]]
    view = document["bufferViews"][accessor["bufferView"]]
    start = 20 + ((len(json.dumps(document, separators=(",", ":"))) + 3) // 4) * 4  # after the JSON chunk
    binary = data[start + 8 :]
    stored = np.frombuffer(binary, "<f4", accessor["count"] * 3, view["byteOffset"]).reshape(-1, 3)
    assert np.allclose(stored, lit_points.payload.normal, atol=1e-6)


def test_the_lit_ldi_glb_lights_its_fallback_quad_and_validates(lit_ldi, tmp_path, gltf_validator):
    data = impostor_glb(lit_ldi)
    path = tmp_path / "ldi.glb"
    path.write_bytes(data)
    (report,) = gltf_validator.validate([path])
    assert report.get("errors") == 0 and report.get("warnings") == 0, report
    document = glb_json(data)
    assert "extensionsUsed" not in document
    (material,) = document["materials"]
    assert material["normalTexture"]["index"] == 1 and "extensions" not in material
    (primitive,) = document["meshes"][0]["primitives"]
    assert {"NORMAL", "TANGENT"} <= set(primitive["attributes"])


@pytest.mark.parametrize("name", ["points", "ldi"])
def test_the_lit_evaluation_meets_the_normal_and_flat_card_targets_on_a_smooth_sphere(name, lit_points, lit_ldi):
    """Measured on llvmpipe (resolution 96, 10 viewpoints): points median 3.1°, interior p95 6.6°,
    flat/lit ≥ 3.1, lit error ≤ 3.3 levels; LDI 1.9°, 3.7°, ≥ 4.7, ≤ 2.5.  The sphere is one colour,
    so its unlit error is 0 and the lit error is the normals' (and the silhouettes') alone."""
    impostor = {"points": lit_points, "ldi": lit_ldi}[name]
    t = evaluate_lit(sphere(), impostor, random_count=1).totals
    print(name, json.dumps(t, indent=1))
    assert t["normal_error_median"] <= 5.0 and t["normal_error_interior_p95"] <= {"points": 10.0, "ldi": 6.0}[name]
    assert t["flat_normal_error_median"] > 30.0  # sprites face the viewer, the sphere does not
    assert t["flat_to_lit_least"] >= {"points": 2.5, "ldi": 3.5}[name]
    assert all(row["lit_error_mean"] <= {"points": 4.0, "ldi": 3.0}[name] for row in t["lights"])


@pytest.mark.parametrize("bake, options", [(bake_points, PointOptions(**POINTS)), (bake_ldi, LdiOptions(**LDI))], ids=["points", "ldi"])  # fmt: skip
def test_without_normals_points_and_samples_are_lit_as_sprites_facing_the_viewer(bake, options):
    impostor = bake(sphere(), CELL, options)
    t = evaluate_lit(sphere(), impostor, random_count=0).totals
    assert t["normal_error_median"] == pytest.approx(t["flat_normal_error_median"])
    assert t["flat_to_lit_least"] == pytest.approx(1.0)


def reference_camera(impostor, resolution: int) -> Camera:
    return Camera.look_at(impostor.reference_viewpoint, CENTRE, math.radians(impostor.fov_deg), resolution, 5.0, 15.0)


def test_three_js_draws_the_points_normals_and_lights_them_as_the_lit_evaluation(lit_points, tmp_path, threejs):
    """three.js's GLTFLoader reads the points' NORMAL; by itself three.js draws glTF points unlit
    (a PointsMaterial), so the harness gives them its MeshStandardMaterial (three.js's own BRDF)
    as one-pixel points (tests/js/render.mjs).  At the baked resolution from the reference
    viewpoint farfield's G-buffer draws each point on the same pixel, so the two agree pixel by pixel."""
    from threejs import decode_normals as three_normals

    from farfield.core.quality.lighting import AMBIENT, default_lights, shade, view_directions

    path = tmp_path / "points.glb"
    path.write_bytes(impostor_glb(lit_points))
    camera = reference_camera(lit_points, lit_points.resolution)
    with impostor_gbuffer(lit_points) as renderer:
        image, normals = renderer.render_normals(camera)
    (three,) = threejs.render(path, [camera], output="normal")
    both = (image[..., 3] > 0) & (three[..., 3] > 0)
    assert both.sum() > 0.9 * (image[..., 3] > 0).sum() > 300  # the sphere, 24 pixels across
    error = angles(normals[both], three_normals(three)[both])
    print("normal angle", np.median(error), np.percentile(error, 95), (error < 0.5).mean())
    # Most pixels show the same point; where two points' depths are within float32 rounding, a
    # neighbour (its normal a few degrees off on a sphere 24 pixels across) can win instead.
    assert (error < 0.5).mean() > 0.75 and np.percentile(error, 95) <= 6.0
    for light in default_lights():
        (lit,) = threejs.render(path, [camera], lights=[light], ambient=AMBIENT)
        mine = shade(image[..., :3], normals, view_directions(camera), light, AMBIENT)
        difference = np.abs(mine.astype(int) - lit[..., :3].astype(int)).max(axis=-1)[both]
        print("lit", light.direction.round(2), difference.mean(), np.percentile(difference, 99))
        assert difference.mean() <= 1.0 and np.percentile(difference, 99) <= 12, light


def test_three_js_reads_the_ldi_quads_normal_texture_as_farfield_draws_it(lit_ldi, tmp_path, threejs):
    """The LDI's GLB fallback (its first layer on the image quad) lit by its normal page in the
    quad's tangent space: three.js's normals match farfield's G-buffer of the same quad."""
    from threejs import decode_normals as three_normals

    from farfield.core.ldi.pages import preview_objects
    from farfield.core.render.raster import MeshRenderer

    path = tmp_path / "ldi.glb"
    path.write_bytes(impostor_glb(lit_ldi))
    camera = replace(reference_camera(lit_ldi, 128), fov=math.radians(15.0))  # the sphere fills the frame
    with MeshRenderer(preview_objects(lit_ldi), normals=True, normal_maps=lit_ldi.channels["normal"][:1]) as renderer:
        image, normals = renderer.render_normals(camera)
    (three,) = threejs.render(path, [camera], mipmaps=False, output="normal")
    both = (image[..., 3] > 0) & (three[..., 3] > 0)
    assert both.sum() > 2000
    error = angles(normals[both], three_normals(three)[both])
    print("normal angle", np.median(error), np.percentile(error, 95))
    assert np.median(error) <= 0.5 and np.percentile(error, 95) <= 2.0
    # and they are the sphere's: the quad's first layer is the front of the sphere
    assert np.median(angles(normals[both], np.array([0.0, 0.0, -1.0]))) < 60.0


MATERIAL = "albedo+normal+material"


def metal_sphere():
    """The sphere as glossy part-metal (metallic 0.7, roughness 0.35)."""
    from farfield.core.scene import Scene

    (ball,) = sphere().objects
    return Scene((replace(ball, metallic_factor=0.7, roughness_factor=0.35),), "metal sphere")


@pytest.mark.parametrize("bake, options", [(bake_points, PointOptions(**POINTS)), (bake_ldi, LdiOptions(**LDI))], ids=["points", "ldi"])  # fmt: skip
def test_the_lit_evaluation_shades_points_and_ldi_samples_with_their_own_material(bake, options):
    """End to end, as the layered test of tests/test_material_channels.py: the points' material
    arrays and the LDI's material pages are what the G-buffer draws ("kept"), within a few levels of
    the lit source; the same bake without them is shaded matte, far off.  Measured (llvmpipe,
    worst light, the 9 corner and reference viewpoints at 96 px): points 4.4 kept, 66 matte; LDI 3.2 kept,
    65 matte.  The glossy sphere shows the normals' error more than the matte one above does."""
    scene = metal_sphere()
    figures = {}
    for channels in ("albedo+normal", MATERIAL):
        impostor = bake(scene, CELL, replace(options, channels=channels))
        figures[channels] = evaluate_lit(scene, impostor, random_count=0).totals
    kept, matte = figures[MATERIAL], figures["albedo+normal"]
    assert kept["source_material"] and kept["impostor_material"] == "kept" and matte["impostor_material"] == "matte"
    assert kept["roughness_error_mean"] < 0.01 and kept["metallic_error_mean"] < 0.01
    worst = {k: max(row["lit_error_mean"] for row in t["lights"]) for k, t in figures.items()}
    print(worst)
    assert worst[MATERIAL] < 6.0 and worst[MATERIAL] * 8.0 < worst["albedo+normal"], worst


def test_point_and_splat_material_g_buffers_keep_mesh_renderers_contract():
    """``render_material`` of points and splats: each element's ORM bytes / 255 and its sRGB
    emission decoded to linear light on its pixels, zero where nothing is drawn, the image and
    normals those of ``render_normals``; a splat pin hole takes its neighbours' mean."""
    from farfield.core.colour_space import srgb_to_linear
    from farfield.core.render.points import PointRenderer
    from farfield.core.render.splats import SplatRenderer

    camera = Camera.look_at(np.zeros(3), CENTRE, math.radians(20.0), 64, 5.0, 15.0)
    rng = np.random.default_rng(5)
    positions = CENTRE + rng.uniform(-1.0, 1.0, (400, 3)) * [1.0, 1.0, 0.0]
    colours = np.full((400, 4), 200, np.uint8)
    orm = rng.integers(0, 256, (400, 4), dtype=np.uint8)
    light = rng.integers(0, 256, (400, 4), dtype=np.uint8)
    normals = np.tile([0.0, 0.0, -1.0], (400, 1))
    with PointRenderer(positions, colours, gbuffer=True, normals=normals, materials=orm, emissive=light) as points:
        assert points.materials
        image, normal, material = points.render_material(camera)
        ids = points.render_ids(camera)
        again, normal_again = points.render_normals(camera)
    assert material.shape == (64, 64, 6) and material.dtype == np.float32
    assert np.array_equal(image, again) and np.array_equal(normal, normal_again)
    drawn = ids >= 0
    assert drawn.sum() > 300 and np.array_equal(drawn, image[..., 3] > 0)
    assert np.allclose(material[drawn, :3], orm[ids[drawn], :3] / 255.0, atol=1e-6)
    assert np.allclose(material[drawn, 3:], srgb_to_linear(light[ids[drawn], :3] / 255.0), atol=1e-5)
    assert not material[~drawn].any()
    with PointRenderer(positions, colours, gbuffer=True, materials=orm) as dark:  # no emission: zero
        assert not dark.render_material(camera)[2][..., 3:].any()
    with pytest.raises(ValueError, match="G-buffer"):
        PointRenderer(positions, colours, materials=orm)
    # Splats: one ORM everywhere but a sparse grid that leaves pin holes for the 3x3 pass.
    grid = np.stack(np.meshgrid(np.linspace(-0.5, 0.5, 12), np.linspace(-0.5, 0.5, 12)), -1).reshape(-1, 2)
    at = CENTRE + np.c_[grid, np.zeros(len(grid))]
    same = np.tile([200, 100, 50, 255], (len(at), 1)).astype(np.uint8)
    splats = (at, np.full((len(at), 4), 200, np.uint8), np.full(len(at), 0.01))
    with SplatRenderer([], splats=splats, gbuffer=True, materials=(same, None)) as drawer:
        image, normal, material = drawer.render_material(camera)
        raw = drawer.render_raw(camera)
    filled = (image[..., 3] > 0) & (raw[..., 3] == 0)
    assert filled.any()  # pin holes were filled, with their neighbours' material
    covered = image[..., 3] > 0
    assert np.allclose(material[covered, :3], [200 / 255, 100 / 255, 50 / 255], atol=1e-6)
    assert not material[~covered].any() and not material[..., 3:].any()


@pytest.mark.parametrize("bake, options", [(bake_points, PointOptions(**POINTS)), (bake_ldi, LdiOptions(**LDI))], ids=["points", "ldi"])  # fmt: skip
def test_the_g_buffer_of_an_emitting_bake_draws_each_elements_material_and_emission(bake, options):
    (ball,) = metal_sphere().objects
    from farfield.core.scene import Scene

    glowing = Scene((replace(ball, emissive_factor=np.array([0.5, 0.2, 0.0])),), "glowing sphere")
    impostor = bake(glowing, CELL, replace(options, channels=MATERIAL))
    with impostor.payload.gbuffer(impostor) as renderer:
        assert renderer.materials
        image, _, material = renderer.render_material(reference_camera(impostor, impostor.resolution))
    covered = image[..., 3] > 0
    assert covered.sum() > 200  # the sphere, about 20 pixels across
    assert np.allclose(material[covered, :3], [1.0, 0.35, 0.7], atol=1.0 / 255)  # ORM bytes / 255
    assert np.allclose(material[covered, 3:], [0.5, 0.2, 0.0], atol=0.004)  # sRGB bytes, decoded
    assert not material[~covered].any()
