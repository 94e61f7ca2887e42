"""Octahedral impostors (docs/techniques/octahedral.md): the octahedral map, the frame atlas, the
bake of a small procedural part, the bundle round trip, the outside-sphere view cell and the
accuracy distance, measured against the real geometry at, beyond and closer than it."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from farfield.core.errors import AtlasOverflowError, ViewCellError
from farfield.core.impostor.bundle import read_bundle, write_bundle
from farfield.core.layering.recording import iter_views
from farfield.core.procedural import box_object
from farfield.core.quality.evaluation import _grow, evaluate_at, vertex_pixels
from farfield.core.render.raster import Camera, MeshRenderer
from farfield.core.scene import Scene
from farfield.core.techniques import get_technique
from farfield.core.techniques.octahedral import mapping
from farfield.core.techniques.octahedral.frames import CameraPlan, cell_size, pages_layout
from farfield.core.techniques.octahedral.runtime import OctahedralRenderer
from farfield.core.viewcells import SphereOutsideCell, parse_viewcell, viewcell_from_dict

RESOLUTION = 64  # output pixels the accuracy distance is computed for: small, for llvmpipe


def tree() -> Scene:
    """A small procedural tree: a trunk, a crown and a red branch to one side (2.2 units tall)."""
    return Scene.from_objects(
        [
            box_object("trunk", [-0.15, -0.15, 0.0], [0.15, 0.15, 1.0], (0.45, 0.3, 0.15, 1.0)),
            box_object("crown", [-0.7, -0.5, 1.0], [0.7, 0.5, 2.2], (0.1, 0.6, 0.2, 1.0)),
            box_object("branch", [0.3, -0.1, 0.2], [1.0, 0.1, 0.5], (0.8, 0.2, 0.2, 1.0)),
        ],
        "tree",
    )


def bake(channels: str = "albedo", grid: int = 8, hemisphere: bool = False, **more):
    scene = tree()
    technique = get_technique("octahedral")
    options = technique.options(
        {"grid": grid, "frame_resolution": 32, "channels": channels, "hemisphere": hemisphere} | more, RESOLUTION
    )
    centre = 0.5 * (scene.bounds[0] + scene.bounds[1])
    return scene, technique.bake(scene, SphereOutsideCell(centre, 3.0, hemisphere), options, None, None)


@pytest.mark.parametrize("hemisphere", [False, True])
def test_the_octahedral_map_round_trips_and_puts_frames_on_grid_points(hemisphere):
    d = mapping.fibonacci_directions(4000, hemisphere)
    assert np.abs(mapping.decode(mapping.encode(d, hemisphere), hemisphere) - d).max() < 1e-12
    n = 7
    frames = mapping.frame_directions(n, hemisphere)
    assert np.allclose(np.linalg.norm(frames, axis=1), 1.0)
    grid = mapping.encode(frames, hemisphere) * (n - 1)
    interior = np.all((grid > 1e-9) & (grid < n - 1 - 1e-9), axis=1)  # border points of the full map are mirrored
    j, i = np.divmod(np.arange(n * n), n)
    assert np.allclose(grid[interior], np.stack([i, j], axis=1)[interior], atol=1e-9)
    # The three blended frames' map points, weighted, give the direction's own map point back.
    index, weight = mapping.blend_frames(d, n, hemisphere)
    assert np.all(weight >= 0.0) and np.allclose(weight.sum(axis=1), 1.0)
    corners = np.stack([i, j], axis=1)[index] / (n - 1)
    assert np.allclose(np.einsum("mk,mkc->mc", weight, corners), mapping.encode(d, hemisphere), atol=1e-12)
    # Top-down is the map's centre; a hemisphere's horizon is its border.
    assert mapping.encode(np.array([[0.0, 0.0, 1.0]]), hemisphere).tolist() == [[0.5, 0.5]]
    if hemisphere:
        horizon = mapping.encode(np.array([[1.0, 2.0, 0.0], [-3.0, 1.0, 0.0]]), True)
        assert np.all(np.any(np.isclose(horizon, 0.0) | np.isclose(horizon, 1.0), axis=1))


def test_the_grid_angle_falls_as_the_grid_grows_and_the_hemisphere_halves_it():
    full = [mapping.grid_angle(n, samples=4000) for n in (8, 16, 32)]
    hemi = [mapping.grid_angle(n, True, samples=4000) for n in (8, 16, 32)]
    assert full[0] > full[1] > full[2] and hemi[0] > hemi[1] > hemi[2]
    assert all(h < f for h, f in zip(hemi, full))  # the same frames over half the directions


def test_atlas_cells_tile_pages_without_overlap_and_overflow_is_refused():
    page, texel, sides = pages_layout(12, 64, 4, 4096)
    assert sides == [12 * 72] and set(page.tolist()) == {0}
    page, texel, sides = pages_layout(5, 30, 2, 100)  # 34-texel cells, 2 a row, 4 a page
    s = cell_size(30, 2)
    assert len(sides) == 7 and sides[:6] == [68] * 6 and sides[6] == 34
    for p in range(len(sides)):
        origins = {tuple(t) for t in texel[page == p] - 2}
        assert len(origins) == (page == p).sum()  # no two cells share a place
        assert all(x % s == 0 and y % s == 0 and x + s <= sides[p] and y + s <= sides[p] for x, y in origins)
    with pytest.raises(AtlasOverflowError, match="72 texels, more than a page of 64"):
        pages_layout(2, 64, 4, 64)


def test_a_bake_records_every_frame_conservatively_with_padding_that_mips_cannot_cross():
    scene, impostor = bake("albedo+normal+depth", grid=9)
    p = impostor.payload
    assert impostor.technique == "octahedral" and p.count == 81 and p.n == 9 and p.depth
    s = cell_size(p.frame_resolution, p.padding)
    (page,) = impostor.pages
    (normal,) = impostor.channels["normal"]
    assert page.shape == (9 * s, 9 * s, 4) == normal.shape
    alpha = page[..., 3]
    inside = np.zeros(alpha.shape, bool)
    for x, y in p.texel:
        inside[y : y + p.frame_resolution, x : x + p.frame_resolution] = True
    assert not alpha[~inside].any() and set(np.unique(alpha)) == {0, 255}  # padding transparent, texels 0 or 255
    assert (page[~inside][:, :3].max(axis=1) > 0).all()  # and coloured (dilated): no black for a mip level to mix in
    assert np.array_equal(normal[..., 3] > 0, alpha > 0)  # depth exactly where colour is
    # Cells are s = 40 texels: mip levels up to 3 average texels of one cell only; the padding (4)
    # holds the frame's own dilated colour, so their filtering reads no other frame.
    assert s % 8 == 0 and p.padding >= 4
    # The top-down frame (the grid's centre, 9 odd) sees the crown's top, green, 1.1 above the centre.
    top = 4 * 9 + 4
    assert np.allclose(p.axes[top, 2], [0.0, 0.0, 1.0])
    x, y = p.texel[top] + p.frame_resolution // 2
    assert page[y, x, 1] > 2 * page[y, x, 0]
    height = ((normal[y, x, 3] - 1) / 254 * 2 - 1) * p.radius
    assert abs(height - (2.2 - 1.1)) < p.radius / 127
    # Conservative: the frame covers the crown's 1.4 x 1.0 top, grown by at most a texel a side.
    texel = 2 * p.radius / p.frame_resolution
    covered = int((alpha[p.texel[top][1] :, p.texel[top][0] :][: p.frame_resolution, : p.frame_resolution] > 0).sum())
    assert 1.4 * 1.0 / texel**2 <= covered <= (1.4 + 2 * texel) * (1.0 + 2 * texel) / texel**2
    stats = impostor.stats
    assert stats["accuracy_distance"] > p.radius and stats["accuracy"]["grid_angle_deg"] > 0
    assert stats["channel_bytes"] == {"albedo": page.nbytes, "normal": normal.nbytes}
    assert "accuracy distance" in get_technique("octahedral").summary(stats)


def test_options_refuse_cells_inside_the_part(tmp_path):
    technique = get_technique("octahedral")
    scene = tree()
    with pytest.raises(ViewCellError, match="bounding sphere"):
        technique.check(SphereOutsideCell([0.0, 0.0, 1.0], 1.0), technique.options(), scene.bounds)
    far = SphereOutsideCell([0.0, 0.0, 1.0], 10.0)
    assert technique.check(far, technique.options({"grid": 4}), scene.bounds).layers == 16


def test_the_bundle_round_trips_the_frames_and_reports_the_accuracy_distance(tmp_path):
    _, impostor = bake("albedo+normal+depth", grid=4)
    paths = write_bundle(impostor, tmp_path / "octa")
    back = read_bundle(paths.directory)
    assert back.payload.kind == "octahedral" and back.viewcell == impostor.viewcell
    for name, array in impostor.payload.arrays().items():
        assert np.array_equal(array, back.payload.arrays()[name]), name
    assert np.array_equal(back.pages[0], impostor.pages[0])
    assert np.array_equal(back.channels["normal"][0], impostor.channels["normal"][0])
    manifest = json.loads(paths.manifest.read_text())
    assert manifest["stats"]["accuracy_distance"] == impostor.stats["accuracy_distance"]
    assert manifest["payload"]["counts"] == {"frames": 16}
    assert isinstance(viewcell_from_dict(manifest["viewcell"]), SphereOutsideCell)


def test_the_outside_sphere_cell_samples_top_down_grazing_and_far_viewpoints():
    cell = parse_viewcell("outside-hemi:1,2,3,5")
    assert isinstance(cell, SphereOutsideCell) and cell.hemisphere and cell.radius == 5.0
    assert viewcell_from_dict(json.loads(json.dumps(cell.to_dict()))).to_dict() == cell.to_dict()
    corners = cell.corners() - cell.centre
    elevation = np.degrees(np.arcsin(corners[:, 2] / np.linalg.norm(corners, axis=1)))
    assert elevation.max() == pytest.approx(90.0) and elevation.min() == pytest.approx(1.0)
    points = cell.sample_random(200, 3)
    assert cell.contains(points).all() and cell.contains(cell.corners()).all() and cell.contains(cell.center[None])[0]
    assert not cell.contains(np.array([[1.0, 2.0, 3.0 + 4.9], [1.0, 2.0 + 6.0, 2.0]])).any()  # too near; below
    full = SphereOutsideCell([0.0, 0.0, 0.0], 2.0)
    assert (full.corners()[:, 2] < 0).any() and full.distance_to_box([[-0.5] * 3, [0.5] * 3]) == pytest.approx(
        2.0 - math.sqrt(0.75)
    )


def _views(impostor, scene, distance: float, seed: int) -> tuple[np.ndarray, list[str]]:
    """Viewpoints ``distance`` from the part's centre: the outside-sphere cell's corners (top-down,
    grazing, 45°, from below) and random ones."""
    centre = impostor.payload.centre
    cell = SphereOutsideCell(centre, distance, impostor.payload.hemisphere)
    random = cell.sample_random(4, seed, depth=0.0)
    points = np.concatenate([cell.corners(), random])
    return points, ["corner"] * len(cell.corners()) + ["random"] * len(random)


@pytest.mark.parametrize(
    "channels, grid",
    [("albedo", 8), ("albedo+normal+depth", 8), ("albedo+normal+depth", 9)],
    ids=["albedo", "depth", "two-sided"],
)
def test_beyond_the_accuracy_distance_no_pixel_is_off_by_more_than_one_and_closer_in_some_are(channels, grid):
    scene, impostor = bake(channels, grid=grid)
    distance = impostor.stats["accuracy_distance"]
    for factor, seed in ((1.0, 1), (1.6, 2)):
        points, kinds = _views(impostor, scene, factor * distance, seed)
        totals = evaluate_at(scene, impostor, points, kinds, samples=2).totals
        assert totals["geometry_pixels"] > 0
        assert totals["hole_pixels"] == 0 and totals["bloat_beyond_1px"] == 0, (factor, totals)
    # Much closer (a tenth of it, at most 2.5 radii), the frames' parallax shows: holes or bloat.
    points, kinds = _views(impostor, scene, min(0.1 * distance, 2.5 * impostor.payload.radius), 3)
    near = evaluate_at(scene, impostor, points[:6], kinds[:6], samples=2, confirm_windows=8).totals
    assert near["hole_pixels"] + near["bloat_beyond_1px"] > 0, near


def test_the_technique_evaluates_from_its_cell_and_the_runtime_releases_cleanly():
    scene, impostor = bake("albedo", grid=6, hemisphere=True)
    technique = get_technique("octahedral")
    cell = SphereOutsideCell(impostor.payload.centre, impostor.stats["accuracy_distance"], True)
    from dataclasses import replace

    far = replace(impostor, viewcell=cell.to_dict(), reference_viewpoint=cell.center)  # as baked for that cell
    result = technique.evaluate(scene, far, 2, 0, 0)
    assert result.totals["hole_pixels"] == 0 and "accuracy distance" in technique.evaluation_text(result, impostor)
    with OctahedralRenderer(impostor) as renderer:
        assert renderer.triangle_count == 2 and renderer.ctx.error == "GL_NO_ERROR"


def test_the_g_buffer_blends_the_frames_normals_and_depth_corrects_their_parallax():
    """The lit evaluation's G-buffer (Payload.gbuffer): the blended normal pages against the
    geometry's normals, 4 radii away, between grid points; the depth-corrected frames put each
    normal where the part has it (the median error falls from degrees to a fraction of one)."""
    from farfield.core.quality.evaluation import depth_bounds
    from farfield.core.render.raster import Camera, MeshRenderer

    medians = {}
    for channels in ("albedo+normal", "albedo+normal+depth"):
        scene, impostor = bake(channels, grid=8)
        centre, radius = impostor.payload.centre, impostor.payload.radius
        eye = centre + 4.0 * radius * np.array([0.62, -0.55, 0.56]) / np.linalg.norm([0.62, -0.55, 0.56])
        near, far = depth_bounds(eye, (centre - eye) / np.linalg.norm(centre - eye), impostor.payload.world_points())
        camera = Camera.look_at(eye, centre, math.radians(45.0), 96, near, far)
        with (
            MeshRenderer(scene.objects, normals=True) as geometry,
            impostor.payload.gbuffer(impostor) as stand_in,
            impostor.payload.gbuffer(impostor, normals=False) as cards,
        ):
            (g_image, g_normal), (i_image, i_normal) = geometry.render_normals(camera), stand_in.render_normals(camera)
            flat_image, flat_normal = cards.render_normals(camera)
        both = (g_image[..., 3] > 0) & (i_image[..., 3] > 0)
        assert both.sum() > 500 and np.array_equal(flat_image[..., 3] > 0, i_image[..., 3] > 0)
        cosine = np.clip(np.sum(g_normal[both] * i_normal[both], axis=1), -1.0, 1.0)
        medians[channels] = float(np.degrees(np.median(np.arccos(cosine))))
        to_eye = (eye - centre) / np.linalg.norm(eye - centre)
        assert np.allclose(flat_normal[both] @ to_eye, 1.0, atol=0.05)  # flat cards face the eye
    assert medians["albedo+normal+depth"] < 1.0 < medians["albedo+normal"], medians


def test_the_runtime_writes_the_depth_where_the_part_is():
    """The pixel depth offset: with depth kept, the card's depth is the part's (within a texel or
    two, the height fields' quantisation and the blend), so it meets other geometry where the part
    would; without depth it is the card plane's, up to the part's extent off."""
    from farfield.core.quality.evaluation import depth_bounds
    from farfield.core.render.raster import Camera, MeshRenderer

    errors = {}
    for channels in ("albedo", "albedo+normal+depth"):
        scene, impostor = bake(channels, grid=8)
        centre, radius = impostor.payload.centre, impostor.payload.radius
        eye = centre + 4.0 * radius * np.array([-0.5, 0.7, 0.5]) / np.linalg.norm([-0.5, 0.7, 0.5])
        near, far = depth_bounds(eye, (centre - eye) / np.linalg.norm(centre - eye), impostor.payload.world_points())
        camera = Camera.look_at(eye, centre, math.radians(45.0), 96, near, far)
        with MeshRenderer(scene.objects) as geometry, OctahedralRenderer(impostor) as stand_in:
            g, i = geometry.render(camera), stand_in.render(camera)
            g_depth, i_depth = geometry.last_depth(camera), stand_in.last_depth(camera)  # the public read-back
        both = (g[..., 3] > 0) & (i[..., 3] > 0)
        errors[channels] = float(np.median(np.abs(g_depth[both] - i_depth[both]))) / radius
    texel = 2.0 / 32  # of a frame, in radii
    assert errors["albedo+normal+depth"] < texel < 5 * texel < errors["albedo"], errors


def test_opposite_frames_bound_the_columns_and_bring_the_accuracy_distance_in():
    """A full grid of odd size has every frame's opposite: with depth, a texel's column runs only
    between the two frames' surfaces, so its walls stray at most half the part's longest internal
    gap; for a convex part (one box: no gap) the distance falls to what the texels and the depth
    steps allow."""
    _, albedo = bake("albedo", grid=9)
    _, one_sided = bake("albedo+normal+depth", grid=8)
    _, two_sided = bake("albedo+normal+depth", grid=9)
    assert one_sided.stats["accuracy"]["gap"] is None and two_sided.stats["accuracy"]["gap"] > 0.0
    assert (
        two_sided.stats["accuracy_distance"] < albedo.stats["accuracy_distance"] < one_sided.stats["accuracy_distance"]
    )
    technique = get_technique("octahedral")
    box = Scene.from_objects([box_object("box", [0.0, 0.0, 0.0], [1.0, 0.6, 0.4], (0.5, 0.5, 0.9, 1.0))], "box")
    options = technique.options({"grid": 9, "frame_resolution": 32, "channels": "albedo+normal+depth"}, RESOLUTION)
    convex = technique.bake(box, SphereOutsideCell([0.5, 0.3, 0.2], 2.0), options, None, None)
    # No gap along the lines; the texels only the exact test covers (the box's rim, between the
    # samples) bound their columns by slabs of 2r / 127 (frames.column_gap): a few of them.
    accuracy = convex.stats["accuracy"]
    assert accuracy["gap"] <= 4 * 2 * convex.payload.radius / 127 and accuracy["radii"] < 10.0


def metal_tree() -> Scene:
    """The tree with a material: a glossy metal crown, a half-rough trunk, an emitting branch."""
    from dataclasses import replace

    trunk, crown, branch = tree().objects
    return Scene.from_objects(
        [
            replace(trunk, roughness_factor=0.6),
            replace(crown, metallic_factor=0.9, roughness_factor=0.25),
            replace(branch, emissive_factor=np.array([1.0, 0.5, 0.0])),
        ],
        "metal tree",
    )


def test_the_material_channel_is_recorded_per_frame_and_blended_by_the_g_buffer(tmp_path):
    """+material: ORM and emissive pages laid out as the colour (a matte part keeps none); the
    runtime's material G-buffer gives the geometry's material where both cover (4 radii away, between
    grid points), the bundle keeps the pages and the GLB's fallback card carries them (validated)."""
    from farfield.core.impostor.glb import impostor_glb
    from farfield.core.quality.evaluation import depth_bounds
    from farfield.core.render.raster import Camera, MeshRenderer

    technique = get_technique("octahedral")
    options = technique.options({"grid": 9, "frame_resolution": 32, "channels": "albedo+normal+material+depth"}, 64)
    matte = technique.bake(tree(), SphereOutsideCell([0.0, 0.0, 1.1], 3.0), options, None, None)
    assert set(matte.channels) == {"normal"}  # nothing to say beyond the default factors
    scene = metal_tree()
    impostor = technique.bake(scene, SphereOutsideCell([0.0, 0.0, 1.1], 3.0), options, None, None)
    assert set(impostor.channels) == {"normal", "material", "emissive"}
    page, material, emissive = impostor.pages[0], impostor.channels["material"][0], impostor.channels["emissive"][0]
    assert material.shape == emissive.shape == page.shape
    assert np.array_equal(material[..., 3] > 0, page[..., 3] > 0) and np.array_equal(emissive[..., 3], material[..., 3])
    assert impostor.stats["channel_bytes"]["material"] == material.nbytes
    covered = material[..., 3] > 0
    assert (material[~covered][..., :3].max(axis=-1) > 0).all()  # dilated into the padding, as the colour
    glossy = (
        (material[..., 1] == 64) & (np.abs(material[..., 2].astype(int) - 230) <= 1) & covered
    )  # the crown: roughness 0.25, metal 0.9
    assert glossy.sum() > 0.2 * covered.sum()
    assert (emissive[covered][:, 0] == 255).sum() > 0 and (emissive[covered][:, 2] == 0).all()

    centre, radius = impostor.payload.centre, impostor.payload.radius
    eye = centre + 4.0 * radius * np.array([0.62, -0.55, 0.56]) / np.linalg.norm([0.62, -0.55, 0.56])
    near, far = depth_bounds(eye, (centre - eye) / np.linalg.norm(centre - eye), impostor.payload.world_points())
    camera = Camera.look_at(eye, centre, math.radians(45.0), 96, near, far)
    with (
        MeshRenderer(scene.objects, normals=True, materials=True) as geometry,
        impostor.payload.gbuffer(impostor) as stand_in,
        matte.payload.gbuffer(matte) as without,
    ):
        g_image, _, g_material = geometry.render_material(camera)
        i_image, _, i_material = stand_in.render_material(camera)
        assert not without.materials
    both = (g_image[..., 3] > 0) & (i_image[..., 3] > 0)
    assert both.sum() > 500
    error = np.abs(g_material[both] - i_material[both])
    assert np.median(error, axis=0).max() < 0.01, np.median(error, axis=0)
    assert (error.max(axis=1) < 0.05).mean() > 0.9
    assert np.abs(i_material[~(i_image[..., 3] > 0)]).max() == 0.0

    # The lit evaluation shades the impostor with its material: closer to the metal tree than matte.
    from farfield.core.quality.lit import evaluate_lit_at

    plain = technique.bake(scene, SphereOutsideCell([0.0, 0.0, 1.1], 3.0), technique.options(
        {"grid": 9, "frame_resolution": 32, "channels": "albedo+normal+depth"}, 64), None, None)  # fmt: skip
    worst = {}
    for name, baked in (("kept", impostor), ("matte", plain)):
        totals = evaluate_lit_at(scene, baked, eye[None], ["random"], samples=1).totals
        assert totals["impostor_material"] == name
        worst[name] = max(light["lit_error_mean"] for light in totals["lights"])
    assert 2.0 * worst["kept"] < worst["matte"], worst

    back = read_bundle(write_bundle(impostor, tmp_path / "octa").directory)
    for name in ("material", "emissive"):
        assert np.array_equal(back.channels[name][0], impostor.channels[name][0])
    glb = impostor_glb(impostor)
    (tmp_path / "octa.glb").write_bytes(glb)  # the session's validator checks it
    document = json.loads(glb[20 : 20 + int.from_bytes(glb[12:16], "little")])
    (lit,) = document["materials"]
    assert {"metallicRoughnessTexture", "baseColorTexture"} <= set(lit["pbrMetallicRoughness"])
    assert {"occlusionTexture", "emissiveTexture", "normalTexture"} <= set(lit)


def twig(thick: float = 0.04) -> Scene:
    """A trunk with two twigs ``thick`` units thick (0.04: a third of a 16-texel frame's texel, a
    sixth of a 64 px pixel at the accuracy distance): thinner than a pixel from every distance the
    test looks from."""
    h = 0.5 * thick
    return Scene.from_objects(
        [
            box_object("trunk", [-0.1, -0.1, 0.0], [0.1, 0.1, 1.0], (0.45, 0.3, 0.15, 1.0)),
            box_object("twig", [0.0, -h, 0.92 - h], [1.4, h, 0.92 + h], (0.8, 0.2, 0.2, 1.0)),
            box_object("twig2", [-h, 0.0, 0.52 - h], [h, 1.2, 0.52 + h], (0.2, 0.2, 0.8, 1.0)),
        ],
        "twig",
    )


@pytest.mark.parametrize("channels", ["albedo", "albedo+normal+depth"])
def test_a_thin_twig_keeps_its_pixels_from_the_accuracy_distance_to_fifty_times_it(channels):
    """Issue 56: the card drawn at the output resolution (one sample a pixel, as a runtime draws it)
    against the geometry drawn conservatively (8 x 8 samples a pixel, and every pixel holding a
    vertex: a part far smaller than a pixel is still there).  Sampling each frame at one point per
    pixel lost the twig: 55 / 3 / 35 / 38 hole pixels at 1 / 1.3 / 2 / 5 times the distance (albedo;
    27 / 30 / 7 / 38 with depth); testing coverage over the pixel's footprint and growing the card by
    a pixel loses none and bloats none."""
    scene = twig()
    technique = get_technique("octahedral")
    options = technique.options({"grid": 9, "frame_resolution": 16, "channels": channels, "samples": 4}, RESOLUTION)
    centre = 0.5 * (scene.bounds[0] + scene.bounds[1])
    impostor = technique.bake(scene, SphereOutsideCell(centre, 3.0, False), options, None, None)
    distance, fov, s = impostor.stats["accuracy_distance"], math.radians(impostor.fov_deg), 8
    holes, bloat, covered = {}, {}, {}
    with MeshRenderer(scene.objects) as geometry, OctahedralRenderer(impostor) as card:
        for factor in (1.0, 1.3, 2.0, 5.0, 50.0):
            holes[factor] = bloat[factor] = covered[factor] = 0
            for direction in mapping.fibonacci_directions(12, False):
                eye = centre + factor * distance * direction
                near, far = factor * distance - 3.0, factor * distance + 3.0
                fine = geometry.render(Camera.look_at(eye, centre, fov, RESOLUTION * s, near, far))
                drawn = card.render(Camera.look_at(eye, centre, fov, RESOLUTION, near, far))[..., 3] > 0
                reach = vertex_pixels(scene.objects, Camera.look_at(eye, centre, fov, RESOLUTION * s, near, far), s)
                reach |= fine[..., 3].reshape(RESOLUTION, s, RESOLUTION, s).max(axis=(1, 3)) > 0
                covered[factor] += int(reach.sum())
                holes[factor] += int((reach & ~_grow(drawn, 1)).sum())
                bloat[factor] += int((drawn & ~_grow(reach, 1)).sum())
    assert covered[1.0] > 50 and covered[50.0] > 0  # the twig is seen: the sweep tests something
    assert holes == dict.fromkeys(holes, 0) and bloat == dict.fromkeys(bloat, 0), (holes, bloat)


@pytest.mark.parametrize("channels", ["albedo", "albedo+normal+depth"])
def test_twigs_a_twentieth_of_a_texel_thin_keep_every_pixel_with_the_default_samples(channels):
    """Issue 56: frames recorded with the default 2 x 2 samples per texel, twigs a twentieth of a
    texel thick (a tenth of the samples' spacing), against the geometry's exact pixel coverage (a
    pixel is the part's where its square meets a triangle: the layer recording's test, one slab
    from the viewpoint), at 1, 1.3, 2 and 5 times the accuracy distance, from top-down, from below,
    grazing and spread directions: no hole pixel, no pixel bloated beyond one.  The frames' old
    coverage (a texel covered when a sample is) lost the twigs: 5 / 0 / 0 / 0 hole pixels at
    1 / 1.3 / 2 / 5 times (albedo); with depth 55 / 29 / 13 / 0, and 5 bloated beyond one at 1 x."""
    scene = twig(0.0065)
    technique = get_technique("octahedral")
    options = technique.options({"grid": 9, "frame_resolution": 16, "channels": channels}, RESOLUTION)
    assert options.samples == 2  # the default
    centre = 0.5 * (scene.bounds[0] + scene.bounds[1])
    impostor = technique.bake(scene, SphereOutsideCell(centre, 3.0, False), options, None, None)
    assert 0.0065 <= 2.0 * impostor.payload.radius / 16 / 20  # a twentieth of a texel at most
    distance, fov = impostor.stats["accuracy_distance"], math.radians(impostor.fov_deg)
    grazing = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [-0.6, 0.8, 0.0], [0.8, 0.6, 0.05], [0.7, -0.7, -0.05]]
    directions = np.concatenate([[[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]], grazing, mapping.fibonacci_directions(12)])
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    holes, bloat, covered = {}, {}, {}
    with OctahedralRenderer(impostor) as card:
        for factor in (1.0, 1.3, 2.0, 5.0):
            near, far = factor * distance - 3.0, factor * distance + 3.0
            cameras = [
                Camera.look_at(centre + factor * distance * d, centre, fov, RESOLUTION, near, far) for d in directions
            ]
            exact = iter_views(scene.objects, [CameraPlan.of_camera(c) for c in cameras], cull=True)
            holes[factor] = bloat[factor] = covered[factor] = 0
            for camera, (_, _, layer, _) in zip(cameras, exact, strict=True):
                reach = layer[::-1, :, 3] > 0
                drawn = card.render(camera)[..., 3] > 0
                covered[factor] += int(reach.sum())
                holes[factor] += int((reach & ~_grow(drawn, 1)).sum())
                bloat[factor] += int((drawn & ~_grow(reach, 1)).sum())
    assert covered[1.0] > 50 and covered[5.0] > 0  # the part is seen: the sweep tests something
    assert holes == dict.fromkeys(holes, 0) and bloat == dict.fromkeys(bloat, 0), (holes, bloat, covered)


