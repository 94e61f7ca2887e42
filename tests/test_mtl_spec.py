"""OBJ/MTL read as the MTL specification means it (issue 54), on small files built like the scenes
where farfield departed from it: a grey atlas tinted by ``Kd``, an RGBA opacity mask whose alpha is
constant, map options, and texture names that differ in case from the files.  three.js's
MTLLoader/OBJLoader draws the same files in tests/test_threejs.py."""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np
import PIL.Image
import pytest

from farfield.core.colour_space import srgb_to_linear
from farfield.core.exchange import load_scene, load_scene_bytes
from farfield.core.exchange.archive import pack_scene, read_assets_zip, referenced_files
from farfield.core.exchange.references import FileIndex, map_statement

GRASS_KD = (0.47, 0.70, 0.30)


def quads_obj(folder: Path, materials: dict[str, list[str]], name: str = "scene") -> Path:
    """One unit quad per material (side by side along x, facing +z, uv 0..1) and an MTL holding
    ``materials`` (material -> its statements)."""
    lines, mtl = [f"mtllib {name}.mtl"], []
    for k, (material, statements) in enumerate(materials.items()):
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
        a = 4 * k + 1
        lines += [
            f"o {material}",
            f"usemtl {material}",
            f"f {a}/{a} {a + 1}/{a + 1} {a + 2}/{a + 2}",
            f"f {a}/{a} {a + 2}/{a + 2} {a + 3}/{a + 3}",
        ]
        mtl += [f"newmtl {material}", *statements, ""]
    (folder / f"{name}.mtl").write_text("\n".join(mtl))
    path = folder / f"{name}.obj"
    path.write_text("\n".join(lines) + "\n")
    return path


def grey_atlas(folder: Path, name: str = "atlas.png") -> np.ndarray:
    rng = np.random.default_rng(3)
    grey = rng.integers(100, 160, size=(16, 16), dtype=np.uint8)
    rgba = np.dstack([grey, grey, grey, np.full_like(grey, 255)])
    PIL.Image.fromarray(rgba, "RGBA").save(folder / name)
    return rgba


def leaf_textures(folder: Path) -> tuple[np.ndarray, np.ndarray]:
    """A green RGBA colour texture whose own alpha cuts its left quarter, and an opacity mask saved
    as RGBA with a constant alpha (the mask is in its colour channels): a disc."""
    colour = np.zeros((16, 16, 4), np.uint8)
    colour[..., 1] = 180
    colour[..., 3] = 255
    colour[:, :4, 3] = 0
    y, x = np.mgrid[:16, :16]
    disc = np.where((x - 8) ** 2 + (y - 8) ** 2 <= 36, 255, 0).astype(np.uint8)
    mask = np.dstack([disc, disc, disc, np.full_like(disc, 255)])
    PIL.Image.fromarray(colour, "RGBA").save(folder / "leaf.png")
    PIL.Image.fromarray(mask, "RGBA").save(folder / "leaf_mask.png")
    return colour, mask


def test_kd_multiplies_map_kd_and_a_material_without_kd_shows_its_texture(tmp_path):
    """A voxel-world scene's shared atlas is grey and ``Kd`` carries each material's tint: the
    colour is ``Kd`` × ``map_Kd`` (MTL; three.js), in linear light."""
    atlas = grey_atlas(tmp_path)
    path = quads_obj(
        tmp_path, {"grass": [f"Kd {' '.join(map(str, GRASS_KD))}", "map_Kd atlas.png"], "plain": ["map_Kd atlas.png"]}
    )
    scene = load_scene(path)
    grass, plain = scene.subset(["grass"]).objects[0], scene.subset(["plain"]).objects[0]
    np.testing.assert_allclose(
        grass.base_color[:3], srgb_to_linear(np.round(np.array(GRASS_KD) * 255) / 255), atol=2e-3
    )
    np.testing.assert_array_equal(plain.base_color, [1.0, 1.0, 1.0, 1.0])
    for obj in (grass, plain):
        np.testing.assert_array_equal(obj.texture, atlas)


