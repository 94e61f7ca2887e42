"""Sidedness (issue 54): one-sided objects are drawn and recorded as an engine shows them.

A conference room whose walls face inward, with a table inside, written as OBJ (which states no
sidedness: one-sided by default, as engines and three.js's OBJLoader draw it): from outside, an
engine culls the near wall's back and shows the room's inside through it; farfield's drawing of the
source and a layered impostor baked for a view cell outside the room show the same, and ``sides
both`` gives back the closed box farfield drew before.  A view cell inside the room sees the
walls.  The view-cell rule (:func:`farfield.core.sidedness.seen_from_cell`) keeps a triangle whose
plane cuts the cell, even one the reference viewpoint sees from behind, and drops one whose back
faces the whole cell.  The option reaches the loaders, the CLI and the upload route, and the same
bytes with the same option hash the same from disk and from an upload.
"""

from __future__ import annotations

import json
import math
import struct
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from fastapi.testclient import TestClient

from farfield.core.errors import SceneLoadError
from farfield.core.exchange import load_scene, load_scene_bytes
from farfield.core.exchange.export import scene_glb
from farfield.core.quality.evaluation import evaluate, impostor_renderer
from farfield.core.render.raster import Camera, MeshRenderer
from farfield.core.scene import Scene, SceneObject
from farfield.core.sidedness import faces_seen, seen_from_cell
from farfield.core.techniques.envmap.technique import EnvmapOptions, bake_envmap
from farfield.core.techniques.layered import BakeOptions, bake_layered
from farfield.core.viewcells import BoxCell, ShaftCell

# ------------------------------------------------------------------------------------ the room

HALF = 2.0  # the room is the cube of this half side around the origin; the table half a unit
OUTSIDE = BoxCell.from_center([9.0, 0.0, 0.0], 1.0)  # beyond the red wall (x = +2)
INSIDE = BoxCell.from_center([0.0, 1.3, 0.0], 0.4)  # between the table and the +y wall


def _face(axis: int, sign: int, half: float, inward: bool) -> np.ndarray:
    """(4, 3) corners of the cube's face on ``axis`` at ``sign``, counter-clockwise seen from the
    inside (``inward``) or from the outside."""
    u, v = (axis + 1) % 3, (axis + 2) % 3
    corners = np.zeros((4, 3))
    for k, (a, b) in enumerate(((-1, -1), (1, -1), (1, 1), (-1, 1))):
        corners[k, axis], corners[k, u], corners[k, v] = sign * half, a * half, b * half
    normal = np.cross(corners[1] - corners[0], corners[2] - corners[0])
    if np.sign(normal[axis]) != (-sign if inward else sign):
        corners = corners[::-1]
    return corners


def write_room(folder: Path) -> Path:
    """room.obj and room.mtl in ``folder``: the red wall at x = +2, the other five grey, all facing
    inward; a green table (a cube facing outward) in the middle."""
    lines, written = ["mtllib room.mtl"], 0
    pieces = {
        ("near_wall", "red"): [_face(0, 1, HALF, True)],
        ("walls", "grey"): [_face(a, s, HALF, True) for a in range(3) for s in (1, -1) if (a, s) != (0, 1)],
        ("table", "green"): [_face(a, s, 0.5, False) for a in range(3) for s in (1, -1)],
    }
    for (name, material), quads in pieces.items():
        lines += [f"o {name}", f"usemtl {material}"]
        for quad in quads:
            lines += ["v {:.6f} {:.6f} {:.6f}".format(*p) for p in quad]
            lines += [f"f {written + 1} {written + 2} {written + 3}", f"f {written + 1} {written + 3} {written + 4}"]
            written += 4
    (folder / "room.mtl").write_text("newmtl red\nKd 1 0 0\nnewmtl grey\nKd 0.5 0.5 0.5\nnewmtl green\nKd 0 1 0\n")
    path = folder / "room.obj"
    path.write_text("\n".join(lines) + "\n")
    return path


def colours(image: np.ndarray) -> dict[str, int]:
    """Drawn pixels (or texels) of ``image`` (..., 4) uint8 by the room's colours."""
    drawn = image[..., 3] > 0
    r, g = image[..., 0].astype(int), image[..., 1].astype(int)
    return {
        "red": int((drawn & (r > 200) & (g < 60)).sum()),
        "green": int((drawn & (g > 200) & (r < 60)).sum()),
        "grey": int((drawn & (np.abs(r - g) < 10) & (r > 60) & (r < 200)).sum()),
    }


def outside_camera() -> Camera:
    """From the outside cell's centre region, looking at the room through its red wall."""
    return Camera.look_at([9.0, 0.3, 0.2], [0.0, 0.0, 0.0], math.radians(40.0), 64, 0.5, 20.0)


