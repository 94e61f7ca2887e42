"""Materials on the source side: the glTF loader reads the metallic-roughness material, the
G-buffer draws it per pixel, the lighting applies occlusion (ambient only) and emission, and the
lit evaluation shades the source and the impostor with what each has; three.js lights the helmet
as farfield shades its G-buffer."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from gltf_files import SQUARE_UV, GltfBuilder, gradient

from farfield.core.colour_space import srgb_to_linear
from farfield.core.exchange import load_scene
from farfield.core.quality.lighting import AMBIENT, DirectionalLight, default_lights, radiance, shade, view_directions
from farfield.core.quality.lit import evaluate_lit_views, lit_text
from farfield.core.render.raster import Camera, MeshRenderer
from farfield.core.scene import SceneObject

pytestmark = pytest.mark.filterwarnings("ignore::farfield.core.scene.SceneWarning")

HELMET = Path(__file__).resolve().parents[2] / "shared" / "scenes" / "damaged_helmet" / "DamagedHelmet.glb"
needs_helmet = pytest.mark.skipif(not HELMET.is_file(), reason=f"needs the shared scene {HELMET}")


def orm(occlusion: int, roughness: int, metallic: int, size: int = 4) -> np.ndarray:
    """(size, size, 4) uint8 one-texel-colour ORM image (R occlusion, G roughness, B metallic)."""
    image = np.empty((size, size, 4), dtype=np.uint8)
    image[...] = (occlusion, roughness, metallic, 255)
    return image


def halves(left, right, size: int = 8) -> np.ndarray:
    """(size, size, 4) uint8: ``left`` RGBA on the image's left half, ``right`` on its right."""
    image = np.empty((size, size, 4), dtype=np.uint8)
    image[:, : size // 2] = left
    image[:, size // 2 :] = right
    return image


def load(path: Path):
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = load_scene(path)
    return {o.name: o for o in scene.objects}, [str(w.message) for w in caught]


def test_the_gltf_loader_reads_factors_textures_strengths_and_the_specifications_defaults(tmp_path):
    b = GltfBuilder()
    packed = b.texture(b.image(halves((100, 200, 50, 255), (255, 100, 250, 255))))  # ORM, left | right
    glow = b.texture(b.image(halves((255, 0, 0, 255), (0, 0, 255, 255))))  # emissive (sRGB)
    full = b.material(texture=b.texture(b.image(gradient())))
    pbr = b.doc["materials"][full]["pbrMetallicRoughness"]
    pbr.update(metallicFactor=0.5, roughnessFactor=0.8, metallicRoughnessTexture={"index": packed})
    b.doc["materials"][full].update(
        occlusionTexture={"index": packed, "strength": 0.5},
        emissiveTexture={"index": glow},
        emissiveFactor=[1.0, 0.5, 0.25],
        extensions={"KHR_materials_emissive_strength": {"emissiveStrength": 4.0}},
    )
    b.used.add("KHR_materials_emissive_strength")
    factors = b.material()
    del b.doc["materials"][factors]["pbrMetallicRoughness"]["metallicFactor"]  # the default, 1
    b.doc["materials"][factors]["pbrMetallicRoughness"]["roughnessFactor"] = 0.25
    b.quad("full", [0, 0, 0], 1.0, full, uv=SQUARE_UV)
    b.quad("factors", [2, 0, 0], 1.0, factors, uv=SQUARE_UV)
    square = b.accessor(np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0.0]]) + [4, 0, 0], bounds=True)
    b.node(name="default", mesh=b.mesh([{"attributes": {"POSITION": square}}]))  # no material at all
    objects, warnings = load(b.write(tmp_path / "materials.glb"))
    assert warnings == []
    full = objects["full"]
    assert (full.metallic_factor, full.roughness_factor, full.occlusion_strength) == (0.5, 0.8, 0.5)
    assert full.emissive_factor.tolist() == [4.0, 2.0, 1.0]  # emissiveFactor x emissiveStrength
    assert full.metallic_roughness_texture is full.occlusion_texture  # one ORM image, decoded once
    assert full.metallic_roughness_texture[0, 0].tolist() == [100, 200, 50, 255]
    assert full.emissive_texture[0, -1].tolist() == [0, 0, 255, 255]
    assert full.material_uv is full.uv  # the textures map as the base colour would
    plain = objects["factors"]
    assert (plain.metallic_factor, plain.roughness_factor, plain.emissive_factor.tolist()) == (1.0, 0.25, [0, 0, 0])
    assert plain.material_uv is None and plain.occlusion_texture is None
    default = objects["default"]  # glTF's default material: metallic 1, roughness 1
    assert (default.metallic_factor, default.roughness_factor) == (1.0, 1.0)