def test_an_rgba_mask_with_constant_alpha_is_read_by_its_luminance_and_multiplies_the_colour_alpha(tmp_path):
    colour, mask = leaf_textures(tmp_path)
    path = quads_obj(tmp_path, {"leaf": ["Kd 1 1 1", "map_Kd leaf.png", "map_d leaf_mask.png"]})
    (obj,) = load_scene(path).objects
    assert obj.alpha_cutoff == 0.5
    expected = (colour[..., 3].astype(np.uint16) * mask[..., 0] + 127) // 255
    assert np.abs(obj.texture[..., 3].astype(int) - expected).max() <= 1
    np.testing.assert_array_equal(obj.texture[..., :3], colour[..., :3])
    assert (
        obj.texture[8, 8, 3] == 255 and obj.texture[0, 0, 3] == 0 and obj.texture[8, 2, 3] == 0
    )  # disc; outside; the colour's own cut


@pytest.mark.parametrize("channel, band", [("r", 0), ("g", 1), ("b", 2), ("m", 3)])
def test_imfchan_chooses_the_channel_of_the_opacity_map(tmp_path, channel, band):
    grey_atlas(tmp_path)
    rng = np.random.default_rng(band)
    mask = np.full((16, 16, 4), 255, np.uint8)
    mask[..., band] = rng.integers(0, 256, size=(16, 16), dtype=np.uint8)
    PIL.Image.fromarray(mask, "RGBA").save(tmp_path / "mask.png")
    path = quads_obj(tmp_path, {"m": ["map_Kd atlas.png", f"map_d -imfchan {channel} mask.png"]})
    (obj,) = load_scene(path).objects
    np.testing.assert_array_equal(obj.texture[..., 3], mask[..., band])


def test_16_bit_greyscale_colour_and_opacity_maps_are_scaled_to_8_bits_not_clipped(tmp_path):
    """Pillow opens a 16-bit greyscale PNG as ``I;16`` and clips it at 255 when it converts it; the
    colour map and a roughness map read v / 257 (the PNG specification's scaling), and the mask cuts where its 16-bit
    value is below half, not only where it is 0."""
    ramp = np.tile(np.linspace(0, 65535, 16).round().astype(np.uint16), (16, 1))
    PIL.Image.fromarray(ramp).save(tmp_path / "grey16.png")
    path = quads_obj(
        tmp_path,
        {"grey": ["map_Kd grey16.png", "map_Pr grey16.png"], "cut": ["Kd 1 1 1", "map_d grey16.png"]},
    )
    scene = load_scene(path)
    grey, cut = scene.subset(["grey"]).objects[0], scene.subset(["cut"]).objects[0]
    expected = np.round(ramp / 257.0).astype(np.uint8)
    np.testing.assert_array_equal(grey.texture[..., 1], expected)
    np.testing.assert_array_equal(grey.metallic_roughness_texture[..., 1], expected)  # a scalar map (map_Pr) too
    assert cut.alpha_cutoff == 0.5
    np.testing.assert_array_equal(cut.texture[..., 3], expected)


def test_an_rgba_texture_named_as_its_own_opacity_map_keeps_its_alpha(tmp_path):
    colour = np.zeros((16, 16, 4), np.uint8)
    colour[..., 0] = np.arange(16, dtype=np.uint8)[None, :] * 16  # colourful: its luminance is no mask
    colour[..., 1] = 90
    colour[..., 3] = np.where(np.arange(16)[:, None] < 8, 255, 40)
    PIL.Image.fromarray(colour, "RGBA").save(tmp_path / "leaf.png")
    path = quads_obj(tmp_path, {"leaf": ["map_Kd leaf.png", "map_d leaf.png"]})
    (obj,) = load_scene(path).objects
    np.testing.assert_array_equal(obj.texture, colour)  # not its luminance, and not alpha squared


def test_a_mask_that_hides_nothing_and_a_texture_that_never_passes_its_cut_are_warned_about(tmp_path):
    grey_atlas(tmp_path)
    PIL.Image.new("L", (4, 4), 255).save(tmp_path / "opaque.png")
    PIL.Image.new("RGBA", (4, 4), (0, 0, 0, 255)).save(tmp_path / "black.png")
    path = quads_obj(
        tmp_path, {"a": ["map_Kd atlas.png", "map_d opaque.png"], "b": ["map_Kd atlas.png", "map_d black.png"]}
    )
    with pytest.warns(UserWarning):
        warnings = load_scene(path).warnings
    assert any("'opaque.png'" in w and "opaque everywhere" in w for w in warnings), warnings
    assert any("'black.png'" in w and "transparent everywhere" in w for w in warnings), warnings
    assert any("object 'b'" in w and "passes its alpha cut" in w for w in warnings), warnings