@pytest.fixture(scope="module")
def room(tmp_path_factory) -> Path:
    return write_room(tmp_path_factory.mktemp("room"))


def test_obj_ply_and_stl_are_one_sided_by_default_and_both_sided_on_request(room, tmp_path):
    one, both = load_scene(room), load_scene(room, sides="both")
    assert [o.double_sided for o in one.objects] == [False] * 3
    assert [o.double_sided for o in both.objects] == [True] * 3
    # "both" is what farfield read before: double-sided objects hash as they did, one-sided ones apart
    assert (
        both.content_hash
        == Scene.from_objects(
            [SceneObject(o.name, o.vertices, o.faces, base_color=o.base_color) for o in both.objects], "x"
        ).content_hash
    )
    assert one.content_hash != both.content_hash
    mesh = one.objects[0]
    import trimesh

    for extension in ("ply", "stl"):
        path = tmp_path / f"wall.{extension}"
        trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).export(path)
        assert not load_scene(path).objects[0].double_sided
        assert load_scene(path, sides="both").objects[0].double_sided
    with pytest.raises(SceneLoadError, match="sides must be 'one' or 'both', got 'two'"):
        load_scene(room, sides="two")


def test_gltf_follows_its_own_flag_not_the_option(tmp_path):
    scene = Scene.from_objects([SceneObject("a", np.eye(3), [[0, 1, 2]])], "a")
    path = tmp_path / "a.glb"
    path.write_bytes(scene_glb(scene))
    assert load_scene(path, sides="one").content_hash == load_scene(path, sides="both").content_hash


def test_the_same_bytes_and_option_hash_the_same_from_disk_and_from_bytes(room):
    assets = {"room.mtl": (room.parent / "room.mtl").read_bytes()}
    for sides in ("one", "both"):
        from_bytes = load_scene_bytes(room.read_bytes(), "obj", room.name, assets, sides=sides)
        assert from_bytes.content_hash == load_scene(room, sides=sides).content_hash


def test_farfield_draws_the_room_from_outside_as_an_engine_does(room, gl):
    camera = outside_camera()
    with MeshRenderer(load_scene(room).objects) as renderer:
        seen = colours(renderer.render(camera))
    # the red wall's back is culled: the table and the far walls' insides show through it
    assert seen["red"] == 0 and seen["green"] > 50 and seen["grey"] > 1000
    with MeshRenderer(load_scene(room, sides="both").objects) as renderer:
        closed = colours(renderer.render(camera))
    assert closed["red"] > 2000 and closed["green"] == 0  # sides both: the closed box of before
    assert gl.error == "GL_NO_ERROR"


def test_a_layered_impostor_from_outside_shows_the_inside_of_the_room(room, gl):
    camera = outside_camera()
    scene = load_scene(room)
    impostor = bake_layered(scene, OUTSIDE, BakeOptions(resolution=64))
    assert all(colours(page)["red"] == 0 for page in impostor.pages)  # the red wall is not recorded
    with impostor_renderer(impostor) as renderer:
        seen = colours(renderer.render(camera))
    assert seen["red"] == 0 and seen["green"] > 50 and seen["grey"] > 1000
    # and the evaluation, which draws the source one-sided too, finds no hole
    result = evaluate(scene, impostor, OUTSIDE, random_count=2, outside_count=0, seed=0)
    assert result.totals["hole_pixels"] == 0
    closed = bake_layered(load_scene(room, sides="both"), OUTSIDE, BakeOptions(resolution=64))
    with impostor_renderer(closed) as renderer:
        seen = colours(renderer.render(camera))
    assert seen["red"] > 2000 and seen["green"] == 0


def test_a_cell_inside_the_room_sees_its_walls(room, gl):
    scene = load_scene(room)
    kept = {o.name: o.triangle_count for o in seen_from_cell(scene.objects, INSIDE)}
    assert kept == {"near_wall": 2, "walls": 10, "table": 2}  # every wall; of the table its top (+y) only
    camera = Camera.look_at(INSIDE.center, [2.0, 1.3, 0.0], math.radians(60.0), 64, 0.05, 20.0)
    with MeshRenderer(scene.objects) as renderer:
        assert colours(renderer.render(camera))["red"] > 2000
    impostor = bake_envmap(scene, INSIDE, EnvmapOptions(resolution=64, layers=4))
    recorded = [colours(page) for page in impostor.pages]
    assert sum(c["red"] for c in recorded) > 0 and sum(c["grey"] for c in recorded) > 0


# ------------------------------------------------------------------------- the view-cell rule