def test_an_unlit_material_is_read_as_matte_not_as_the_default_metal(tmp_path):
    """KHR_materials_unlit: the author wants the base colour as it is; without metallicFactor the
    specification's default would make it metal (dark under ambient light alone)."""
    b = GltfBuilder()
    flat = b.material()
    del b.doc["materials"][flat]["pbrMetallicRoughness"]["metallicFactor"]
    b.doc["materials"][flat]["extensions"] = {"KHR_materials_unlit": {}}
    b.used.add("KHR_materials_unlit")
    b.quad("flat", [0, 0, 0], 1.0, flat, uv=SQUARE_UV)
    objects, _ = load(b.write(tmp_path / "unlit.glb"))
    assert (objects["flat"].metallic_factor, objects["flat"].roughness_factor) == (0.0, 1.0)


def test_tex_coord_and_transform_are_applied_and_a_texture_on_other_coordinates_is_dropped_with_one_warning(
    tmp_path,
):
    b = GltfBuilder()
    packed = b.texture(b.image(halves((0, 255, 255, 255), (255, 0, 0, 255))))
    glow = b.texture(b.image(halves((255, 255, 255, 255), (0, 0, 0, 255))))
    moved = {"offset": [0.5, 0.0], "scale": [0.5, 1.0]}
    material = b.material()
    b.doc["materials"][material]["pbrMetallicRoughness"]["metallicRoughnessTexture"] = {
        "index": packed,
        "texCoord": 1,
        "extensions": {"KHR_texture_transform": moved},
    }
    b.doc["materials"][material].update(
        occlusionTexture={"index": packed, "texCoord": 1, "extensions": {"KHR_texture_transform": moved}},
        emissiveTexture={"index": glow},  # TEXCOORD_0: not the material uv
        emissiveFactor=[1.0, 1.0, 1.0],
    )
    b.used.add("KHR_texture_transform")
    b.quad("q", [0, 0, 0], 1.0, material, uv=SQUARE_UV, uv1=SQUARE_UV)
    b.quad("r", [2, 0, 0], 1.0, material, uv=SQUARE_UV, uv1=SQUARE_UV)
    objects, warnings = load(b.write(tmp_path / "coordinates.glb"))
    q = objects["q"]
    assert q.emissive_texture is None and q.emissive_factor.tolist() == [1.0, 1.0, 1.0]  # factor kept
    dropped = [w for w in warnings if "emissive_texture" in w]
    assert len(dropped) == 1, warnings  # one warning for the material, not one per object
    # TEXCOORD_1 scaled by 0.5 and offset by 0.5 in u: the right half of the image, then v flipped
    expected = np.column_stack([0.5 + 0.5 * SQUARE_UV[:, 0], 1.0 - SQUARE_UV[:, 1]])
    assert np.allclose(q.material_uv, expected)
    assert q.uv is None  # no base-colour texture


@pytest.mark.invalid_glb  # written broken on purpose
@pytest.mark.parametrize("case", ["missing_texture", "missing_set", "bad_factor"])
def test_bad_material_inputs_warn_and_never_refuse_the_file(tmp_path, case):
    b = GltfBuilder()
    material = b.material()
    pbr = b.doc["materials"][material]["pbrMetallicRoughness"]
    if case == "missing_texture":
        pbr["metallicRoughnessTexture"] = {"index": 9}
    elif case == "missing_set":
        pbr["metallicRoughnessTexture"] = {"index": b.texture(b.image(orm(255, 128, 0))), "texCoord": 3}
    else:
        pbr["roughnessFactor"] = 1.5
    b.quad("q", [0, 0, 0], 1.0, material, uv=SQUARE_UV)
    objects, warnings = load(b.write(tmp_path / f"{case}.glb"))
    assert len(warnings) == 1, warnings
    q = objects["q"]
    assert q.metallic_roughness_texture is None
    assert q.roughness_factor == 1.0


