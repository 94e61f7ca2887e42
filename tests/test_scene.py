"""Scene model and loaders: real scenes, procedural round trips, colour sources, and every bad input."""

from __future__ import annotations

import dataclasses
import json
import warnings

import numpy as np
import PIL.Image
import pytest
import scenes  # tests/ is on sys.path under pytest's default (prepend) import mode
import trimesh

from farfield.core.colour_space import srgb_to_linear
from farfield.core.errors import DegenerateGeometryError, ErrorKind, SceneLoadError, SceneNotFoundError
from farfield.core.exchange import load_scene, load_scene_bytes, supported_extensions
from farfield.core.scene import Scene, SceneObject, SceneWarning, sample_texture

# --------------------------------------------------------------------------- real scenes


@pytest.mark.parametrize("real", scenes.REAL_SCENES, ids=lambda r: r.path.split("/")[-1])
def test_real_scene_triangles_and_size(real):
    scene = scenes.real_scene(real.path)
    assert scene.triangle_count == real.triangles
    assert sum(obj.triangle_count for obj in scene.objects) == real.triangles
    np.testing.assert_allclose(scene.extents, real.size, atol=real.atol)
    assert scene.warnings == ()
    assert scene.source == real.path.split("/")[-1]


@pytest.mark.parametrize(
    ("path", "sources", "texture_shape"),
    [
        ("duck/duck.obj", {"LOD3sp_LOD3spShape": "texture"}, (512, 512, 4)),
        ("damaged_helmet/DamagedHelmet.glb", {"node_damagedHelmet_-6514": "texture"}, (2048, 2048, 4)),
        ("stanford_bunny/bun_zipper.ply", {"bun_zipper": "material"}, None),
        ("scrub_pine/scrubPine.obj", {"SoftPine2": "texture", "SoftPineBark": "texture"}, None),
    ],
)
def test_real_scene_objects_and_colour_sources(path, sources, texture_shape):
    scene = scenes.real_scene(path)
    assert {obj.name: obj.colour_source for obj in scene.objects} == sources
    for obj in scene.objects:
        if texture_shape is not None:
            assert obj.texture.shape == texture_shape
        if obj.texture is not None:
            assert obj.uv.shape == (len(obj.vertices), 2)


def test_scrub_pine_leaf_cards_are_alpha_cut_and_bark_is_opaque():
    scene = scenes.real_scene("scrub_pine/scrubPine.obj")
    leaves, bark = scene.subset(["SoftPine2"]).objects[0], scene.subset(["SoftPineBark"]).objects[0]
    assert leaves.alpha_cutoff == 0.5
    assert leaves.texture[..., 3].min() < 128  # transparent texels around the needles
    assert bark.alpha_cutoff is None
    assert leaves.triangle_count + bark.triangle_count == 527


def test_duck_textured_obj_multiplies_kd_into_its_texture():
    duck = scenes.real_scene("duck/duck.obj").objects[0]
    # The MTL says Kd 0.64 and map_Kd: the MTL specification (and three.js) multiply them, in linear light.
    np.testing.assert_allclose(
        duck.base_color, [*srgb_to_linear(np.full(3, 163 / 255)), 1.0]
    )  # Kd as trimesh keeps it, in bytes
    assert duck.alpha_cutoff is None
    # The yellow duck: the texels its uv land on are mostly yellow (red and green over blue).
    texels = sample_texture(duck.texture, duck.uv).astype(float)
    assert np.median(texels[:, 0]) > np.median(texels[:, 2]) and np.median(texels[:, 1]) > np.median(texels[:, 2])


def test_same_file_twice_and_from_bytes_give_the_same_hash():
    path = scenes.SHARED_SCENES / "duck" / "duck.obj"
    first, second = load_scene(path), load_scene(str(path))
    assert first.content_hash == second.content_hash
    assets = {name: (path.parent / name).read_bytes() for name in ("duck.mtl", "duckCM.png")}
    uploaded = load_scene_bytes(path.read_bytes(), ".OBJ", "duck.obj", assets=assets)
    assert uploaded.content_hash == first.content_hash
    assert uploaded.names == first.names


def test_same_content_at_another_path_has_the_same_hash(tmp_path):
    original = scenes.SHARED_SCENES / "stanford_bunny" / "bun_zipper.ply"
    copy = tmp_path / "renamed.ply"
    copy.write_bytes(original.read_bytes())
    moved = load_scene(copy)
    assert moved.content_hash == scenes.real_scene("stanford_bunny/bun_zipper.ply").content_hash
    assert moved.names == ("renamed",)


def test_obj_bytes_without_their_assets_warn_and_lose_the_texture():
    path = scenes.SHARED_SCENES / "duck" / "duck.obj"
    with pytest.warns(SceneWarning, match="duck.mtl"):
        scene = load_scene_bytes(path.read_bytes(), "obj", "duck.obj")
    assert scene.objects[0].colour_source == "material"
    assert any("duck.mtl" in message for message in scene.warnings)
    assert scene.content_hash != scenes.real_scene("duck/duck.obj").content_hash


# --------------------------------------------------------------------------- procedural scenes