def test_map_kd_offset_and_scale_move_the_uv_and_unsupported_options_are_named(tmp_path):
    grey_atlas(tmp_path)
    path = quads_obj(
        tmp_path, {"moved": ["map_Kd -s 2 3 1 -o 0.5 0.25 0 -clamp on atlas.png"], "still": ["map_Kd atlas.png"]}
    )
    with pytest.warns(UserWarning):
        scene = load_scene(path)
    moved, still = scene.subset(["moved"]).objects[0], scene.subset(["still"]).objects[0]
    np.testing.assert_allclose(moved.uv, still.uv * [2.0, 3.0] + [0.5, 0.25])
    assert any("-clamp on" in w and "not supported" in w for w in scene.warnings), scene.warnings


def test_tabs_indented_statements_and_trailing_comments_read_as_the_plain_file(tmp_path):
    """OBJ separates keywords and arguments by white space, and three.js's OBJLoader trims and
    splits each line so; trimesh found only ``\\n<keyword> ``: an indented ``v`` line lost its
    vertex (the faces after it failed or named the wrong ones), a ``f\\t`` line its face, and a
    ``# comment`` after a ``v`` or ``f`` line refused the file.  Each now reads as the plain file."""
    grey_atlas(tmp_path)
    plain = quads_obj(tmp_path, {"a": ["map_Kd atlas.png"], "b": ["Kd 0.2 0.4 0.6"]}).read_text()
    assets = {"scene.mtl": (tmp_path / "scene.mtl").read_bytes(), "atlas.png": (tmp_path / "atlas.png").read_bytes()}
    expected = load_scene_bytes(plain.encode(), "obj", "scene.obj", assets)
    variants = {
        "tabs": plain.replace(" ", "\t"),
        "indented": "".join("  \t" + line for line in plain.splitlines(keepends=True)),
        "continued": "".join(
            line.replace(" ", "\\\n  ", 2).replace("\\\n  ", " ", 1) if line.startswith("f ") else line
            for line in plain.splitlines(keepends=True)
        ),
        "comments": "".join(
            line.rstrip("\n") + " # corner\n" if line[:2] in ("v ", "f ", "vt") else line
            for line in plain.splitlines(keepends=True)
        ),
    }
    for kind, text in variants.items():
        scene = load_scene_bytes(text.encode(), "obj", "scene.obj", assets)
        assert [o.name for o in scene.objects] == [o.name for o in expected.objects], kind
        assert scene.content_hash == expected.content_hash, kind
        assert scene.triangle_count == 4 and scene.objects[0].texture is not None, kind


def test_a_comment_ending_in_a_backslash_does_not_swallow_the_next_statement():
    """A ``\\`` at the end of a statement continues it; a comment ends at its line (Blender's
    importer reads it so): ``# C:\\models\\`` joined the next ``v`` line into the comment, and every
    face after it named the wrong vertices, silently."""
    plain = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\n"
    expected = load_scene_bytes(plain.encode(), "obj", "scene.obj")
    for comment in ("# exported from C:\\models\\\n", "  # C:\\models\\\r\n"):
        scene = load_scene_bytes((comment + plain).encode(), "obj", "scene.obj")
        assert scene.content_hash == expected.content_hash, comment


def test_an_obj_with_cr_line_endings_reads_as_the_plain_file():
    """Lines ended by CR alone (classic Mac OS exporters): trimesh saw one long line and refused the
    file with numpy's "could not be read to its end due to unmatched data"."""
    plain = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf -3 -1 -2\n"
    expected = load_scene_bytes(plain.encode(), "obj", "scene.obj")
    scene = load_scene_bytes(plain.replace("\n", "\r").encode(), "obj", "scene.obj")
    assert scene.content_hash == expected.content_hash and scene.triangle_count == 2


