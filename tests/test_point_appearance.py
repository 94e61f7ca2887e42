"""The directional appearance of point-based impostors (core/techniques/points/appearance.py, seed 001 §4.3,
§5.2, §5.3): the runtime's look-up finds the texel the integration filled, and a surface whose
sub-pixel structure shows different colours from different sides of the view cell (the paper's
Fig. 3 "microgeometry") keeps those colours, as a 16-sample reference of the real geometry shows
them, where one colour per point cannot."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from farfield.core.colour_space import linear_to_srgb, srgb_to_linear
from farfield.core.errors import LayerPlanError, ViewCellError
from farfield.core.quality.evaluation import downsample, impostor_renderer
from farfield.core.render.points import Appearance, PointRenderer
from farfield.core.render.raster import Camera, MeshRenderer
from farfield.core.scene import Scene, SceneObject
from farfield.core.techniques import get_technique
from farfield.core.techniques.points.appearance import plane_coordinates
from farfield.core.viewcells import BoxCell, ShaftCell
from tests.scenes import box_object as _box

RED, BLUE = (0.9, 0.1, 0.1, 1.0), (0.1, 0.1, 0.9, 1.0)


def test_the_runtime_looks_up_the_texel_where_the_eye_ray_crosses_the_sampling_plane():
    # One point at z = 10; the plane z = 0 with the rectangle [-1, 1]^2 split in 8 x 2 texels.
    tile = np.zeros((2, 8, 4), np.uint8)
    tile[..., 0] = np.arange(8)[None, :] * 30
    tile[..., 1] = np.array([50, 150])[:, None]
    tile[..., 2:] = (200, 255)
    page = np.zeros((4, 16, 4), np.uint8)
    page[2:4, 8:16] = tile  # the tile's first texel at (8, 2)
    plane = SimpleNamespace(
        normal=np.array([0.0, 0.0, 1.0]),
        offset=0.0,
        u=np.array([1.0, 0.0, 0.0]),
        v=np.array([0.0, 1.0, 0.0]),
        rectangle=np.array([[-1.0, -1.0], [1.0, 1.0]]),
    )
    appearance = Appearance(
        (page,),
        np.array([0]),
        np.array([[8, 2]]),
        (8, 2),
        plane.normal,
        0.0,
        plane.u,
        plane.v,
        plane.rectangle[0],
        plane.rectangle[1],
    )
    point = np.array([[0.0, 0.0, 10.0]])
    with PointRenderer(point, np.array([[0, 0, 0, 255]], np.uint8), appearance) as renderer:
        for column, row in ((0, 0), (3, 1), (7, 0), (2.5, 1)):  # 2.5: halfway between two texels
            crossing = np.array([-1.0 + 2.0 * (column + 0.5) / 8, -1.0 + 2.0 * (row + 0.5) / 2])
            eye = np.array([*(crossing * 11.0 / 10.0), -1.0])  # the ray eye -> point crosses z = 0 there
            assert np.allclose(plane_coordinates(plane, eye, point)[0], [(column + 0.5) / 8, (row + 0.5) / 2])
            camera = Camera.look_at(eye, point[0], math.radians(10.0), 15, 1.0, 20.0)
            image = renderer.render(camera)
            drawn = image[image[..., 3] > 0]
            assert drawn.shape[0] == 1
            # Halfway between two texels: their mean in linear light (the pages are sRGB textures).
            halfway = 255.0 * float(linear_to_srgb(0.5 * (srgb_to_linear(60 / 255) + srgb_to_linear(90 / 255))))
            expected = [30 * column, [50, 150][row], 200] if column == int(column) else [halfway, 150, 200]
            assert np.abs(drawn[0, :3].astype(float) - expected).max() <= 1.0, (column, row, drawn[0])


def sawtooth(period: float = 0.02, width: float = 4.0, height: float = 2.0, depth: float = 10.0) -> Scene:
    """Teeth along x, far finer than a pixel: the faces facing -x red, those facing +x blue."""
    x = np.arange(-0.5 * width, 0.5 * width, period)
    rise, fall = [], []
    for x0 in x:
        low0, ridge, low1 = (x0, depth), (x0 + 0.5 * period, depth - period), (x0 + period, depth)
        rise.append((low0, ridge))
        fall.append((ridge, low1))

    def strip(name, pieces, colour):
        vertices, faces = [], []
        for (xa, za), (xb, zb) in pieces:
            base = len(vertices)
            vertices += [
                (xa, -0.5 * height, za),
                (xa, 0.5 * height, za),
                (xb, 0.5 * height, zb),
                (xb, -0.5 * height, zb),
            ]
            faces += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
        return SceneObject(name, np.array(vertices, float), np.array(faces), base_color=colour)

    return Scene.from_objects([strip("facing -x", rise, RED), strip("facing +x", fall, BLUE)], source="sawtooth")


def _mean_colour(image: np.ndarray) -> np.ndarray:
    covered = image[..., 3] > 0
    return image[covered, :3].astype(float).mean(axis=0)


def test_microgeometry_keeps_its_colour_from_each_side_of_the_cell():
    scene = sawtooth()
    cell = BoxCell(np.array([-5.0, -0.5, -0.5]), np.array([5.0, 0.5, 0.5]))
    technique = get_technique("points")
    impostor = technique.bake(scene, cell, technique.options({}, 64), None, None)
    assert impostor.stats["single_colour_share"] < 0.5 and impostor.payload.counts()["textured"] > 0
    target = np.array([0.0, 0.0, 10.0])
    views = {}
    with (
        MeshRenderer(scene.objects) as geometry,
        impostor_renderer(impostor) as points,
        PointRenderer(impostor.payload.positions, impostor.payload.colour.astype(np.uint8)) as preview,
    ):
        for side, eye in (("left", [-5.0, 0.0, 0.0]), ("right", [5.0, 0.0, 0.0]), ("middle", [0.0, 0.0, 0.0])):
            camera = Camera.look_at(np.array(eye), target, math.radians(45.0), 64, 5.0, 20.0)
            fine = Camera.look_at(np.array(eye), target, math.radians(45.0), 64 * 4, 5.0, 20.0)
            views[side] = {
                "reference": _mean_colour(downsample(geometry.render(fine), 4)),  # 16 samples per pixel
                "points": _mean_colour(points.render(camera)),
                "preview": _mean_colour(preview.render(camera)),
            }
    print({side: {k: v.round(1).tolist() for k, v in found.items()} for side, found in views.items()})
    # The real geometry: red from the left, blue from the right.
    assert views["left"]["reference"][0] > views["left"]["reference"][2] + 100
    assert views["right"]["reference"][2] > views["right"]["reference"][0] + 100
    for side in ("left", "right", "middle"):
        found = views[side]
        error = np.abs(found["points"] - found["reference"]).max()
        assert error <= 35.0 and error < 0.6 * max(np.abs(found["preview"] - found["reference"]).max(), 20.0), (
            side,
            found,
        )
    # One colour per point shows the same purple from both sides, far from either.  (The 8 texels
    # of a tile lag behind at the cell's sides: the edge texel averages the viewpoints of a texel
    # and a half, and the bilinear look-up blends in the next.)
    for side in ("left", "right"):
        assert np.abs(views[side]["preview"] - views[side]["reference"]).max() > 60.0, views[side]


def test_point_impostors_refuse_what_they_cannot_make():
    technique = get_technique("points")
    scene = sawtooth()
    with pytest.raises(LayerPlanError, match="box view cell"):
        technique.bake(
            scene, ShaftCell(np.zeros(3), np.array([0.0, 0.0, 1.0]), 0.1, 1.0), technique.options({}, 64), None, None
        )
    with pytest.raises(LayerPlanError, match="min_views"):
        technique.options({"min_views": 200, "max_views": 100})
    with pytest.raises(ViewCellError, match="reaches the view cell"):  # a cell touching the part
        technique.bake(
            scene,
            BoxCell(np.array([-1.0, -1.0, 9.0]), np.array([1.0, 1.0, 9.995])),
            technique.options({}, 64),
            None,
            None,
        )


def _evaluate(scene: Scene, cell: BoxCell, resolution: int = 64):
    technique = get_technique("points")
    impostor = technique.bake(scene, cell, technique.options({}, resolution), None, None)
    return impostor, technique.evaluate(scene, impostor, 8, 0, 0).totals


@pytest.mark.slow
def test_a_sub_pixel_part_and_a_part_seen_nearly_edge_on_keep_every_pixel():
    cell = BoxCell.from_center([0.0, 0.0, 0.0], 1.0)
    # A box a tenth of a pixel wide at 10 units (a 64-pixel image's pixel is 0.13 units there).
    speck = Scene.from_objects([_box("speck", (-0.0065, -0.0065, 9.99), (0.0065, 0.0065, 10.01))], source="speck")
    impostor, totals = _evaluate(speck, cell)
    assert 0 < impostor.payload.count < 50 and totals["hole_pixels"] == 0, (impostor.payload.count, totals)
    # A sheet in the plane y = 0 through the cell's middle: every viewer sees it within 3 degrees of edge-on.
    sheet = SceneObject(
        "sheet",
        np.array([[-1.0, 0.0, 9.0], [1.0, 0.0, 9.0], [1.0, 0.0, 11.0], [-1.0, 0.0, 11.0]]),
        np.array([[0, 1, 2], [0, 2, 3]]),
    )
    impostor, totals = _evaluate(Scene.from_objects([sheet], source="sheet"), cell)
    assert impostor.payload.count > 0 and totals["hole_pixels"] == 0, (impostor.payload.count, totals)


def test_a_part_whose_texels_are_all_cut_away_is_refused():
    quad = SceneObject(
        "glass", np.array([[-1.0, -1.0, 10.0], [1.0, -1.0, 10.0], [1.0, 1.0, 10.0], [-1.0, 1.0, 10.0]]), np.array([[0, 1, 2], [0, 2, 3]]),
        uv=np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]), texture=np.zeros((4, 4, 4), np.uint8), alpha_cutoff=0.5,
    )  # fmt: skip
    technique = get_technique("points")
    with pytest.raises(LayerPlanError, match="no surface"):
        technique.bake(
            Scene.from_objects([quad], source="glass"),
            BoxCell.from_center([0.0, 0.0, 0.0], 1.0),
            technique.options({}, 64),
            None,
            None,
        )


@pytest.mark.slow
def test_the_cli_bakes_evaluates_and_compares_a_point_impostor(tmp_path):
    from click.testing import CliRunner

    from farfield.cli.main import _register, cli
    from tests.scenes import write_scene

    _register()
    scene_file = write_scene(sawtooth(), tmp_path, "glb", "sawtooth")
    cell = "box:-5,-0.5,-0.5,5,0.5,0.5"
    common = [str(scene_file), "--viewcell", cell, "--resolution", "64", "--quiet"]
    baked = CliRunner().invoke(
        cli,
        [
            "bake",
            *common,
            "--technique",
            "points",
            "--option",
            "max_views=64",
            "--out",
            str(tmp_path / "points"),
            "--json",
        ],
    )
    assert baked.exit_code == 0, baked.output
    assert CliRunner().invoke(cli, ["bake", *common, "--out", str(tmp_path / "layered")]).exit_code == 0
    checked = CliRunner().invoke(
        cli, ["evaluate", str(tmp_path / "points"), str(scene_file), "--random", "4", "--check"]
    )
    assert checked.exit_code == 0 and "points" in checked.output, checked.output
    compared = CliRunner().invoke(
        cli,
        ["evaluate", str(tmp_path / "layered"), str(tmp_path / "points"), str(scene_file), "--random", "2", "--json"],
    )
    assert compared.exit_code == 0, compared.output
    import json

    rows = {row["technique"]: row for row in json.loads(compared.output)["bundles"]}
    assert rows["points"]["points"] > 0 and rows["points"]["triangles"] == 0 and rows["layered"]["points"] == 0
    wrong = CliRunner().invoke(
        cli,
        [
            "bake",
            *common[:1],
            "--viewcell",
            "shaft:0,0,0,0,0,1,5,1",
            "--technique",
            "points",
            "--out",
            str(tmp_path / "shaft"),
        ],
    )
    assert wrong.exit_code == 2 and "box view cell" in wrong.output and not (tmp_path / "shaft").exists()


def test_points_drawn_as_baked_pixels_look_the_same_through_a_window():
    # The evaluation's confirmation draws windows of its supersampled camera: the points must
    # land in the same baked pixels there as in the whole image.
    rng = np.random.default_rng(5)
    positions = rng.uniform([-1.0, -1.0, 9.0], [1.0, 1.0, 11.0], (3000, 3))
    colours = np.concatenate([rng.integers(0, 256, (3000, 3)), np.full((3000, 1), 255)], axis=1).astype(np.uint8)
    fov = math.radians(20.0)
    with PointRenderer(positions, colours, grid=(64, fov)) as renderer:
        whole = Camera.look_at(np.array([0.3, -0.2, 0.0]), np.array([0.0, 0.0, 10.0]), fov, 64 * 4, 5.0, 15.0)
        image = renderer.render(whole)
        covered = image[..., 3] > 0
        assert (
            covered.any() and (covered.reshape(64, 4, 64, 4).all(axis=(1, 3)) == covered[::4, ::4]).all()
        )  # whole baked pixels
        for x0, y0, size, resolution in (
            (100, 88, 40, 40),
            (96, 120, 24, 72),
        ):  # windows on whole baked pixels, as the evaluation's
            window = renderer.render(whole.window(x0, y0, size, resolution))
            scale = resolution // size
            expected = np.repeat(np.repeat(image[y0 : y0 + size, x0 : x0 + size], scale, axis=0), scale, axis=1)
            assert np.array_equal(window, expected), (x0, y0, size, resolution)


def test_the_glb_holds_the_points_their_preview_colour_and_their_tiles():
    from farfield.core.impostor.glb import POINT_APPEARANCE, impostor_glb
    from tests.test_bundle import accessor_array, parse_glb

    technique = get_technique("points")
    cell = BoxCell(np.array([-5.0, -0.5, -0.5]), np.array([5.0, 0.5, 0.5]))
    impostor = technique.bake(sawtooth(), cell, technique.options({"max_views": 64}, 48), None, None)
    payload = impostor.payload
    document, binary = parse_glb(impostor_glb(impostor))
    (node,) = document["nodes"]
    assert (
        node["extras"]["farfield"]["technique"] == "points" and node["extras"]["farfield"]["viewcell"] == cell.to_dict()
    )
    (primitive,) = document["meshes"][0]["primitives"]
    assert (
        primitive["mode"] == 0
        and POINT_APPEARANCE in document["extensionsUsed"]
        and POINT_APPEARANCE not in document.get("extensionsRequired", [])
    )
    positions = accessor_array(document, binary, primitive["attributes"]["POSITION"])
    assert np.allclose(positions + np.asarray(node["translation"]), payload.positions, atol=1e-5)
    colour = accessor_array(document, binary, primitive["attributes"]["COLOR_0"])  # glTF: linear
    assert np.allclose(colour, srgb_to_linear(payload.colour[:, :3] / 255.0), atol=1e-6)
    tile = accessor_array(document, binary, primitive["attributes"]["_FARFIELD_TILE"])
    assert np.array_equal(tile[:, 0], payload.page) and np.array_equal(tile[:, 1:], payload.texel)
    extension = primitive["extensions"][POINT_APPEARANCE]
    assert extension["tile"] == payload.tile.tolist() and extension["plane"] == payload.plane.tolist()
    assert extension["axes"] == payload.axes.tolist() and extension["rectangle"] == payload.rectangle.tolist()
    assert len(extension["textures"]) == len(impostor.pages) > 0
    assert document["materials"][primitive["material"]]["extensions"] == {"KHR_materials_unlit": {}}