@pytest.mark.parametrize(
    ("make", "objects", "triangles", "colours"),
    [
        (scenes.city, 301, 301 * 12 - 10, {"material"}),
        (scenes.forest, 200, 200 * 32, {"vertex"}),
        (scenes.sphere_field, 100, 100 * 320, {"texture", "material"}),
        (scenes.dense_mesh, 1, 81_920, {"material"}),
    ],
    ids=["city", "forest", "spheres", "dense"],
)
def test_procedural_scenes_are_deterministic(make, objects, triangles, colours):
    scene = make()
    assert scene.object_count == objects
    assert scene.triangle_count == triangles
    assert {obj.colour_source for obj in scene.objects} == colours
    assert make().content_hash == scene.content_hash
    assert make(seed=99).content_hash != scene.content_hash


def test_multi_object_glb_keeps_names_triangles_and_colours(tmp_path):
    city = scenes.city(buildings=40)
    loaded = load_scene(scenes.write_scene(city, tmp_path, "glb"))
    assert sorted(loaded.names) == sorted(city.names)
    by_name = {obj.name: obj for obj in loaded.objects}
    for original in city.objects:
        obj = by_name[original.name]
        assert obj.triangle_count == original.triangle_count
        np.testing.assert_allclose(obj.vertices, original.vertices, rtol=1e-6)  # GLB stores float32
        assert obj.colour_source == "material"
        np.testing.assert_allclose(obj.base_color, original.base_color, atol=1 / 255)  # trimesh: uint8


def test_glb_vertex_colours_survive(tmp_path):
    forest = scenes.forest(trees=5)
    loaded = load_scene(scenes.write_scene(forest, tmp_path, "glb"))
    for original, obj in zip(forest.objects, loaded.objects):
        assert obj.name == original.name and obj.colour_source == "vertex"
        # COLOR_0 is linear in glTF and stored as bytes: back within that quantisation.
        np.testing.assert_allclose(obj.vertex_colors, original.vertex_colors, atol=2)


def test_multi_object_obj_keeps_names_and_triangles(tmp_path):
    spheres = scenes.sphere_field(spheres=6)
    loaded = load_scene(scenes.write_scene(spheres, tmp_path, "obj"))
    assert loaded.names == spheres.names
    for original, obj in zip(spheres.objects, loaded.objects):
        assert obj.triangle_count == original.triangle_count
        assert obj.colour_source == original.colour_source
        np.testing.assert_allclose(obj.bounds, original.bounds, rtol=1e-12)


# OBJ files without vt and vn, in the shapes trimesh's reader groups differently: objects, materials
# (several, one, undefined), groups, no o at all, quads, n-gons, a concave polygon, mixed corner
# counts, unused and shared vertices, vertex colours.
NO_UV_MTL = "newmtl red\nKd 1 0 0\nnewmtl blue\nKd 0 0 1\nd 0.5\n"
NO_UV_OBJS = {
    "objects and materials": "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nv 9 9 9\no a\nusemtl red\n"
    "f 1 2 3\nusemtl blue\nf 2 4 3\no b\nv 0 0 1\nv 1 0 1\nv 0 1 1\nusemtl red\nf 6 7 8\nf 1 6 2\no c\nusemtl nope\nf 3 4 8\n",
    "no o, one material": "mtllib m.mtl\nusemtl blue\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 4 3\n",
    "groups, quads and n-gons": "v 0 0 0\nv 2 0 0\nv 2 2 0\nv 1 1 0\nv 0 2 0\nv 0 0 3\nv 1 0 3\nv 1 1 3\nv 0 1 3\n"
    "g one\nf 1 2 3 4 5\ng two\nf 6 7 8 9\nf 6 8 9\no tail\nf 1 6 9 5\n",
    "vertex colours": "o a\nv 0 0 0 1 0 0\nv 1 0 0 0 1 0\nv 0 1 0 0 0 1\nv 5 5 5 1 1 1\no b\nv 0 0 2 1 1 0\nv 1 0 2 0 1 1\n"
    "v 0 1 2 1 0 1\nf 5 6 7\no a2\nf 1 2 3\n",
    "CR LF lines": "mtllib m.mtl\r\nv 0 0 0\r\nv 1 0 0\r\nv 0 1 0\r\nv 1 1 0\r\no a\r\nusemtl red\r\nf 1 2 3\r\n"
    "o b\r\nusemtl blue\r\nf 2 4 3\r\n",
}


def _texts_parsed(monkeypatch) -> list:
    """The OBJ texts handed to trimesh's parser from now on (a spy: the parser still runs)."""
    import farfield.core.exchange.obj as obj_loader

    given = []
    parse = obj_loader.parse
    monkeypatch.setattr(obj_loader, "parse", lambda data, *a, **k: given.append(data) or parse(data, *a, **k))
    return given


def _assert_same_objects(now, before) -> None:
    """Every field of every object equal (arrays element by element), in order."""
    for a, b in zip(now.objects, before.objects):
        for field in dataclasses.fields(a):
            x, y = getattr(a, field.name), getattr(b, field.name)
            if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
                assert x is not None and y is not None and np.array_equal(x, y), (a.name, field.name)
            else:
                assert x == y, (a.name, field.name)