def test_a_transmissive_glass_material_is_drawn_opaque_with_one_warning(tmp_path):
    """KHR_materials_transmission (a window pane) is not drawn: the pane hides the room behind it,
    which three.js shows, so the loader says so once per material (none at the default factor 0)."""
    b = GltfBuilder()
    glass = b.material(
        color=(0.9, 0.95, 1.0, 1.0), extensions={"KHR_materials_transmission": {"transmissionFactor": 1}}
    )
    b.doc["materials"][glass]["name"] = "glass"
    default = b.material(extensions={"KHR_materials_transmission": {}})
    b.used.add("KHR_materials_transmission")
    b.quad("pane", [0, 0, 0], 1.0, glass)
    b.quad("pane2", [2, 0, 0], 1.0, glass)
    b.quad("wall", [0, 0, -1], 3.0, default)
    objects, warnings = load(b.write(tmp_path / "glass.glb"))
    assert len(warnings) == 1 and "'glass'" in warnings[0] and "KHR_materials_transmission" in warnings[0], warnings
    assert objects["pane"].alpha_cutoff is None and objects["pane"].base_color[3] == 1.0


QUAD_OBJ = """mtllib q.mtl
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
vn 0 0 1
usemtl steel
f 1/1/1 2/2/1 3/3/1
f 1/1/1 3/3/1 4/4/1
"""


def test_the_obj_loader_reads_the_pbr_extension_of_mtl_composing_scalar_maps_into_one_image(tmp_path):
    import PIL.Image

    (tmp_path / "q.obj").write_text(QUAD_OBJ)
    (tmp_path / "q.mtl").write_text(
        "newmtl steel\nKd 1 1 1\nmap_Kd base.png\nPr 0.5\nmap_Pr rough.png\nmap_Pm -imfchan r metal.png\n"
        "Ke 0.5 0.25 1\nmap_Ke glow.png\n"
    )
    PIL.Image.fromarray(gradient()[..., :3]).save(tmp_path / "base.png")
    PIL.Image.fromarray(np.full((4, 4), 128, np.uint8)).save(tmp_path / "rough.png")
    PIL.Image.fromarray(np.full((4, 4, 3), [200, 0, 0], np.uint8)).save(tmp_path / "metal.png")
    PIL.Image.fromarray(halves((255, 255, 255, 255), (0, 0, 0, 255), 4)[..., :3]).save(tmp_path / "glow.png")
    objects, warnings = load(tmp_path / "q.obj")
    assert warnings == []
    (quad,) = objects.values()
    assert (quad.roughness_factor, quad.metallic_factor) == (0.5, 1.0)  # Pm defaults to 1 beside its map
    assert quad.metallic_roughness_texture[0, 0].tolist() == [255, 128, 200, 255]  # G rough, B metal (-imfchan r)
    assert quad.emissive_factor.tolist() == [0.5, 0.25, 1.0]
    assert quad.emissive_texture[0, :, 0].tolist() == [255, 255, 0, 0]
    assert quad.material_uv is quad.uv
    (tmp_path / "q.mtl").write_text("newmtl steel\nKd 1 1 1\nmap_Pr missing.png\n")
    objects, warnings = load(tmp_path / "q.obj")
    (quad,) = objects.values()
    assert quad.metallic_roughness_texture is None and len(warnings) == 1 and "missing.png" in warnings[0]
    assert (quad.roughness_factor, quad.metallic_factor) == (1.0, 0.0)  # the matte default


def _camera(resolution: int = 64) -> Camera:
    return Camera.look_at([2.0, 0.0, 7.0], [2.0, 0.0, 0.0], math.radians(50.0), resolution, 0.1, 20.0)


