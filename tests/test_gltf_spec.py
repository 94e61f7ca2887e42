"""farfield's glTF reader follows the glTF 2.0 specification (issue 54), checked on small files
built by ``tests/gltf_files.py`` (every one validator-clean: ``glb_files_are_valid`` in conftest).

trimesh's reader, which farfield used before, fails each of these: it repeats every texture,
ignores ``KHR_texture_transform`` and ``texCoord``, reads sparse accessors as zeros and
normalized integers as raw, names a mesh's second primitive with a random suffix, and keeps one
node of a node reached along two paths.  three.js draws the same files alike
(``tests/test_threejs.py``).
"""

from __future__ import annotations

import io
import json
import struct

import numpy as np
import PIL.Image
import pytest
from gltf_files import CLAMP, MIRROR, SHORT, SQUARE_UV, UBYTE, USHORT, GltfBuilder, gradient, sampler_scene

from farfield.core.errors import DegenerateGeometryError, SceneLoadError
from farfield.core.exchange import load_scene, load_scene_bytes
from farfield.core.scene import sample_texture


@pytest.fixture(scope="module")
def samplers(tmp_path_factory):
    path = sampler_scene(tmp_path_factory.mktemp("gltf") / "samplers.glb")
    scene = load_scene(path)
    return {obj.name: obj for obj in scene.objects}, scene


def _load(b: GltfBuilder, tmp_path, name: str):
    """The builder's file written where the validator fixture checks it, then loaded."""
    return load_scene(b.write(tmp_path / name))


def _texel(obj, uv_gltf):
    """The texel farfield's object shows at glTF uv ``uv_gltf`` of its original coordinates,
    found by interpolating the loaded uv over the quad's corners (uv are affine on a quad)."""
    corners = SQUARE_UV * 2.0 - 0.5 if obj.name in ("clamp", "mirror") else SQUARE_UV
    # barycentric on the first triangle (0, 1, 2) in the original uv, then the loaded uv there
    a, b, c = corners[[0, 1, 2]]
    m = np.column_stack([b - a, c - a])
    s, t = np.linalg.solve(m, np.asarray(uv_gltf, dtype=float) - a)
    loaded = obj.uv[0] + s * (obj.uv[1] - obj.uv[0]) + t * (obj.uv[2] - obj.uv[0])
    return sample_texture(obj.texture, loaded[None])[0]


def test_clamp_to_edge_gives_the_edge_texel_beyond_the_texture(samplers):
    objects, _ = samplers
    image = gradient()
    clamp = objects["clamp"]
    assert (_texel(clamp, [1.4, 0.5])[:3] == image[8, 15, :3]).all()  # beyond the right edge: the last column
    assert (_texel(clamp, [-0.4, -0.4])[:3] == image[0, 0, :3]).all()  # beyond the top-left corner
    assert (_texel(clamp, [0.53, 0.53])[:3] == image[8, 8, :3]).all()  # inside: as it is


def test_mirrored_repeat_reflects_the_texture_beyond_its_edge(samplers):
    objects, _ = samplers
    image = gradient()
    mirror = objects["mirror"]
    assert (_texel(mirror, [1.25, 0.53])[:3] == image[8, 11, :3]).all()  # u 1.25 reads u 0.75
    assert (_texel(mirror, [-0.25, 0.53])[:3] == image[8, 3, :3]).all()  # u -0.25 reads u 0.25
    assert (_texel(mirror, [0.53, 1.25])[:3] == image[11, 8, :3]).all()


def test_texture_transform_and_second_uv_set_are_applied(samplers):
    objects, _ = samplers
    moved = objects["transform"]
    c, s = np.cos(0.4), np.sin(0.4)
    u, v = 0.5 * 1.5, 0.5 * 0.75
    expected = np.array([c * u + s * v + 0.25, -s * u + c * v + 0.1])  # KHR_texture_transform at uv (0.5, 0.5)
    centre = 0.25 * moved.uv.sum(axis=0)
    assert np.allclose([centre[0], 1.0 - centre[1]], expected)
    second = objects["texcoord1"]
    assert np.allclose(np.sort(second.uv[:, 0]), [0, 0, 0.5, 0.5])  # TEXCOORD_1 (0..0.5), not TEXCOORD_0 (0.5)


def test_normalized_colours_quantized_positions_and_sparse_accessors_are_decoded(samplers):
    objects, _ = samplers
    colours = objects["colours"].vertex_colors
    assert colours[:, :3].tolist() == [[255, 0, 0], [0, 255, 0], [0, 0, 255], [255, 255, 0]]
    quantized = objects["quantized"]
    assert np.allclose(quantized.bounds, [[2.2, 1.1, 0.0], [3.2, 2.1, 0.0]])
    sparse = objects["sparse"]
    assert np.allclose(sparse.bounds, [[0.0, 2.2, 0.0], [1.0, 3.2, 0.0]], atol=1e-6)
    assert len(np.unique(sparse.vertices, axis=0)) == 4