@pytest.mark.parametrize("name", list(NO_UV_OBJS))
def test_obj_without_uv_or_normals_loads_as_trimesh_read_it_and_on_the_linear_path(tmp_path, monkeypatch, name):
    """trimesh read each object of a file without vt/vn over all of the file's vertices (pieces x
    vertices: 16,000 objects 4.8 s); farfield now gives it the corners as ``i/i`` (its linear
    branch, core/exchange/obj_no_uv.py).  The scene is the one trimesh's own path gave, field by
    field, and the corners trimesh parses are the paired ones."""
    import farfield.core.exchange.obj as obj_loader
    import farfield.core.exchange.obj_no_uv as no_uv

    monkeypatch.setattr(no_uv, "PAIR_ABOVE", 0)  # paired however small the file (test_..._only_where_it_pays)
    (tmp_path / "m.mtl").write_text(NO_UV_MTL)
    path = tmp_path / "f.obj"
    path.write_bytes(NO_UV_OBJS[name].encode())
    given = _texts_parsed(monkeypatch)
    now = load_scene(path)
    assert b"\nf 1/1 2/2 " in given[-1] or b"\nf 1/1 6/6 " in given[-1] or b"\nf 5/5 6/6 7/7" in given[-1]
    monkeypatch.setattr(obj_loader, "paired_indices", lambda text: text)  # the faces as written: trimesh's path
    before = load_scene(path)
    assert b"/" not in given[-1]
    assert now.names == before.names and now.content_hash == before.content_hash
    _assert_same_objects(now, before)


MIXED_MTL = "newmtl tex\nKd 1 1 1\nmap_Kd t.png\nnewmtl red\nKd 1 0 0\n"
_MIXED_V = "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nv 0 0 1\nv 1 0 1\nv 0 1 1\nv 1 1 1\nv 9 9 9\n"
MIXED_OBJS = {
    "objects with and without vt": _MIXED_V + "vt 0 0\nvt 1 0\nvt 0 1\nvt 1 1\n"
    "o a\nusemtl tex\nf 1/1 2/2 4/4 3/3\no b\nusemtl tex\nf 5 6 8\nf 5 8 7\no c\nusemtl red\nf 2 6 8 4\n"
    "o d\nusemtl tex\nf 3/1 4/2 8/4\nf 3/1 8/4 7/3\n",
    "one object, a material of each kind": _MIXED_V + "vt 0 0\nvt 1 0\nvt 0 1\n"
    "o a\nusemtl tex\nf 1/1 2/2 3/3\nusemtl red\nf 5 6 7\nf 6 8 7\n",
    "CR LF lines": (_MIXED_V + "vt 0 0\nvt 1 0\nvt 0 1\no a\nusemtl tex\nf 1/1 2/2 3/3\no b\nf 4 5 6\n").replace(
        "\n", "\r\n"
    ),
}


@pytest.mark.parametrize("name", list(MIXED_OBJS))
def test_obj_mixing_objects_with_and_without_vt_loads_as_trimesh_read_it_and_on_the_linear_path(
    tmp_path, monkeypatch, name
):
    """Objects without vt in a file with vt kept trimesh's masks over all the file's vertices
    (pieces x vertices); their corners now reach it as ``i/K``, K past the last vt, its linear
    branch (core/exchange/obj_no_uv.py).  Geometry, uvs (none for the objects without vt: their
    texture is not sampled) and every other field are the ones trimesh's own path gave."""
    import farfield.core.exchange.obj as obj_loader
    import farfield.core.exchange.obj_no_uv as no_uv

    monkeypatch.setattr(no_uv, "PAIR_ABOVE", 0)  # paired however small the file
    (tmp_path / "m.mtl").write_text(MIXED_MTL)
    PIL.Image.fromarray(np.arange(4 * 4 * 3, dtype=np.uint8).reshape(4, 4, 3) * 5).save(tmp_path / "t.png")
    path = tmp_path / "f.obj"
    path.write_bytes(MIXED_OBJS[name].encode())
    given = _texts_parsed(monkeypatch)
    now = load_scene(path)
    plain = [line for line in MIXED_OBJS[name].replace("\r", "").split("\n") if line[:2] == "f " and "/" not in line]
    assert plain and not set(plain) & set(given[-1].decode().replace("\r", "").split("\n"))  # all written i/K
    monkeypatch.setattr(obj_loader, "paired_indices", lambda text: text)  # the faces as written: trimesh's path
    before = load_scene(path)
    assert set(plain) <= set(given[-1].decode().replace("\r", "").split("\n"))
    assert now.names == before.names and now.content_hash == before.content_hash
    assert any(o.uv is not None for o in now.objects) and any(o.uv is None for o in now.objects)
    _assert_same_objects(now, before)


def test_obj_with_a_piece_of_faces_with_and_without_vt_reaches_trimesh_as_written(tmp_path, monkeypatch):
    """trimesh reads a piece (an object's run of one material) holding both kinds as one without
    uvs, one vertex per v; ``i/K`` there would split its vertices by uv.  Such a file is left as written."""
    import farfield.core.exchange.obj_no_uv as no_uv

    monkeypatch.setattr(no_uv, "PAIR_ABOVE", 0)
    text = _MIXED_V + "vt 0 0\nvt 1 0\nvt 0 1\no a\nf 1/1 2/2 3/3\no b\nf 5 6 7\nf 6/1 8/2 7/3\n"
    assert no_uv.paired_indices(text) == text
    assert no_uv.paired_indices(text.replace("f 6/1 8/2 7/3", "f 6 8 7")) != text.replace("f 6/1 8/2 7/3", "f 6 8 7")