def test_every_material_library_is_read_and_a_material_none_defines_is_named(tmp_path):
    """``mtllib a.mtl b.mtl`` names two libraries (the specification: "mtllib filename1 filename2
    ..."), and a file may have several ``mtllib`` lines; trimesh read the first line as one file
    name, so the materials of the others drew in the default grey with no warning.  A ``usemtl``
    that no library defines is warned about, and packing an upload takes every library's files."""
    (tmp_path / "mats").mkdir()
    (tmp_path / "a.mtl").write_text("newmtl red\nKd 1 0 0\n")
    (tmp_path / "mats" / "b.mtl").write_text("newmtl green\nKd 0 1 0\nmap_Kd atlas.png\n")
    grey_atlas(tmp_path / "mats")
    (tmp_path / "c.mtl").write_text("newmtl blue\nKd 0 0 1\n")
    lines = ["mtllib a.mtl mats/b.mtl", "mtllib c.mtl"]
    for k, material in enumerate(("red", "green", "blue", "nowhere")):
        lines += [f"v {k} 0 0", f"v {k + 1} 0 0", f"v {k} 1 0", "vt 0 0", "vt 1 0", "vt 0 1"]
        lines += [
            f"o {material}",
            f"usemtl {material}",
            f"f {3 * k + 1}/{3 * k + 1} {3 * k + 2}/{3 * k + 2} {3 * k + 3}/{3 * k + 3}",
        ]
    path = tmp_path / "scene.obj"
    path.write_text("\n".join(lines) + "\n")
    scene = load_scene(path)
    colour = {obj.name.split("_")[0]: obj for obj in scene.objects}
    np.testing.assert_array_equal(colour["red"].base_color, [1, 0, 0, 1])
    np.testing.assert_array_equal(colour["blue"].base_color, [0, 0, 1, 1])
    np.testing.assert_array_equal(colour["green"].base_color, [0, 1, 0, 1])
    assert colour["green"].texture is not None
    assert [w for w in scene.warnings if "nowhere" in w] == [
        "material 'nowhere' (usemtl) is defined in no material library; its faces use the default colour"
    ]
    assert len(scene.warnings) == 1, scene.warnings
    assert referenced_files(path) == ["a.mtl", "mats/b.mtl", "c.mtl", "mats/atlas.png"]
    with zipfile.ZipFile(io.BytesIO(pack_scene(path))) as archive:
        assets = {name: archive.read(name) for name in archive.namelist() if name != "scene.obj"}
    assert load_scene_bytes(path.read_bytes(), "obj", "scene.obj", assets).content_hash == scene.content_hash


def test_a_concave_polygon_is_cut_into_triangles_that_cover_it_once(tmp_path):
    """An L-shaped hexagon written from a corner that does not see the others: trimesh's fan (and
    three.js's) covered 4 square units for its 3, a triangle outside it and one twice.  Its
    triangles now cover it once, face its way and keep each corner's uv; a convex pentagon keeps
    its fan."""
    corners = np.array([[2, 0], [2, 1], [1, 1], [1, 2], [0, 2], [0, 0]], dtype=float)
    lines = [f"v {x} {y} 0" for x, y in corners] + [f"vt {x / 2} {y / 2}" for x, y in corners] + ["vn 0 0 1"]
    lines = ["mtllib shapes.mtl", *lines, "o ell", "usemtl atlas", "f " + " ".join(f"{k}/{k}/1" for k in range(1, 7))]
    lines += [
        "v 5 0 0",
        "v 6 0 0",
        "v 6.5 1 0",
        "v 5.5 2 0",
        "v 4.5 1 0",
        "o pentagon",
        "usemtl plain",
        "f 7 8 9 10 11",
    ]
    grey_atlas(tmp_path)
    (tmp_path / "shapes.mtl").write_text("newmtl atlas\nmap_Kd atlas.png\nnewmtl plain\nKd 1 1 1\n")
    (tmp_path / "shapes.obj").write_text("\n".join(lines) + "\n")
    scene = load_scene(tmp_path / "shapes.obj")
    ell, pentagon = scene.subset(["ell"]).objects[0], scene.subset(["pentagon"]).objects[0]
    a, b, c = (ell.vertices[ell.faces[:, k]] for k in range(3))
    normals = np.cross(b - a, c - a)
    assert (normals[:, 2] > 0).all() and np.isclose(0.5 * normals[:, 2].sum(), 3.0)

    def turn(p, q, r):  # z of (q - p) x (r - p), per triangle
        return (q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1]) - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0])

    rng = np.random.default_rng(5)
    for x, y in rng.uniform(0.0, 2.0, size=(400, 2)):
        p = np.broadcast_to([x, y, 0.0], a.shape)
        covering = int(((turn(a, b, p) > 0) & (turn(b, c, p) > 0) & (turn(c, a, p) > 0)).sum())
        assert covering == (1 if x < 1.0 or y < 1.0 else 0), (x, y, covering)
    np.testing.assert_allclose(ell.uv, ell.vertices[:, :2] / 2)  # each corner kept its vt
    np.testing.assert_allclose(ell.normals, [[0, 0, 1]] * len(ell.normals))
    np.testing.assert_array_equal(pentagon.faces, [[0, 1, 2], [0, 2, 3], [0, 3, 4]])