def test_double_sided_follows_the_material_and_defaults_to_one_sided(tmp_path):
    b = GltfBuilder()
    b.quad("both", [0, 0, 0], 1.0, b.material(double_sided=True))
    b.quad("one", [2, 0, 0], 1.0, b.material(double_sided=False))
    b.quad("default", [4, 0, 0], 1.0, b._add("materials", {}))
    scene = _load(b, tmp_path, "sides.glb")
    sides = {obj.name: obj.double_sided for obj in scene.objects}
    assert sides == {"both": True, "one": False, "default": False}


def _triangle_mesh(b: GltfBuilder, mode: int, count: int) -> int:
    angles = np.linspace(0.0, np.pi, count)
    points = np.column_stack([np.cos(angles), np.sin(angles), np.zeros(count)])
    if mode == 5:  # a strip zig-zags between two rows
        points = np.column_stack([np.arange(count) // 2, 1 - np.arange(count) % 2, np.zeros(count)]).astype(float)
    position = b.accessor(points, bounds=True)
    return b.mesh([{"attributes": {"POSITION": position}, "mode": mode, "material": b.material()}])


def test_strips_and_fans_become_counter_clockwise_triangles(tmp_path):
    b = GltfBuilder()
    b.node(name="strip", mesh=_triangle_mesh(b, 5, 6))
    b.node(name="fan", mesh=_triangle_mesh(b, 6, 6), translation=[0.0, 3.0, 0.0])
    scene = _load(b, tmp_path, "topology.glb")
    for obj in scene.objects:
        assert obj.triangle_count == 4
        a, b_, c = (obj.vertices[obj.faces[:, k]] for k in range(3))
        normals = np.cross(b_ - a, c - a)
        assert (normals[:, 2] > 0).all(), obj.name  # every triangle faces +z, as glTF's winding rule says


def test_primitives_instances_and_gpu_instancing_get_stable_names(tmp_path):
    b = GltfBuilder()
    material = b.material()
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0]], dtype=float)
    prims = [
        {"attributes": {"POSITION": b.accessor(square + [0, k, 0], bounds=True)}, "material": material}
        for k in range(2)
    ]
    mesh = b.mesh(prims, name="pair")
    b.node(name="left", children=[b.node(root=False, name="leaf", mesh=mesh)])
    b.node(name="right", children=[b.node(root=False, name="leaf", mesh=mesh)], translation=[5.0, 0.0, 0.0])
    instanced = b.mesh([prims[0]])
    offsets = b.accessor(np.array([[0.0, 0, 10], [0, 0, 20], [0, 0, 30]]))
    b.node(
        name="grass", mesh=instanced, extensions={"EXT_mesh_gpu_instancing": {"attributes": {"TRANSLATION": offsets}}}
    )
    b.used.add("EXT_mesh_gpu_instancing")
    names = [_load(b, tmp_path, f"names{k}.glb").names for k in range(2)]
    assert names[0] == names[1]  # deterministic
    assert set(names[0]) == {"leaf.p0", "leaf.p1", "leaf.p0_1", "leaf.p1_1", "grass@0", "grass@1", "grass@2"}
    scene = _load(b, tmp_path, "names.glb")
    by_name = {obj.name: obj for obj in scene.objects}
    assert by_name["leaf.p0_1"].bounds[0][0] == pytest.approx(5.0)  # the second node's transform
    assert by_name["grass@2"].bounds[0][2] == pytest.approx(30.0)


def test_a_required_extension_farfield_does_not_read_is_refused_by_name(tmp_path):
    b = GltfBuilder()
    b.quad("q", [0, 0, 0], 1.0, b.material())
    b.used.add("KHR_draco_mesh_compression")
    b.required.add("KHR_draco_mesh_compression")
    with pytest.raises(SceneLoadError, match="KHR_draco_mesh_compression"):
        _load(b, tmp_path, "draco.glb")


def test_percent_encoded_uris_name_files_with_spaces(tmp_path):
    b = GltfBuilder()
    b.quad("q", [0, 0, 0], 1.0, b.material(texture=b.texture(b.image(gradient()))), uv=SQUARE_UV)
    document = b._document()
    (tmp_path / "my buffer.bin").write_bytes(bytes(b.blob))
    document["buffers"] = [{"uri": "my%20buffer.bin", "byteLength": len(b.blob)}]
    (tmp_path / "scene.gltf").write_text(json.dumps(document))
    scene = load_scene(tmp_path / "scene.gltf")
    assert scene.objects[0].colour_source == "texture"
    upload = load_scene_bytes((tmp_path / "scene.gltf").read_bytes(), "gltf", "scene.gltf",
                              {"my buffer.bin": bytes(b.blob)})  # fmt: skip
    assert upload.content_hash == scene.content_hash