OBJ_PIECES_AS_TRIMESH_CUTS = {
    "o usemtl red": "o a\nusemtl red\nf 1 2 4\no usemtl red\nf 1/1 2/2 3/3\n",
    "o a usemtl red": "o a\nusemtl red\nf 1 2 4\no b\nf 5 6 7\no a usemtl red\nf 1/1 2/2 3/3\n",
    "nameless o twice": "o a\nf 1/1 2/2 3/3\no \nf 1 2 4\no b\nf 5/1 6/2 7/3\no \nf 1/1 2/2 3/3\n",
}


@pytest.mark.parametrize("name", list(OBJ_PIECES_AS_TRIMESH_CUTS))
def test_obj_pieces_are_the_ones_trimesh_cuts_where_o_lines_are_odd(tmp_path, monkeypatch, name):
    """trimesh starts a piece at ``usemtl `` anywhere, so an ``o`` line holding it names its object
    only up to there (``o usemtl red``: not at all, the object stays ``a``), and two nameless ``o``
    are one object.  In each file here a plain face and one with vt share a piece, which trimesh
    reads without uvs, one vertex per v.  Taken as two pieces (the whole line as the name, or each
    nameless ``o`` keeping the name before it), the plain face's corners were written ``i/K`` and
    trimesh split their shared vertices by uv (9 vertices where 6)."""
    import farfield.core.exchange.obj as obj_loader
    import farfield.core.exchange.obj_no_uv as no_uv

    monkeypatch.setattr(no_uv, "PAIR_ABOVE", 0)
    (tmp_path / "m.mtl").write_text(MIXED_MTL)
    path = tmp_path / "f.obj"
    path.write_text(_MIXED_V + "vt 0 0\nvt 1 0\nvt 0 1\n" + OBJ_PIECES_AS_TRIMESH_CUTS[name])
    now = load_scene(path)
    monkeypatch.setattr(obj_loader, "paired_indices", lambda text: text)  # the faces as written: trimesh's path
    before = load_scene(path)
    assert now.names == before.names and now.content_hash == before.content_hash
    for a, b in zip(now.objects, before.objects):
        assert a.vertices.shape == b.vertices.shape and np.array_equal(a.faces, b.faces), a.name


def _grid_obj(n: int, objects: int) -> str:
    """``objects`` objects, each an n x n grid of vertices in two triangles a cell, no vt/vn."""
    lines = []
    for k in range(objects):
        lines += [f"o part{k}", *(f"v {i + n * k} {j} 0" for i in range(n) for j in range(n))]
        base = 1 + n * n * k
        for a in (base + i * n + j for i in range(n - 1) for j in range(n - 1)):
            lines += [f"f {a} {a + n} {a + n + 1}", f"f {a} {a + n + 1} {a + 1}"]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(("objects", "paired"), [(1, False), (4, False), (900, True)])
def test_obj_without_uv_is_paired_only_where_it_pays(tmp_path, monkeypatch, objects, paired):
    """The pairing made a file of one large object without vt/vn (a scan, a terrain) 1.6x slower
    to load and 27% larger at its peak (2,000,000 triangles, docs/measurements/loading.md): trimesh's
    masks cost pieces x vertices, which is small there.  Such a file reaches trimesh as written;
    one of many small objects, where the masks are quadratic, paired."""

    path = tmp_path / "grid.obj"
    path.write_text(_grid_obj(40 if objects < 10 else 4, objects))
    given = _texts_parsed(monkeypatch)
    scene = load_scene(path)
    assert len(scene.objects) == objects
    assert (b"/" in given[-1]) == paired


@pytest.mark.parametrize("real", [r for r in scenes.REAL_SCENES if r.path.endswith(".obj")], ids=lambda r: r.path)
def test_shared_obj_scenes_load_as_before_the_pairing(monkeypatch, real):
    """The shared OBJ scenes have vt: the pairing leaves them to trimesh as they are."""
    import farfield.core.exchange.obj as obj_loader

    if not scenes.SHARED_SCENES.exists():
        pytest.skip("../shared/scenes is not beside the checkout")
    now = load_scene(scenes.SHARED_SCENES / real.path)
    monkeypatch.setattr(obj_loader, "paired_indices", lambda text: text)
    before = load_scene(scenes.SHARED_SCENES / real.path)
    assert now.names == before.names and now.content_hash == before.content_hash


@pytest.mark.parametrize("extension", ["ply", "stl"])
def test_single_mesh_formats_name_the_object_after_the_file(tmp_path, extension):
    dense = scenes.dense_mesh(subdivisions=4)
    loaded = load_scene(scenes.write_scene(dense, tmp_path, extension, stem="blob"))
    assert loaded.names == ("blob",)
    assert loaded.triangle_count == dense.triangle_count == 5120
    np.testing.assert_allclose(loaded.bounds, dense.bounds, rtol=1e-6)