def material_quads() -> list[SceneObject]:
    """A quad with ORM (left half: occlusion 100/255, roughness 200/255, metallic 50/255; right
    half other values) and emissive textures, and a quad of plain factors."""
    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0.0]])
    f = np.array([[0, 1, 2], [0, 2, 3]])
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1.0]])
    up = np.tile([0.0, 0.0, 1.0], (4, 1))
    textured = SceneObject(
        "textured", v, f, uv=uv, normals=up, base_color=(0.8, 0.8, 0.8, 1.0),
        metallic_factor=1.0, roughness_factor=0.5, occlusion_strength=0.5,
        metallic_roughness_texture=halves((100, 200, 50, 255), (255, 20, 255, 255)),
        occlusion_texture=halves((100, 200, 50, 255), (255, 20, 255, 255)),
        emissive_factor=(0.5, 0.25, 1.0), emissive_texture=halves((188, 188, 188, 255), (0, 0, 0, 255)),
        material_uv=uv,
    )  # fmt: skip
    plain = SceneObject("plain", v + [3.0, 0, 0], f, normals=up, metallic_factor=0.3, roughness_factor=0.6)
    return [textured, plain]


def test_the_material_g_buffer_gives_occlusion_roughness_metallic_and_linear_emission_per_pixel():
    camera = _camera()
    with MeshRenderer(material_quads(), normals=True, materials=True) as renderer:
        image, normals, material = renderer.render_material(camera)
    with MeshRenderer(material_quads(), normals=True) as plain:
        image_plain, normals_plain = plain.render_normals(camera)
    assert (image == image_plain).all() and (normals == normals_plain).all()  # the material adds only
    left = camera.project(np.array([[-0.5, 0.0, 0.0]]))[0].astype(int)
    right = camera.project(np.array([[0.5, 0.0, 0.0]]))[0].astype(int)
    other = camera.project(np.array([[3.0, 0.0, 0.0]]))[0].astype(int)
    grey = srgb_to_linear(np.array([188 / 255.0]))[0]
    expected_left = [1 + 0.5 * (100 / 255 - 1), 0.5 * 200 / 255, 50 / 255, 0.5 * grey, 0.25 * grey, grey]
    assert np.allclose(material[left[1], left[0]], expected_left, atol=2e-3)
    assert np.allclose(material[right[1], right[0]], [1.0, 0.5 * 20 / 255, 1.0, 0, 0, 0], atol=2e-3)
    assert np.allclose(material[other[1], other[0]], [1.0, 0.6, 0.3, 0, 0, 0], atol=1e-6)  # factors only
    assert (material[image[..., 3] == 0] == 0).all()
    with pytest.raises(ValueError):
        MeshRenderer(material_quads(), materials=True)


def test_occlusion_darkens_the_ambient_term_only_and_emission_is_added():
    """A hand computation: occlusion multiplies three.js's indirect diffuse term (the ambient one)
    and nothing else; emission adds to the radiance, unlit."""
    n = np.array([[[0.0, 0.0, 1.0]]])
    grey = np.full((1, 1, 3), 180, np.uint8)
    light = DirectionalLight(np.array([0.0, 0.6, 0.8]), np.ones(3), 2.0)
    ambient_only = radiance(grey, n, n, DirectionalLight(-n[0, 0], np.ones(3), 1.0), AMBIENT)
    direct_only = radiance(grey, n, n, light, np.zeros(3))
    both = radiance(grey, n, n, light, AMBIENT, occlusion=np.array([[0.25]]), emissive=np.array([0.1, 0.2, 0.3]))
    assert np.allclose(both, direct_only + 0.25 * ambient_only + [0.1, 0.2, 0.3])
    # without occlusion or emission the result is what it was, bit for bit
    assert (radiance(grey, n, n, light, AMBIENT) == radiance(grey, n, n, light, AMBIENT, 1.0, 0.0, 0.0)).all()
    assert (shade(grey, n, n, light, occlusion=1.0, emissive=np.zeros(3)) == shade(grey, n, n, light)).all()
    # a metal lit by ambient alone stays black whatever its occlusion; emission shows through
    black = radiance(grey, n, n, DirectionalLight(-n[0, 0], np.ones(3), 1.0), AMBIENT, metallic=1.0, occlusion=0.5)
    assert np.allclose(black, 0.0)