def test_colour_components_of_every_kind_read_alike(tmp_path):
    b = GltfBuilder()
    material = b.material()
    linear = np.array([[1.0, 0.0, 0.0, 1.0], [0.0, 0.5, 0.0, 1.0], [0.0, 0.0, 0.25, 0.5], [1.0, 1.0, 1.0, 1.0]])
    for name, values, y in (("float", linear, 0), ("ubyte", np.round(linear * 255).astype(np.uint8), 2),
                            ("ushort", np.round(linear * 65535).astype(np.uint16), 4)):  # fmt: skip
        b.quad(name, [0, y, 0], 1.0, material, colours=values)
    scene = _load(b, tmp_path, "colours.glb")
    colours = {obj.name: obj.vertex_colors.astype(int) for obj in scene.objects}
    assert np.abs(colours["ubyte"] - colours["float"]).max() <= 1
    assert np.abs(colours["ushort"] - colours["float"]).max() <= 1
    assert colours["float"][1].tolist() == [0, 188, 0, 255]  # linear 0.5 is sRGB 188


@pytest.mark.parametrize("component", [UBYTE, USHORT, SHORT])
def test_quantized_texture_coordinates_are_normalized(component, tmp_path):
    b = GltfBuilder()
    top = np.iinfo({UBYTE: np.uint8, USHORT: np.uint16, SHORT: np.int16}[component]).max
    material = b.material(texture=b.texture(b.image(gradient()), (CLAMP, MIRROR)))
    uv = b.accessor(SQUARE_UV * top, component, normalized=True)
    position = b.accessor(np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=float), bounds=True)
    indices = b.accessor(np.array([0, 1, 2, 0, 2, 3]), USHORT, target=34963)
    b.node(
        name="q",
        mesh=b.mesh(
            [{"attributes": {"POSITION": position, "TEXCOORD_0": uv}, "indices": indices, "material": material}]
        ),
    )
    b.used.add("KHR_mesh_quantization")
    b.required.add("KHR_mesh_quantization")
    (obj,) = _load(b, tmp_path, "uv.glb").objects
    assert obj.colour_source == "texture"
    centre = sample_texture(obj.texture, obj.uv.mean(axis=0)[None])[0]
    assert abs(int(centre[0]) - int(gradient()[8, 8, 0])) <= 16


def _quad_document() -> tuple[dict, bytes]:
    b = GltfBuilder()
    b.quad("q", [0, 0, 0], 1.0, b.material(texture=b.texture(b.image(gradient()), (CLAMP, CLAMP))), uv=SQUARE_UV)
    return b._document(), bytes(b.blob)


def _glb(document: dict, blob: bytes) -> bytes:
    """A GLB of ``document`` (any JSON, however malformed) over ``blob``."""
    text = json.dumps({**document, "buffers": [{"byteLength": len(blob)}]}).encode()
    text += b" " * (-len(text) % 4)
    blob += b"\0" * (-len(blob) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(blob), 0x004E4942) + blob
    return b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body