def test_ply_vertex_colours(tmp_path):
    tree = scenes.forest(trees=1)
    loaded = load_scene(scenes.write_scene(tree, tmp_path, "ply"))
    assert loaded.objects[0].colour_source == "vertex"
    np.testing.assert_array_equal(loaded.objects[0].vertex_colors, tree.objects[0].vertex_colors)


def _box_mesh() -> trimesh.Trimesh:
    return trimesh.creation.box(extents=(1.0, 2.0, 4.0))


def _signed_volume(obj: SceneObject) -> float:
    corners = obj.vertices[obj.faces]
    return float(np.linalg.det(corners).sum() / 6.0)


def test_node_transforms_are_applied_in_world_space(tmp_path):
    rotation = trimesh.transformations.rotation_matrix(np.pi / 3, [0.0, 1.0, 0.0])
    moved = trimesh.transformations.translation_matrix([10.0, -5.0, 3.0]) @ rotation @ np.diag([2.0, 3.0, 0.5, 1.0])
    mirrored = trimesh.transformations.translation_matrix([-20.0, 0.0, 0.0]) @ np.diag([-1.0, 1.0, 1.0, 1.0])
    source = trimesh.Scene()
    source.add_geometry(_box_mesh(), geom_name="box", node_name="plain")
    source.add_geometry(_box_mesh(), geom_name="box", node_name="moved", transform=moved)  # an instance
    source.add_geometry(_box_mesh(), geom_name="box", node_name="mirrored", transform=mirrored)
    path = tmp_path / "transforms.glb"
    path.write_bytes(source.export(file_type="glb"))
    # The GLB must really carry the transform (not pre-baked vertices) for this test to mean anything.
    parsed = trimesh.load_scene(path)
    assert not np.allclose(parsed.graph["moved"][0], np.eye(4))

    scene = load_scene(path)
    assert scene.names == ("mirrored", "moved", "plain")
    local = np.asarray(_box_mesh().vertices)
    for name, matrix in [("plain", np.eye(4)), ("moved", moved), ("mirrored", mirrored)]:
        obj = scene.subset([name]).objects[0]
        np.testing.assert_allclose(obj.vertices, trimesh.transformations.transform_points(local, matrix), atol=1e-9)
        # Faces stay outward (positive volume) even under the mirroring transform.
        assert _signed_volume(obj) == pytest.approx(abs(np.linalg.det(matrix[:3, :3])) * 8.0)
    np.testing.assert_allclose(scene.bounds[0][0], -20.5)


# --------------------------------------------------------------------------- uv and texture convention


@pytest.mark.parametrize("extension", ["glb", "obj"])
def test_uv_convention_is_the_same_for_every_format(tmp_path, extension):
    quad = scenes.textured_quad(alpha_cutoff=0.5)
    loaded = load_scene(scenes.write_scene(quad, tmp_path, extension)).objects[0]
    np.testing.assert_array_equal(loaded.texture, scenes.QUAD_TEXTURE)
    np.testing.assert_allclose(loaded.uv, quad.objects[0].uv)
    corner_colours = sample_texture(loaded.texture, loaded.uv * 0.98 + 0.01)  # inside each corner texel
    # Vertex (0, 1, 0) with uv (0, 1) shows the top-left texel (red); (0, 0) the bottom-left (blue).
    np.testing.assert_array_equal(corner_colours[3], [255, 0, 0, 255])
    np.testing.assert_array_equal(corner_colours[0], [0, 0, 255, 255])
    np.testing.assert_array_equal(corner_colours[2], [0, 255, 0, 0])
    assert loaded.alpha_cutoff == 0.5


def test_gltf_alpha_mask_cutoff_is_kept(tmp_path):
    loaded = load_scene(scenes.write_scene(scenes.textured_quad(alpha_cutoff=0.3), tmp_path, "glb"))
    assert loaded.objects[0].alpha_cutoff == pytest.approx(0.3)
    opaque = load_scene(scenes.write_scene(scenes.textured_quad(), tmp_path, "glb", stem="opaque"))
    assert opaque.objects[0].alpha_cutoff is None  # glTF OPAQUE: texture alpha ignored


def test_obj_texture_with_alpha_is_cut_at_half_and_opaque_one_is_not(tmp_path):
    translucent = load_scene(scenes.write_scene(scenes.textured_quad(), tmp_path, "obj", stem="a"))
    assert translucent.objects[0].alpha_cutoff == 0.5
    opaque_texture = scenes.QUAD_TEXTURE.copy()
    opaque_texture[..., 3] = 255
    opaque = load_scene(scenes.write_scene(scenes.textured_quad(texture=opaque_texture), tmp_path, "obj", stem="b"))
    assert opaque.objects[0].alpha_cutoff is None