def test_an_alpha_cut_card_is_covered_where_its_texture_passes_the_cut_not_over_its_whole_square():
    """The exact coverage keeps the alpha cut (slab.frag's conservative cut, as the layers'): a card
    whose texture is opaque on a band (u from 1/8 to 1/2) and transparent elsewhere (its edges too:
    the renderers' repeat wrap reads across them), seen head-on in a frame, covers the band to
    within a texel and nothing of the rest beyond a texel, with one sample per texel or four."""
    from farfield.core.scene import SceneObject
    from farfield.core.techniques.octahedral.frames import Sphere, record_frames

    texture = np.zeros((64, 64, 4), np.uint8)
    texture[:, 8:32] = (200, 60, 40, 255)
    card = SceneObject(
        "leaf",
        np.array([[-1.0, 0.0, -1.0], [1.0, 0.0, -1.0], [1.0, 0.0, 1.0], [-1.0, 0.0, 1.0]]),
        np.array([[0, 1, 2], [0, 2, 3]]),
        uv=np.array([[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]]),
        texture=texture,
        alpha_cutoff=0.5,
    )
    sphere = Sphere(np.zeros(3), math.sqrt(2.0))
    # The frame looks along +y: its right is world +x (u = (x + 1) / 2), 16 texels over [-r, r].
    x = (np.arange(16) + 0.5) / 16 * 2 * sphere.radius - sphere.radius
    texel = 2 * sphere.radius / 16
    rows = np.abs(x)[:, None] < 1.0 - texel  # rows well inside the card
    band = (x > -0.75 + texel) & (x < -texel)
    clear = (x > texel) | (x < -0.75 - texel)
    for samples in (1, 2):
        covered = record_frames([card], sphere, np.array([[0.0, -1.0, 0.0]]), 16, samples=samples).colour[0, ..., 3] > 0
        assert covered[rows & band[None, :]].all(), samples
        assert not covered[:, clear].any(), samples


def test_sampled_coverage_is_the_fast_knob_that_loses_what_falls_between_the_samples():
    """``coverage=sampled`` skips the slab pass: the twentieth-of-a-texel twigs keep fewer texels
    (some fall between the samples), every texel it keeps the exact bake keeps too, and the option
    reaches the bake."""
    scene = twig(0.0065)
    technique = get_technique("octahedral")
    centre = 0.5 * (scene.bounds[0] + scene.bounds[1])
    kept = {}
    for coverage in ("exact", "sampled"):
        options = technique.options({"grid": 5, "frame_resolution": 16, "coverage": coverage}, RESOLUTION)
        impostor = technique.bake(scene, SphereOutsideCell(centre, 3.0, False), options, None, None)
        kept[coverage] = impostor.pages[0][..., 3] > 0
    assert (kept["sampled"] <= kept["exact"]).all()
    assert kept["exact"].sum() > kept["sampled"].sum()
    with pytest.raises(Exception, match="coverage"):
        technique.options({"coverage": "rough"}, RESOLUTION)