def _plate(name: str, z: float, up: bool, colour, double_sided: bool) -> SceneObject:
    """A 4 x 2 plate in the plane at height ``z``, at y 3..5, facing up (+z) or down."""
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    vertices = np.array([[-2.0, 3.0, z], [2.0, 3.0, z], [2.0, 5.0, z], [-2.0, 5.0, z]])
    return SceneObject(name, vertices, faces if up else faces[:, ::-1], base_color=colour, double_sided=double_sided)


def test_a_triangle_whose_plane_cuts_the_cell_is_recorded_one_behind_the_whole_cell_is_not(gl):
    cell = BoxCell([-1.0, -1.0, -1.0], [1.0, 1.0, 1.0])

    def recorded(double_sided: bool) -> dict[str, int]:
        scene = Scene.from_objects(
            [
                # its plane (z = 0.5) cuts the cell: the cell's top sees its front, the reference
                # viewpoint (the cell's centre, z = 0) its back
                _plate("cut", 0.5, True, (1.0, 0.0, 0.0, 1.0), double_sided),
                # its plane (z = -1.5) lies below the cell and it faces down: the whole cell is behind it
                _plate("behind", -1.5, False, (0.0, 0.0, 1.0, 1.0), double_sided),
            ],
            "plates",
        )
        impostor = bake_layered(scene, cell, BakeOptions(resolution=64))
        texels = np.concatenate([page.reshape(-1, 4) for page in impostor.pages])
        drawn = texels[:, 3] > 0
        return {
            "red": int((drawn & (texels[:, 0] > 200) & (texels[:, 2] < 60)).sum()),
            "blue": int((drawn & (texels[:, 2] > 200) & (texels[:, 0] < 60)).sum()),
        }

    one = recorded(False)
    assert one["red"] > 1000 and one["blue"] == 0
    both = recorded(True)
    assert both["red"] == one["red"] and both["blue"] > 1000


def test_faces_seen_tests_every_corner_with_a_tolerance():
    vertices = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    up, down = np.array([[0, 1, 2]]), np.array([[0, 2, 1]])
    above = BoxCell([0.0, 0.0, 1.0], [1.0, 1.0, 2.0]).corners()
    across = BoxCell([0.0, 0.0, -1.0], [1.0, 1.0, 1.0]).corners()
    touching = BoxCell([0.0, 0.0, -1.0], [1.0, 1.0, 0.0]).corners()  # its top face lies on the plane
    assert faces_seen(vertices, up, above).tolist() == [True]
    assert faces_seen(vertices, down, above).tolist() == [False]
    assert faces_seen(vertices, down, across).tolist() == [True]
    assert faces_seen(vertices, up, touching).tolist() == [True]  # edge-on from the cell's top
    # far from the origin, a cell a rounding error behind the plane still counts as on it
    far = np.array([1e6, -2e6, 3e5])
    assert faces_seen(vertices + far, up, touching + far - [0.0, 0.0, 1e-9]).tolist() == [True]
    assert faces_seen(vertices + far, up, touching + far - [0.0, 0.0, 1e-2]).tolist() == [False]


def test_an_unbounded_shaft_reaches_the_front_of_a_plane_it_runs_towards():
    # a triangle in the plane z = 0 facing down (-z)
    wall = SceneObject(
        "wall", np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]), [[0, 2, 1]], double_sided=False
    )
    up = ShaftCell([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], math.radians(30.0), 5.0)  # above the plane, opening upward
    assert seen_from_cell([wall], up) == ()
    # a horizontal shaft above the plane: its near cap is behind the wall, but its lower edges run
    # down through the plane, so viewpoints far along them are in front of it
    sideways = ShaftCell([0.0, 0.0, 3.0], [1.0, 0.0, 0.0], math.radians(60.0), 1.0)
    assert np.all(sideways.corners()[:, 2] > 0.0)
    assert seen_from_cell([wall], sideways)[0].triangle_count == 1
    # ended before it reaches the plane, it sees nothing of the wall's front
    assert seen_from_cell([wall], ShaftCell([0.0, 0.0, 3.0], [1.0, 0.0, 0.0], math.radians(60.0), 1.0, 2.0)) == ()


def test_double_sided_objects_pass_the_view_cell_rule_untouched():
    objects = (SceneObject("a", np.eye(3), [[0, 1, 2]]), SceneObject("b", np.eye(3) + 1, [[0, 2, 1]]))
    kept = seen_from_cell(objects, BoxCell([5.0, 5.0, 5.0], [6.0, 6.0, 6.0]))
    assert all(a is b for a, b in zip(kept, objects, strict=True))