def test_obj_map_d_becomes_texture_alpha(tmp_path):
    opaque_texture = scenes.QUAD_TEXTURE.copy()
    opaque_texture[..., 3] = 255
    path = scenes.write_scene(scenes.textured_quad(texture=opaque_texture), tmp_path, "obj")
    mask = np.array([[255, 0], [255, 40]], dtype=np.uint8)
    PIL.Image.fromarray(mask, "L").save(tmp_path / "mask.png")
    with path.with_suffix(".mtl").open("a") as mtl:
        mtl.write("map_d mask.png\n")
    obj = load_scene(path).objects[0]
    assert obj.alpha_cutoff == 0.5
    np.testing.assert_array_equal(obj.texture[..., 3], mask)
    np.testing.assert_array_equal(obj.texture[..., :3], opaque_texture[..., :3])


def _atlas_obj(tmp_path, materials: int, map_d: bool = False):
    """Two-triangle quads, one per material, every material naming the same atlas (and mask)."""
    rng = np.random.default_rng(0)
    atlas = rng.integers(0, 256, size=(64, 32, 4), dtype=np.uint8)
    atlas[..., 3] = 255
    PIL.Image.fromarray(atlas, "RGBA").save(tmp_path / "atlas.png")
    mask = np.full((64, 32), 255, dtype=np.uint8)
    mask[:8] = 0
    PIL.Image.fromarray(mask, "L").save(tmp_path / "mask.png")
    lines, mtl = ["mtllib m.mtl"], []
    for k in range(materials):
        lines += [
            f"v {k} 0 0",
            f"v {k + 1} 0 0",
            f"v {k + 1} 1 0",
            f"v {k} 1 0",
            "vt 0 0",
            "vt 1 0",
            "vt 1 1",
            "vt 0 1",
        ]
    for k in range(materials):
        a = 4 * k + 1
        lines += [
            f"o part{k}",
            f"usemtl mat{k}",
            f"f {a}/{a} {a + 1}/{a + 1} {a + 2}/{a + 2}",
            f"f {a}/{a} {a + 2}/{a + 2} {a + 3}/{a + 3}",
        ]
        mtl += [f"newmtl mat{k}", "Kd 1 1 1", "map_Kd atlas.png"] + (["map_d mask.png"] if map_d else []) + [""]
    (tmp_path / "m.mtl").write_text("\n".join(mtl))
    (tmp_path / "scene.obj").write_text("\n".join(lines) + "\n")
    return tmp_path / "scene.obj", atlas, mask


@pytest.mark.parametrize("map_d", [False, True])
def test_obj_materials_naming_one_atlas_share_one_decoded_texture(tmp_path, map_d):
    """Issue 29: a texture file named by many materials is decoded once and every object holds that
    one array (before, 45 materials of one 4096^2 atlas took 92 s and 11 GB to load)."""
    path, atlas, mask = _atlas_obj(tmp_path, 5, map_d)
    scene = load_scene(path)
    assert scene.object_count == 5
    textures = [obj.texture for obj in scene.objects]
    assert all(t is textures[0] for t in textures)
    assert not textures[0].flags.writeable
    np.testing.assert_array_equal(textures[0][..., :3], atlas[..., :3])
    np.testing.assert_array_equal(textures[0][..., 3], mask if map_d else atlas[..., 3])
    assert {obj.alpha_cutoff for obj in scene.objects} == ({0.5} if map_d else {None})
    # Sharing changes nothing else: the scene is the one its objects give, and hashes alike.
    again = Scene.from_objects([dataclasses.replace(o, texture=o.texture.copy()) for o in scene.objects], "copy")
    assert again.content_hash == scene.content_hash
    assert all(o.texture is not textures[0] for o in again.objects)  # writable input is still copied


def test_scene_object_copies_a_writable_array_and_shares_a_frozen_one():
    quad = scenes.textured_quad().objects[0]
    texture = np.array(scenes.QUAD_TEXTURE)  # writable: the object must not see later changes
    obj = dataclasses.replace(quad, texture=texture)
    texture[...] = 0
    np.testing.assert_array_equal(obj.texture, scenes.QUAD_TEXTURE)
    assert dataclasses.replace(quad, texture=obj.texture).texture is obj.texture


# --------------------------------------------------------------------------- missing referenced files


def test_missing_obj_texture_warns_and_falls_back_to_material_colour(tmp_path):
    quad = scenes.textured_quad()
    coloured = dataclasses.replace(quad.objects[0], base_color=np.array([0.2, 0.4, 0.6, 1.0]))
    path = scenes.write_obj(Scene.from_objects([coloured], "quad"), tmp_path / "quad.obj", skip_textures=True)
    assert not (tmp_path / "quad.png").exists()
    with pytest.warns(SceneWarning, match=r"quad\.png"):
        scene = load_scene(path)
    obj = scene.objects[0]
    assert obj.colour_source == "material" and obj.texture is None and obj.alpha_cutoff is None
    np.testing.assert_allclose(obj.base_color, [0.2, 0.4, 0.6, 1.0], atol=1 / 255)
    assert len(scene.warnings) == 1 and "quad.png" in scene.warnings[0]
    assert scene.summary()["warnings"] == list(scene.warnings)


def test_missing_material_library_warns(tmp_path):
    path = scenes.write_scene(scenes.textured_quad(), tmp_path, "obj")
    path.with_suffix(".mtl").unlink()
    with pytest.warns(SceneWarning, match=r"scene\.mtl"):
        scene = load_scene(path)
    assert scene.objects[0].colour_source == "material"