HOSTILE = {
    "accessor without a view, 10^12 elements": lambda d: d["accessors"].append({"componentType": 5126, "count": 10**12, "type": "VEC3"})
    or d["meshes"][0]["primitives"][0]["attributes"].update(POSITION=len(d["accessors"]) - 1),
    "sparse byteOffset not a number": lambda d: d["accessors"][0].update(
        sparse={"count": 1, "indices": {"bufferView": 0, "componentType": 5123, "byteOffset": "x"}, "values": {"bufferView": 0}}
    ),
    "wrapS a list": lambda d: d["samplers"][0].update(wrapS=[1]),
    "extensionsRequired holds a list": lambda d: d.update(extensionsRequired=[[1]]),
    "indices of floats": lambda d: d["meshes"][0]["primitives"][0].update(indices=0),
    "empty scenes over a cycle": lambda d: (
        d.update(scenes=[]),
        d.pop("scene"),
        d["nodes"].extend([{"children": [2]}, {"children": [1]}]),
        d["nodes"][0].update(children=[1]),
    ),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_malformed_files_are_refused_with_a_scene_error_not_a_crash(case):
    """Found by an independent review of the reader (each raised TypeError, ValueError, MemoryError
    or OverflowError, or hung, before): a clear scene error, at once (an empty scene list draws
    nothing: no triangles)."""
    document, blob = _quad_document()
    HOSTILE[case](document)
    with pytest.raises((SceneLoadError, DegenerateGeometryError)):
        load_scene_bytes(_glb(document, blob), "glb", "hostile.glb")


def test_a_node_whose_children_are_not_an_array_has_none():
    document, blob = _quad_document()
    document.pop("scenes"), document.pop("scene"), document["nodes"][0].update(children=5)
    assert load_scene_bytes(_glb(document, blob), "glb", "children.glb").names == ("q",)


def test_infinite_uv_under_a_clamping_sampler_is_a_scene_error():
    document, blob = _quad_document()
    uv = np.frombuffer(blob, dtype=np.uint8).copy()
    view = document["bufferViews"][
        document["accessors"][document["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"]]["bufferView"]
    ]
    floats = uv[view["byteOffset"] : view["byteOffset"] + view["byteLength"]].view(np.float32)
    floats[0] = np.inf
    uv[view["byteOffset"] : view["byteOffset"] + view["byteLength"]] = floats.view(np.uint8)
    with pytest.raises(SceneLoadError, match="non-finite"):
        load_scene_bytes(_glb(document, uv.tobytes()), "glb", "inf.glb")


def test_specular_glossiness_is_drawn_even_beside_metallic_roughness(tmp_path):
    """KHR_materials_pbrSpecularGlossiness, "Best practices": a client that reads it renders it."""
    b = GltfBuilder()
    material = b.material(
        color=(1.0, 0.0, 0.0, 1.0),
        extensions={"KHR_materials_pbrSpecularGlossiness": {"diffuseFactor": [0.0, 0.0, 1.0, 1.0]}},
    )
    b.used.add("KHR_materials_pbrSpecularGlossiness")
    b.quad("q", [0, 0, 0], 1.0, material)
    (obj,) = _load(b, tmp_path, "gloss.glb").objects
    assert obj.base_color.tolist() == [0.0, 0.0, 1.0, 1.0]


def test_gpu_instancing_with_only_custom_attributes_draws_identity_instances(tmp_path):
    b = GltfBuilder()
    mesh = b.mesh(
        [
            {
                "attributes": {"POSITION": b.accessor(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), bounds=True)},
                "material": b.material(),
            }
        ]
    )
    ids = b.accessor(np.arange(3, dtype=np.float32))
    b.node(name="tuft", mesh=mesh, extensions={"EXT_mesh_gpu_instancing": {"attributes": {"_ID": ids}}})
    b.used.add("EXT_mesh_gpu_instancing")
    scene = _load(b, tmp_path, "ids.glb")
    assert scene.names == ("tuft@0", "tuft@1", "tuft@2")


def test_clamped_objects_of_one_image_share_a_few_padded_copies(tmp_path):
    """Padding comes in powers of two texels, so 40 quads whose uv reach past the edge by 40
    different amounts share a few copies of the image, not 40."""
    b = GltfBuilder()
    material = b.material(texture=b.texture(b.image(gradient(64)), (CLAMP, CLAMP)))
    for k in range(40):
        b.quad(f"q{k:02d}", [2.0 * k, 0, 0], 1.0, material, uv=SQUARE_UV * (1.0 + 0.05 * k))
    scene = _load(b, tmp_path, "copies.glb")
    assert len({id(obj.texture) for obj in scene.objects}) <= 8


def test_a_16_bit_greyscale_png_is_scaled_to_8_bits_and_its_trns_grey_cut(tmp_path):
    """A 16-bit greyscale PNG (Pillow's mode ``I;16``) reads as v / 257 (the PNG specification's
    scaling, as browsers decode it), not clipped at 255 (everything but black was white), and its
    ``tRNS`` grey value is transparent under alphaMode MASK."""
    wide = np.array([[0, 0x1234, 0x4000, 0x8080, 0xC000, 0xFFFF]] * 2, dtype=np.uint16)
    data = io.BytesIO()
    PIL.Image.fromarray(wide).save(data, format="PNG", transparency=0x1234)
    b = GltfBuilder()
    image = b._add("images", {"bufferView": b.view(data.getvalue()), "mimeType": "image/png"})
    b.quad("grey", [0, 0, 0], 1.0, b.material(texture=b.texture(image), alphaMode="MASK"), uv=SQUARE_UV)
    (obj,) = _load(b, tmp_path, "grey16.glb").objects
    expected = np.round(wide / 257.0).astype(np.uint8)
    np.testing.assert_array_equal(obj.texture[..., 0], expected)
    np.testing.assert_array_equal(obj.texture[..., 2], expected)
    np.testing.assert_array_equal(obj.texture[..., 3], np.where(wide == 0x1234, 0, 255))
    assert obj.alpha_cutoff == 0.5