def test_one_camera_culls_by_the_eye_side_whatever_the_frame(gl):
    """A mirroring frame (right negated) flips the image's winding; the renderer flips its front face."""
    tri = SceneObject(
        "t", np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]]), [[0, 1, 2]], double_sided=False
    )
    with MeshRenderer([tri]) as renderer:
        for z, visible in ((5.0, True), (-5.0, False)):
            camera = Camera.look_at([0.1, 0.2, z], [0.0, 0.0, 0.0], math.radians(60.0), 32, 0.1, 20.0)
            mirrored = Camera(camera.eye, -camera.right, camera.up, camera.forward, camera.fov, 32, 0.1, 20.0)
            for cam in (camera, mirrored, camera.window(4.0, 4.0, 24.0, 16)):
                assert (renderer.render(cam)[..., 3] > 0).any() == visible
        assert renderer.ctx.front_face == "ccw"
    assert gl.error == "GL_NO_ERROR"


# ------------------------------------------------------------------------ exports, CLI, upload


def test_an_exported_glb_keeps_each_objects_sidedness_vertex_coloured_ones_too():
    colours_ = np.array([[255, 0, 0, 255], [0, 255, 0, 255], [0, 0, 255, 255]], np.uint8)
    scene = Scene.from_objects(
        [
            SceneObject("one", np.eye(3), [[0, 1, 2]], vertex_colors=colours_, double_sided=False),
            SceneObject("two", np.eye(3) + 1, [[0, 1, 2]], vertex_colors=colours_),
            SceneObject("plain", np.eye(3) + 2, [[0, 1, 2]], double_sided=False),
        ],
        "s",
    )
    data = scene_glb(scene)
    (length,) = struct.unpack_from("<I", data, 12)
    document = json.loads(data[20 : 20 + length])
    sided = {m["name"]: m["doubleSided"] for m in document["materials"]}
    assert sided == {"one_material": False, "two_material": True, "plain_material": False}
    assert all("COLOR_0" in mesh["primitives"][0]["attributes"] for mesh in document["meshes"][:2])


def test_the_cli_takes_the_option(room):
    from farfield.cli.inspect_cmd import inspect
    from farfield.cli.main import cli

    cli.add_command(inspect)  # only the command this test runs, as tests/test_cli_inspect.py does
    runner = CliRunner()
    one = json.loads(runner.invoke(cli, ["inspect", str(room), "--json"]).output)
    both = json.loads(runner.invoke(cli, ["inspect", str(room), "--json", "--sides", "both"]).output)
    assert {o["double_sided"] for o in one["objects"]} == {False}
    assert {o["double_sided"] for o in both["objects"]} == {True}
    assert one["content_hash"] == load_scene(room).content_hash != both["content_hash"]
    refused = runner.invoke(cli, ["inspect", str(room), "--sides", "two"])
    assert refused.exit_code == 2 and "'two' is not one of 'one', 'both'" in refused.output


KEY = "ff-test-sidedness-key-0123456789"


@pytest.fixture(scope="module")
def api(tmp_path_factory):
    from farfield.api.app import create_app
    from farfield.service.settings import Settings

    home = tmp_path_factory.mktemp("sidedness")
    settings = Settings.from_env(
        {"FARFIELD_HOME": str(home), "REDIS_URL": "redis://127.0.0.1:1/0", "FARFIELD_ADMIN_KEY": KEY}
    )
    with TestClient(create_app(settings), headers={"Authorization": f"Bearer {KEY}"}) as client:
        yield client


@pytest.mark.slow
def test_the_upload_takes_the_option_and_hashes_as_the_disk_does(api, room):
    from farfield.service.db import SceneRow
    from farfield.service.scenes import load_stored_scene

    files = [("file", (room.name, room.read_bytes())), ("file", ("room.mtl", (room.parent / "room.mtl").read_bytes()))]
    made = {}
    for sides in (None, "one", "both"):
        response = api.post("/v1/scenes", files=files, data={} if sides is None else {"sides": sides})
        assert response.status_code == 201, response.text
        made[sides] = response.json()
        assert made[sides]["sides"] == (sides or "one")
        assert made[sides]["content_hash"] == load_scene(room, sides=sides or "one").content_hash
    assert made[None]["content_hash"] == made["one"]["content_hash"] != made["both"]["content_hash"]
    # a worker loads the stored file with the row's option again: the same scene
    svc = api.app.state.services
    with svc.db.session() as s:
        row = s.get(SceneRow, made["both"]["id"])
    assert load_stored_scene(svc.blobs, row).content_hash == made["both"]["content_hash"]
    refused = api.post("/v1/scenes", files=files, data={"sides": "two"})
    assert refused.status_code == 422
    assert "sides must be 'one' or 'both', got 'two'" in refused.json()["detail"]