def test_the_lit_evaluation_shades_source_and_impostor_with_their_materials_and_says_which():
    source = material_quads()
    # The impostor-like stand-in: the same quads with their material in ORM/emissive pages (factors 1)
    pages = []
    for obj in source:
        if obj.metallic_roughness_texture is None:
            pages.append(obj)
            continue
        page = obj.metallic_roughness_texture.copy()
        page[..., 1] = np.round(page[..., 1] * obj.roughness_factor)
        page[..., 2] = np.round(page[..., 2] * obj.metallic_factor)
        page[..., 0] = np.round(255 * (1 + obj.occlusion_strength * (page[..., 0] / 255.0 - 1)))
        pages.append(
            replace(obj, metallic_factor=1.0, roughness_factor=1.0, occlusion_strength=1.0,
                    metallic_roughness_texture=page, occlusion_texture=page)
        )  # fmt: skip
    camera = _camera(96)
    lights = default_lights((0.0, 0.0, 1.0))[:2]
    # the impostor-like quads drawn as a payload's gbuffer draws them, with and without their material
    with (
        MeshRenderer(source, normals=True, materials=True) as geometry,
        MeshRenderer(pages, normals=True, materials=True) as kept,
        MeshRenderer(pages, normals=True) as matte,
    ):
        views = [(camera, {"kind": "corner"})]
        with_material = evaluate_lit_views(geometry, kept, matte, views, 1, lights)
        without = evaluate_lit_views(geometry, matte, matte, views, 1, lights)
    t, u = with_material.totals, without.totals
    print(lit_text(with_material), lit_text(without), sep="\n")
    assert t["source_material"] and t["impostor_material"] == "kept" and u["impostor_material"] == "matte"
    assert t["roughness_error_mean"] < 0.01 and t["metallic_error_mean"] < 0.01 and t["occlusion_error_mean"] < 0.01
    assert u["metallic_error_mean"] > 0.3  # the metal half is drawn matte
    for kept_light, matte_light in zip(t["lights"], u["lights"], strict=True):
        assert kept_light["lit_error_mean"] < 1.0
        assert matte_light["lit_error_mean"] > 5.0 * max(kept_light["lit_error_mean"], 0.5)
    assert "impostor's kept" in lit_text(with_material) and "impostor's matte" in lit_text(without)


@needs_helmet
def test_the_helmet_keeps_its_material_and_draws_it_in_the_g_buffer():
    (helmet,) = load_scene(HELMET).objects
    assert helmet.metallic_roughness_texture.shape == (2048, 2048, 4)
    assert helmet.occlusion_texture.shape == (2048, 2048, 4) and helmet.emissive_texture is not None
    assert helmet.material_uv is helmet.uv and helmet.emissive_factor.tolist() == [1.0, 1.0, 1.0]
    centre = 0.5 * (helmet.bounds[0] + helmet.bounds[1])
    camera = Camera.look_at(centre + [0.0, 0.0, 4.0], centre, math.radians(40.0), 64, 0.5, 10.0)
    with MeshRenderer([helmet], normals=True, materials=True) as renderer:
        image, _, material = renderer.render_material(camera)
    covered = image[..., 3] > 0
    assert covered.sum() > 1000
    values = material[covered]
    assert 0.0 <= values[:, :3].min() and values[:, :3].max() <= 1.0
    assert values[:, 2].max() > 0.5 and values[:, 2].min() < 0.2  # metal and not
    assert values[:, 0].min() < 0.6  # occluded crevices
    assert (values[:, 3:].max(axis=1) > 0.1).sum() > 10  # the visor's glowing parts