def _external_image_gltf(tmp_path, write_image: bool):
    files = scenes.to_trimesh(scenes.textured_quad()).export(file_type="gltf")
    document = json.loads(files.pop("model.gltf"))
    document["images"] = [{"uri": "quad.png"}]
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    if write_image:
        (tmp_path / "quad.png").write_bytes(scenes.png_bytes(scenes.QUAD_TEXTURE))
    path = tmp_path / "quad.gltf"
    path.write_text(json.dumps(document))
    return path, files


def test_gltf_with_external_image(tmp_path):
    path, files = _external_image_gltf(tmp_path, write_image=True)
    scene = load_scene(path)
    np.testing.assert_array_equal(scene.objects[0].texture, scenes.QUAD_TEXTURE)
    assets = {**files, "quad.png": (tmp_path / "quad.png").read_bytes()}
    uploaded = load_scene_bytes(path.read_bytes(), "gltf", "quad.gltf", assets=assets)
    assert uploaded.content_hash == scene.content_hash


def test_gltf_missing_external_image_warns(tmp_path):
    path, _ = _external_image_gltf(tmp_path, write_image=False)
    with pytest.warns(SceneWarning, match=r"quad\.png"):
        scene = load_scene(path)
    assert scene.objects[0].colour_source == "material"


# --------------------------------------------------------------------------- bad input


def test_missing_file_is_not_found(tmp_path):
    with pytest.raises(SceneNotFoundError, match="nothing.glb") as caught:
        load_scene(tmp_path / "nothing.glb")
    assert caught.value.kind is ErrorKind.MISSING


@pytest.mark.parametrize("suffix", [".fbx", ".mtl", ""])
def test_unknown_extension_lists_the_supported_ones(tmp_path, suffix):
    path = tmp_path / f"model{suffix}"
    path.write_bytes(b"whatever")
    with pytest.raises(SceneLoadError, match="supported: .glb, .gltf, .obj, .ply, .stl") as caught:
        load_scene(path)
    assert caught.value.kind is ErrorKind.BAD_INPUT
    with pytest.raises(SceneLoadError, match="supported"):
        load_scene_bytes(b"whatever", suffix or "dae", "model")


def test_directory_is_refused(tmp_path):
    folder = tmp_path / "folder.obj"
    folder.mkdir()
    with pytest.raises(SceneLoadError, match="directory"):
        load_scene(folder)


def _glb() -> bytes:
    return scenes.to_trimesh(scenes.textured_quad()).export(file_type="glb")


