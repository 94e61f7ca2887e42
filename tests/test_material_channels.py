"""The material channels of a lit impostor (channels ``albedo+normal+material``): glTF's ORM packing
(occlusion, roughness, metallic) and the emission recorded per texel, kept as pages, in bundles and
GLBs, and the Toksvig roughness of a normal map's footprint."""

from __future__ import annotations

import json
import struct
from dataclasses import replace

import numpy as np
import pytest

from farfield.core.impostor.bundle import read_bundle, write_bundle
from farfield.core.impostor.glb import impostor_glb
from farfield.core.layering.recording import material_uv_source
from farfield.core.scene import Scene, SceneObject
from farfield.core.techniques.envmap.technique import EnvmapOptions, bake_envmap
from farfield.core.techniques.layered import BakeOptions, bake_layered
from farfield.core.viewcells import BoxCell

CELL = BoxCell([-0.1, -0.1, -0.1], [0.1, 0.1, 0.1])
MATERIAL = "albedo+normal+material"


def quad(name="q", x0=-1.0, x1=1.0, **fields) -> SceneObject:
    """A square at z = 10 facing the cell (normal -z), uv 0..1 across it (u along x, v along y)."""
    vertices = np.array([[x0, -1.0, 10.0], [x1, -1.0, 10.0], [x1, 1.0, 10.0], [x0, 1.0, 10.0]])
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    return SceneObject(name, vertices, np.array([[0, 2, 1], [0, 3, 2]]), uv=uv,
                       normals=np.tile([0.0, 0.0, -1.0], (4, 1)), **fields)  # fmt: skip


def bake(objects, channels=MATERIAL, resolution=32):
    return bake_layered(Scene(tuple(objects), "q"), CELL, BakeOptions(resolution=resolution, channels=channels))


def covered(impostor, channel: str) -> np.ndarray:
    """(n, 4) uint8 texels of the channel's first page where the colour is covered."""
    return impostor.channels[channel][0][impostor.pages[0][..., 3] > 0]