@pytest.mark.parametrize("teeth, clipped", [(4_998, True), (4_999, False)])
def test_a_concave_polygon_past_the_corner_limit_keeps_its_fan_with_a_warning(teeth, clipped):
    """Ear clipping costs more per corner as a polygon grows (a 400,000-corner comb took 143 CPU s,
    one 7.8 MB face): a concave polygon of more than MAX_CLIPPED_CORNERS (10,000) corners is fanned,
    as before the ear clipping, and a warning says so; one at the limit is still clipped."""
    corners = [(x, y) for k in range(teeth) for x, y in ((2 * k, 0), (2 * k + 1, 10))]
    corners += [(2 * teeth, 0), (2 * teeth, -1), (0, -1), (-1, 0)]  # a comb: no corner sees the others
    obj = "".join(f"v {x} {y} 0\n" for x, y in corners) + "f " + " ".join(map(str, range(1, len(corners) + 1)))
    scene = load_scene_bytes(obj.encode(), "obj", "comb.obj")
    (comb,) = scene.objects
    a, b, c = (comb.vertices[comb.faces[:, k]] for k in range(3))
    turns = np.cross(b - a, c - a)[:, 2]
    assert len(comb.faces) == len(corners) - 2
    assert (turns.max() <= 0) == clipped  # clockwise; the fan has triangles turned against the polygon
    warned = [w for w in scene.warnings if "corners (more than 10,000)" in w]
    assert len(warned) == (0 if clipped else 1), scene.warnings
    assert all(f"'f 1 2 3 ...' has {len(corners):,} corners" in w for w in warned), warned


def test_map_statements_split_options_from_file_names():
    assert map_statement("-s 1 1 1 my tex.png").file == "my tex.png"
    assert map_statement("-imfchan r -bm 0.5 bump map.png").options == {"imfchan": ("r",), "bm": ("0.5",)}
    assert map_statement("-o 1 leaf.png").options == {"o": ("1",)}
    assert map_statement("-clamp on leaf.png").options == {"clamp": ("on",)}
    assert map_statement("leaf.png").options == {}


def case_scene(folder: Path) -> Path:
    """Materials naming their textures in other case and Windows-style folders than the files have."""
    (folder / "textures").mkdir()
    grey_atlas(folder / "textures", "bark.png")
    grey_atlas(folder, "leaf.png")
    return quads_obj(folder, {"bark": ["map_Kd Textures\\Bark.PNG"], "leaf": ["map_Kd LEAF.png"], "flat": ["Kd 1 0 0"]})


def test_texture_names_resolve_alike_from_disk_and_from_an_upload(tmp_path):
    path = case_scene(tmp_path)
    from_disk = load_scene(path)
    assert all(o.texture is not None for o in from_disk.objects if o.name != "flat"), [
        o.name for o in from_disk.objects if o.texture is None
    ]
    files = {
        p.relative_to(tmp_path).as_posix(): p.read_bytes() for p in tmp_path.rglob("*") if p.is_file() and p != path
    }
    uploaded = load_scene_bytes(path.read_bytes(), "obj", path.name, assets=files)
    assert uploaded.content_hash == from_disk.content_hash
    # what `farfield submit` packs: the files under their own names, found as the loader finds them
    assert sorted(referenced_files(path)) == ["leaf.png", "scene.mtl", "textures/bark.png"]
    packed = read_assets_zip(pack_scene(path))
    assert (
        load_scene_bytes(packed.pop("scene.obj"), "obj", "scene.obj", assets=packed).content_hash
        == from_disk.content_hash
    )


def test_a_file_index_prefers_the_exact_name_and_refuses_an_ambiguous_base_name():
    index = FileIndex(["a/leaf.png", "b/leaf.png", "Leaf.png", "bark.png"])
    assert index.find("Leaf.png") == "Leaf.png"
    assert index.find("x/y/BARK.png") == "bark.png"
    assert index.find("c/leaf.png") == "Leaf.png"  # the base name, case folded: the one at the top
    assert index.find("missing.png") is None
    assert FileIndex(["a/leaf.png", "b/leaf.png"]).find("c/leaf.png") is None


def test_upload_zip_of_a_folder_keeps_its_names(tmp_path):
    path = case_scene(tmp_path)
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        for p in tmp_path.rglob("*"):
            if p.is_file():
                archive.write(p, p.relative_to(tmp_path).as_posix())
    assets = read_assets_zip(buffer.getvalue())
    scene = load_scene_bytes(assets.pop("scene.obj"), "obj", "scene.obj", assets=assets)
    assert scene.content_hash == load_scene(path).content_hash