@pytest.mark.parametrize(
    ("extension", "data"),
    [(ext, b"") for ext in ("glb", "gltf", "obj", "ply", "stl")]
    + [(ext, np.random.default_rng(7).bytes(600)) for ext in ("glb", "gltf", "obj", "ply", "stl")]
    + [
        ("glb", _glb()[:100]),  # truncated
        ("glb", b"glTF" + _glb()[4:60]),
        ("glb", b"glTF" + bytes(40)),  # version 0
        ("gltf", b"{not json"),
        ("ply", b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n"),
        ("stl", b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0\n"),
        ("obj", scenes.bad_obj("bad_index").encode()),
    ],
    ids=[f"empty-{e}" for e in ("glb", "gltf", "obj", "ply", "stl")]
    + [f"random-{e}" for e in ("glb", "gltf", "obj", "ply", "stl")]
    + ["truncated-glb", "short-glb", "version0-glb", "not-json-gltf", "short-ply", "short-stl", "bad-index-obj"],
)
@pytest.mark.invalid_glb  # corrupt GLBs on purpose
def test_corrupt_bytes_are_one_scene_load_error_naming_the_file(tmp_path, extension, data):
    path = tmp_path / f"broken.{extension}"
    path.write_bytes(data)
    with pytest.raises(SceneLoadError, match=rf"broken\.{extension}") as caught:
        load_scene(path)
    assert type(caught.value) is SceneLoadError
    with pytest.raises(SceneLoadError, match="upload.bin"):
        load_scene_bytes(data, extension, "upload.bin")


@pytest.mark.parametrize(
    ("extension", "data"),
    [
        ("obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\n"),  # a point cloud
        ("obj", b"# nothing but a comment\n"),
        ("gltf", b'{"asset": {"version": "2.0"}}'),
        ("stl", b"solid empty\nendsolid empty\n"),
        (
            "ply",
            b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
            b"property float z\nend_header\n0 0 0\n1 1 1\n",
        ),
    ],
)
def test_no_triangles_is_degenerate(tmp_path, extension, data):
    path = tmp_path / f"empty.{extension}"
    path.write_bytes(data)
    with pytest.raises(DegenerateGeometryError, match="no triangles"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SceneWarning)  # "skipped PointCloud geometry"
            load_scene(path)


@pytest.mark.parametrize(
    ("kind", "error", "match"),
    [
        ("nan", DegenerateGeometryError, r"object 'thing': 1 of 3 vertices have non-finite"),
        ("inf", DegenerateGeometryError, r"object 'thing': 1 of 3 vertices have non-finite"),
        ("point", DegenerateGeometryError, r"zero extent"),
        ("huge", SceneLoadError, r"object 'thing': coordinate magnitude 1e\+13 exceeds the limit 1e\+12"),
        ("bad_index", SceneLoadError, r"index"),
    ],
)
def test_bad_geometry_in_a_file(tmp_path, kind, error, match):
    path = tmp_path / f"{kind}.obj"
    path.write_text(scenes.bad_obj(kind))
    with pytest.raises(error, match=match) as caught:
        load_scene(path)
    assert str(caught.value).startswith(f"{kind}.obj: ")


@pytest.mark.parametrize(
    ("kind", "error"),
    [
        ("nan", DegenerateGeometryError),
        ("inf", DegenerateGeometryError),
        ("huge", SceneLoadError),
        ("no_faces", DegenerateGeometryError),
        ("bad_index", SceneLoadError),
    ],
)
def test_bad_arrays_make_no_scene_object(kind, error):
    with pytest.raises(error, match="'thing'"):
        SceneObject("thing", *scenes.bad_arrays(kind))


def test_bad_scenes_in_memory():
    with pytest.raises(DegenerateGeometryError, match="no triangles"):
        Scene.from_objects((), "empty")
    with pytest.raises(DegenerateGeometryError, match="zero extent"):
        Scene.from_objects([SceneObject("dot", *scenes.bad_arrays("point"))], "dot")
    box = scenes.box_object("same", (0, 0, 0), (1, 1, 1))
    with pytest.raises(SceneLoadError, match="duplicate object names: 'same'"):
        Scene.from_objects([box, box], "twins")
    with pytest.raises(SceneLoadError, match="shape"):
        SceneObject("flat", np.zeros((3, 2)), [[0, 1, 2]])
    with pytest.raises(SceneLoadError, match="no uv"):
        SceneObject("tex", box.vertices, box.faces, texture=scenes.checker())
    with pytest.raises(SceneLoadError, match="base_color"):
        SceneObject("bright", box.vertices, box.faces, base_color=(2.0, 0.0, 0.0, 1.0))


# --------------------------------------------------------------------------- model behaviour


def test_scene_is_immutable():
    scene = scenes.city(buildings=3)
    obj = scene.objects[1]
    with pytest.raises(dataclasses.FrozenInstanceError):
        obj.name = "other"
    with pytest.raises(ValueError, match="read-only"):
        obj.vertices[0, 0] = 1.0
    with pytest.raises(ValueError, match="read-only"):
        scene.bounds[0, 0] = 1.0


def test_content_hash_follows_geometry_and_colour_not_names_or_order():
    city = scenes.city(buildings=5)
    reordered = Scene.from_objects(reversed(city.objects), "elsewhere")
    assert reordered.content_hash == city.content_hash
    renamed = Scene.from_objects([dataclasses.replace(o, name=o.name + "_x") for o in city.objects], "c")
    assert renamed.content_hash == city.content_hash
    first = city.objects[1]
    moved = dataclasses.replace(first, vertices=first.vertices + np.array([0.0, 0.0, 1e-9]))
    assert Scene.from_objects([moved, *city.objects[2:]], "c").content_hash != city.subset(city.names[1:]).content_hash
    recoloured = dataclasses.replace(first, base_color=np.array([0.1, 0.2, 0.3, 1.0]))
    assert Scene.from_objects([recoloured], "c").content_hash != Scene.from_objects([first], "c").content_hash
    negative_zero = dataclasses.replace(first, vertices=np.where(first.vertices == 0.0, -0.0, first.vertices))
    assert Scene.from_objects([negative_zero], "c").content_hash == Scene.from_objects([first], "c").content_hash


def test_subset_selects_by_name_and_names_unknown_ones():
    city = scenes.city(buildings=10)
    part = city.subset(["building_003", "ground", "building_003"])
    assert part.names == ("ground", "building_003")
    assert part.triangle_count == 2 + 12
    np.testing.assert_array_equal(part.bounds[1][1], part.objects[1].bounds[1][1])
    with pytest.raises(SceneLoadError, match="'tower', 'castle'"):
        city.subset(["ground", "tower", "castle"])
    with pytest.raises(SceneLoadError, match="no object names"):
        city.subset([])
    # A bundle evaluated against another scene asks for all its objects (the house's 102 against
    # the city): five are named, not every one.
    asked = [f"window_{i:03d}" for i in range(102)]
    with pytest.raises(SceneLoadError, match=r"'window_004' and 97 more of the 103 asked for \(the scene") as caught:
        city.subset(["ground", *asked])
    assert "window_005" not in str(caught.value)


def test_summary_is_json_ready():
    summary = json.loads(json.dumps(scenes.sphere_field(spheres=4).summary()))
    assert summary["object_count"] == 4 and summary["triangle_count"] == 4 * 320
    assert len(summary["content_hash"]) == 64
    first, second = summary["objects"][:2]
    assert first["colour_source"] == "texture" and first["texture_size"] == [8, 8]
    assert second["colour_source"] == "material" and second["texture_size"] is None
    assert set(first) >= {"name", "triangles", "bounds", "colour_source", "alpha_cutoff"}
    assert summary["warnings"] == []


def test_supported_extensions():
    assert supported_extensions() == ("glb", "gltf", "obj", "ply", "stl")