def halves(left, right, size: int = 64) -> np.ndarray:
    """(size, size, 4) uint8 texture: its left half (u < 0.5) one RGBA, its right half another."""
    texture = np.empty((size, size, 4), dtype=np.uint8)
    texture[:, : size // 2], texture[:, size // 2 :] = left, right
    return texture


def near(texels: np.ndarray, value, tolerance: int = 3) -> np.ndarray:
    """(n,) bool: the texels (n, 4) within ``tolerance`` of ``value`` in every channel."""
    return (np.abs(texels.astype(int) - np.asarray(value)) <= tolerance).all(axis=1)


def test_constant_materials_record_their_factors_and_emission_only_where_an_object_emits():
    shiny = quad(metallic_factor=0.25, roughness_factor=0.5)
    impostor = bake([shiny])
    assert sorted(impostor.channels) == ["material", "normal"]  # nothing emits: no emissive page
    assert np.unique(covered(impostor, "material"), axis=0).tolist() == [[255, 128, 64, 255]]
    assert set(impostor.stats["channel_bytes"]) == {"albedo", "normal", "material"}

    glowing = replace(shiny, emissive_factor=np.array([0.5, 0.2, 0.0]))
    plain = quad("plain", x0=1.0, x1=3.0)  # no material: the defaults, occlusion 1, roughness 1, metallic 0
    impostor = bake([glowing, plain])
    assert sorted(impostor.channels) == ["emissive", "material", "normal"]
    page, colour = impostor.channels["material"][0], impostor.pages[0]
    rows = colour[..., 3] > 0
    orm = {tuple(t) for t in page[rows].tolist()}
    assert orm == {(255, 128, 64, 255), (255, 255, 0, 255)}
    emission = {tuple(t) for t in impostor.channels["emissive"][0][rows].tolist()}
    # Linear 0.5, 0.2 sRGB-encoded; the plain quad emits nothing.
    assert emission == {(188, 124, 0, 255), (0, 0, 0, 255)}


def test_textured_materials_are_read_at_the_material_uv_with_their_factors_and_strength():
    left, right = (0, 200, 100, 255), (0, 50, 250, 255)  # G roughness, B metallic
    material = dict(
        metallic_factor=0.8,
        roughness_factor=1.0,
        metallic_roughness_texture=halves(left, right),
        occlusion_texture=halves((100, 0, 0, 255), (255, 0, 0, 255)),
        occlusion_strength=0.5,
        emissive_factor=np.array([1.0, 1.0, 1.0]),
        emissive_texture=halves((255, 0, 0, 255), (0, 0, 255, 255)),
    )
    obj = quad(**material, material_uv=quad().uv)
    impostor = bake([obj])
    orm, emissive = covered(impostor, "material"), covered(impostor, "emissive")
    # occlusion 1 + 0.5 (R - 1): 100 -> 0.696 (177.5), 255 -> 1; roughness G; metallic B x 0.8; the
    # emission red on the left, blue on the right (factor 1).  The atlas may turn a tile, so the
    # halves are told apart by their values; texels on the seam and the wrapped border blend.
    left_texels, right_texels = near(orm, (177, 200, 80, 255)), near(orm, (255, 50, 200, 255))
    assert left_texels.sum() >= 8 and right_texels.sum() >= 8 and (left_texels | right_texels).mean() > 0.5
    assert near(emissive[left_texels], (255, 0, 0, 255)).all() and near(emissive[right_texels], (0, 0, 255, 255)).all()

    # A material uv of its own (no base-colour texture: it takes the uv's place): mirrored, the halves swap.
    mirrored = quad().uv * [-1.0, 1.0] + [1.0, 0.0]
    swapped = replace(obj, material_uv=mirrored)
    assert material_uv_source(swapped) == "uv slot"
    other = covered(bake([swapped]), "material")
    assert near(other[left_texels], (255, 50, 200, 255)).mean() > 0.9
    assert near(other[right_texels], (177, 200, 80, 255)).mean() > 0.9


def test_a_material_uv_the_recording_cannot_carry_is_warned_of_and_read_at_the_base_uv():
    textured = quad(
        texture=np.full((2, 2, 4), 255, np.uint8),
        metallic_roughness_texture=halves((0, 200, 0, 255), (0, 50, 0, 255)),
        material_uv=quad().uv[::-1].copy(),
    )
    assert material_uv_source(textured) == "fallback"
    with pytest.warns(UserWarning, match="material textures are read at the base-colour uv"):
        impostor = bake([textured])
    assert "material" in impostor.channels


def test_other_channel_sets_are_untouched_by_the_material():
    """The colour and normal pages of a material bake are those of the albedo+normal bake, and a
    colour-only bake keeps no channel."""
    obj = quad(metallic_factor=1.0, roughness_factor=0.3, emissive_factor=np.array([0.2, 0.2, 0.2]))
    lit, full = bake([obj], "albedo+normal"), bake([obj])
    assert sorted(lit.channels) == ["normal"]
    assert all(np.array_equal(a, b) for a, b in zip(lit.pages, full.pages))
    assert all(np.array_equal(a, b) for a, b in zip(lit.channels["normal"], full.channels["normal"]))
    assert bake([obj], "albedo").channels == {}


def glb_json(data: bytes) -> dict:
    length = struct.unpack_from("<I", data, 12)[0]
    return json.loads(data[20 : 20 + length])


@pytest.fixture(scope="module")
def emitting():
    obj = quad(
        metallic_factor=0.5,
        roughness_factor=0.4,
        occlusion_texture=halves((100, 0, 0, 255), (255, 0, 0, 255)),
        material_uv=quad().uv,
        emissive_factor=np.array([0.3, 0.6, 0.9]),
    )
    return bake([obj, quad("plain", x0=1.0, x1=3.0)])


def test_the_bundle_keeps_the_material_and_emissive_pages_bit_for_bit(emitting, tmp_path):
    paths = write_bundle(emitting, tmp_path / "b")
    manifest = json.loads(paths.manifest.read_text())
    assert sorted(manifest["channels"]) == ["emissive", "material", "normal"]
    assert (paths.directory / "material-000.png").is_file() and (paths.directory / "emissive-000.png").is_file()
    back = read_bundle(paths.directory)
    for name in ("material", "emissive"):
        assert all(np.array_equal(a, b) for a, b in zip(back.channels[name], emitting.channels[name]))


def test_the_glb_lights_its_pages_with_the_orm_and_emissive_textures_and_validates(emitting, tmp_path, gltf_validator):
    data = impostor_glb(emitting)
    path = tmp_path / "material.glb"
    path.write_bytes(data)
    (report,) = gltf_validator.validate([path])
    assert report.get("errors") == 0 and report.get("warnings") == 0, report
    document = glb_json(data)
    names = [image["name"] for image in document["images"]]
    for material in document["materials"]:
        pbr = material["pbrMetallicRoughness"]
        orm = pbr["metallicRoughnessTexture"]["index"]
        assert material["occlusionTexture"]["index"] == orm and names[orm].startswith("material-")
        assert pbr["metallicFactor"] == 1.0 and pbr["roughnessFactor"] == 1.0
        assert names[material["emissiveTexture"]["index"]].startswith("emissive-")
        assert material["emissiveFactor"] == [1.0, 1.0, 1.0]
    # Without emission, no emissive texture.
    plain = bake([quad(roughness_factor=0.5)])
    for material in glb_json(impostor_glb(plain))["materials"]:
        assert "metallicRoughnessTexture" in material["pbrMetallicRoughness"] and "emissiveTexture" not in material


def test_an_envmap_records_the_material_channels_too():
    obj = quad(metallic_factor=0.25, roughness_factor=0.5, emissive_factor=np.array([0.5, 0.2, 0.0]))
    impostor = bake_envmap(Scene((obj,), "q"), CELL, EnvmapOptions(resolution=16, channels=MATERIAL))
    assert sorted(impostor.channels) == ["emissive", "material", "normal"]
    rows = impostor.pages[0][..., 3] > 0
    assert {tuple(t) for t in impostor.channels["material"][0][rows].tolist()} == {(255, 128, 64, 255)}