@needs_helmet
def test_three_js_lights_the_helmets_material_as_farfield_shades_its_g_buffer(threejs):
    """three.js (GLTFLoader's MeshStandardMaterial with metalnessMap, roughnessMap, aoMap, emissiveMap)
    against farfield's material G-buffer of the helmet shaded by :func:`shade`, under two test lights;
    base colour unmipmapped on both sides (``mipmaps=False``, as farfield draws it), the material and
    normal maps mipmapped on both.  three.js's geometryRoughness is taken from the unmapped normals.

    Bounds (llvmpipe against SwiftShader, 128 px): mean <= 4 levels and 95th percentile <= 12 away
    from silhouettes and creases, median <= 2 over every pixel both draw; the helmet's glossy metal
    makes the shading sensitive to which mip level each rasteriser picks (farfield's own G-buffer,
    mipmapped against not, differs by 6.9 levels on average from the side view), measured 1.3-3.2
    levels.  Shaded as the matte default instead, the same pixels are 42-72 levels off."""
    from farfield.core.quality.lighting import geometry_roughness

    (helmet,) = load_scene(HELMET).objects
    centre = 0.5 * (helmet.bounds[0] + helmet.bounds[1])
    cameras = [
        Camera.look_at(centre + offset, centre, math.radians(40.0), 128, 0.5, 10.0)
        for offset in ([0.0, 0.0, 3.2], [2.4, 0.8, 2.0])
    ]
    unmapped = replace(helmet, normal_texture=None, normal_uv=None, tangents=None)
    with (
        MeshRenderer([helmet], normals=True, materials=True) as renderer,
        MeshRenderer([unmapped], normals=True) as smooth,
    ):
        ours = [renderer.render_material(camera) for camera in cameras]
        rough = [geometry_roughness(smooth.render_normals(camera)[1], camera) for camera in cameras]
    for light in default_lights()[1:3]:
        theirs = threejs.render(HELMET, cameras, mipmaps=False, lights=[light], ambient=AMBIENT)
        for camera, (image, normals, material), extra, three in zip(cameras, ours, rough, theirs, strict=True):
            both = (image[..., 3] > 0) & (three[..., 3] > 0)
            # Away from silhouettes and creases: there the two rasterisers' edges, and three.js's
            # geometryRoughness (screen-space derivatives of the normal), differ pixel by pixel.
            inner = both & (extra < 0.25)
            for axis in (0, 1):
                inner &= np.roll(both, 1, axis) & np.roll(both, -1, axis)
            mine = shade(
                image[..., :3], normals, view_directions(camera), light, AMBIENT,
                roughness=material[..., 1], metallic=material[..., 2], geometry_roughness=extra,
                occlusion=material[..., 0], emissive=material[..., 3:6],
            )  # fmt: skip
            difference = np.abs(mine.astype(int) - three[..., :3].astype(int)).max(axis=-1)[inner]
            matte = shade(image[..., :3], normals, view_directions(camera), light, AMBIENT, geometry_roughness=extra)
            matte_difference = np.abs(matte.astype(int) - three[..., :3].astype(int)).max(axis=-1)[inner]
            everywhere = np.abs(mine.astype(int) - three[..., :3].astype(int)).max(axis=-1)[both]
            print(
                "helmet lit", light.direction.round(2), inner.sum(), both.sum(), difference.mean(),
                np.median(difference), np.percentile(difference, 95), "all covered", everywhere.mean(),
                np.median(everywhere), "matte", matte_difference.mean(),
            )  # fmt: skip
            assert inner.sum() > 3000
            assert difference.mean() <= 4.0 and np.percentile(difference, 95) <= 12
            assert np.median(everywhere) <= 2
            assert matte_difference.mean() > 10.0 * difference.mean()  # the material is what matches


def test_a_scene_glb_written_by_farfield_loads_back_with_its_material(tmp_path):
    from farfield.core.exchange.export import scene_glb
    from farfield.core.scene import Scene

    source = Scene.from_objects(material_quads(), source="materials")
    path = tmp_path / "written.glb"
    path.write_bytes(scene_glb(source))
    back = {o.name: o for o in load_scene(path).objects}
    textured, plain = back["textured"], back["plain"]
    assert (textured.metallic_factor, textured.roughness_factor) == (1.0, 0.5)
    assert (
        textured.metallic_roughness_texture[..., 1:3] == material_quads()[0].metallic_roughness_texture[..., 1:3]
    ).all()
    # occlusion strength 0.5 baked into the image: 1 + 0.5 (100/255 - 1) = 0.696 -> 177.5 -> 178
    assert textured.occlusion_strength == 1.0 and textured.occlusion_texture[0, 0, 0] == 178
    assert np.allclose(textured.emissive_factor, [0.5, 0.25, 1.0]) and textured.emissive_texture is not None
    assert (plain.metallic_factor, plain.roughness_factor) == (0.3, 0.6) and not plain.emissive_factor.any()
