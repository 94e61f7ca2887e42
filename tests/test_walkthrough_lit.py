"""The lit walkthrough: the environment-map reference runtime draws its impostors lit (the near
field's and the quads' G-buffers, the quads with their normal pages), frame by frame against the
full scene lit by the same lights (issue 55, item 5).

The scene: the procedural city, 36 buildings; two cubic cells of 4 m at street level where two
streets cross, the same bake with and without the normal channel (64 px, 6 layers, the four
horizontal faces).  A
sun high in the sky lights what the cells see of the far field (roofs, the ground and the walls
facing it), where flat cards (vertical quads, each lit by its own normal) cannot stand in for the
roofs and the ground.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from farfield.cli.main import _register, cli
from farfield.core.impostor.database import INDEX_NAME, ImpostorDatabase, write_database
from farfield.core.procedural import city
from farfield.core.quality.lighting import default_lights, shade, sun, view_directions
from farfield.core.quality.walkthrough import generate_path, walkthrough
from farfield.core.render.context import gl_context
from farfield.core.render.deferred import DeferredShader
from farfield.core.render.raster import Camera, MeshRenderer
from farfield.core.techniques.envmap.technique import EnvmapOptions, bake_envmap
from farfield.core.viewcells import grid_boxes
from tests.scenes import write_scene

pytestmark = pytest.mark.filterwarnings("ignore::farfield.core.scene.SceneWarning")

OPTIONS = dict(resolution=64, fov_deg=90.0, layers=6, directions=("+x", "-x", "+z", "-z"))
SUN = sun(60.0, 60.0)  # high: on the roofs and the ground the cells see, and on walls facing +x and -z
FRAMES = 6


@pytest.fixture(scope="module")
def scene():
    return city(36)


@pytest.fixture(scope="module")
def databases(scene, tmp_path_factory):
    """{channels: database folder} for the same two cells baked with and without normal pages."""
    root = tmp_path_factory.mktemp("lit-walk")
    boxes = grid_boxes([26.0, 0.5, 28.0], [34.0, 4.5, 32.0], [2, 1, 1])
    return {
        channels: write_database(
            root / channels.replace("+", "-"),
            "envmap",
            {},
            [(list(ijk), bake_envmap(scene, box, EnvmapOptions(**OPTIONS, channels=channels))) for ijk, box in boxes],
        )
        for channels in ("albedo+normal", "albedo")
    }


def walk(scene, folder, lights):
    with ImpostorDatabase(folder) as db:
        positions, forwards = generate_path(db, FRAMES)
        return walkthrough(scene, db, positions, forwards, repeats=1, lights=lights)


def test_normal_pages_light_the_far_field_closer_than_flat_cards(scene, databases):
    lit = walk(scene, databases["albedo+normal"], (SUN,))
    cards = walk(scene, databases["albedo"], (SUN,))
    unlit = walk(scene, databases["albedo+normal"], None)
    s, c = lit["summary"]["lit"], cards["summary"]["lit"]
    assert s["frames_lit"] == c["frames_lit"] == FRAMES == lit["summary"]["frames_served"]
    assert lit["summary"]["cell_switches"] >= 1
    # The lit draw leaves the unlit figures as they were, frame by frame.
    for a, b in zip(lit["frames"], unlit["frames"]):
        assert a["colour_error_mean"] == b["colour_error_mean"] and "lit" not in b
    assert "lit" not in unlit["summary"]
    # With normal pages: no frame is drawn as flat cards, and no note says so.
    assert s["frames_flat_cards"] == 0 and "note" not in s
    assert all(f["lit"]["normals"] for f in lit["frames"])
    # Where the impostor draws (the far field), its lit error is a fraction of the flat cards',
    # the same cards that the database without normal pages draws.
    far, far_cards = s["far"]["lights"][0], c["far"]["lights"][0]
    assert far["lit_error_mean"] < 0.4 * far_cards["lit_error_mean"], (far, far_cards)
    assert far["lit_error_mean"] < 0.4 * far["flat_error_mean"]
    assert far_cards["lit_error_mean"] == pytest.approx(far_cards["flat_error_mean"])
    assert s["far"]["normal_error_interior_median"] < 2.0 < 20.0 < s["far"]["flat_normal_error_median"]
    # The whole frame holds the near field, the same geometry on both sides: smaller errors, same order.
    assert s["lights"][0]["lit_error_mean"] < c["lights"][0]["lit_error_mean"]
    assert s["lights"][0]["lit_error_mean"] <= far["lit_error_mean"]
    # Without normal pages the database is drawn as flat cards, and the summary says so.
    assert c["frames_flat_cards"] == FRAMES and "flat cards" in c["note"]
    assert not any(f["lit"]["normals"] for f in cards["frames"])
    # Times: the G-buffer draws (GL) and the numpy shading, each per frame.
    for f in lit["frames"]:
        assert f["lit"]["impostor_gbuffer_ms"] > 0 and f["lit"]["full_gbuffer_ms"] > 0 and f["lit"]["shade_ms"] > 0
        assert f["lit"]["shade_gl_ms"] > 0
    assert s["sources"][0]["direction"] == pytest.approx(SUN.direction.tolist())


def test_cli_lit_walkthrough(scene, databases, tmp_path):
    scene_file = write_scene(scene, tmp_path, "glb", "city")
    folder = str(databases["albedo+normal"])
    _register()
    runner = CliRunner()
    common = ["walkthrough", folder, str(scene_file), "--frames", "2", "--repeats", "1"]
    run = runner.invoke(cli, [*common, "--lit", "--light-azimuth", "60", "--light-elevation", "60", "--json"])
    assert run.exit_code == 0, run.output
    data = json.loads(run.output)
    lit = data["summary"]["lit"]
    assert {"sources", "frames_lit", "frames_flat_cards", "lights", "far", "impostor_gbuffer_ms_mean",
            "full_gbuffer_ms_mean", "shade_ms_mean", "shade_gl_ms_mean", "lit_to_unlit_worst", "flat_to_lit_least"} <= set(lit)  # fmt: skip
    assert np.allclose(lit["sources"][0]["direction"], SUN.direction) and len(lit["lights"]) == 1
    frame = data["frames"][0]["lit"]
    assert {"normals", "lit_error_mean", "flat_error_mean", "far_lit_error_mean", "far_flat_error_mean",
            "impostor_gbuffer_ms", "full_gbuffer_ms", "shade_ms", "shade_gl_ms", "stats", "far_stats"} <= set(frame)  # fmt: skip
    # The five test lights by default; the table, the lit totals and a plot.
    plot = tmp_path / "lit.png"
    run = runner.invoke(cli, [*common, "--lit", "--plot", str(plot)])
    assert run.exit_code == 0, run.output
    assert "far lit" in run.output and "far field" in run.output and run.output.count("(+0.00, +1.00, +0.00)") == 2
    assert "G-buffer draw" in run.output and "note:" not in run.output and plot.stat().st_size > 0
    # A database without normal pages is drawn as flat cards, with a note, not an error.
    run = runner.invoke(cli, ["walkthrough", str(databases["albedo"]), str(scene_file), "--frames", "2",
                              "--repeats", "1", "--lit"])  # fmt: skip
    assert run.exit_code == 0, run.output
    assert "note: 2 of 2 frames" in run.output and "flat cards" in run.output
    # Usage errors: a light without --lit, an elevation past the zenith, a placement database.
    assert runner.invoke(cli, [*common, "--light-azimuth", "30"]).exit_code == 2
    assert runner.invoke(cli, [*common, "--lit", "--light-elevation", "95"]).exit_code == 2
    placement = tmp_path / "placement"
    placement.mkdir()
    index = json.loads((databases["albedo"] / INDEX_NAME).read_text())
    (placement / INDEX_NAME).write_text(json.dumps(index | {"kind": "placement", "placement": {"parameters": {}}}))
    run = runner.invoke(cli, ["walkthrough", str(placement), str(scene_file), "--lit"])
    assert run.exit_code == 2 and "colour-only" in run.output


@pytest.mark.parametrize("roughness, metallic", [(1.0, 0.0), (0.3, 0.5)])
def test_the_shading_pass_lights_as_shade_does(scene, roughness, metallic):
    """The GL's deferred pass (what the walkthrough times) and numpy's ``shade`` (what it measures
    with) agree to a level on the city's G-buffer, under every test light."""
    camera = Camera.look_at(np.array([30.0, 3.0, 30.0]), np.array([80.0, 12.0, 70.0]), np.radians(90.0), 64, 0.1, 500.0)
    with MeshRenderer(scene.objects, normals=True) as renderer, DeferredShader(64, roughness, metallic) as deferred:
        image, normals = renderer.render_normals(camera)
        deferred.load(image, normals)
        for light in default_lights():
            expected = shade(
                image[..., :3], normals, view_directions(camera), light, roughness=roughness, metallic=metallic
            )
            got = deferred.shade(camera, light)
            difference = np.abs(expected.astype(np.int16) - got.astype(np.int16)).max(axis=-1)
            assert difference.max() <= 1 and (difference > 0).mean() < 0.01, (light.direction, difference.max())
        assert deferred.frame_seconds(camera, light) > 0
        with pytest.raises(ValueError, match="64 x 64"):
            deferred.load(image[:32], normals)
    assert deferred._owned == [] and gl_context().error == "GL_NO_ERROR"
