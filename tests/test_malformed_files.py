"""Scene files that are wrong in ways a parser silently accepted (issue 59, item 12): each is refused
with a message naming what is wrong, not read as something else."""

from __future__ import annotations

import numpy as np
import pytest

from farfield.core.errors import SceneLoadError
from farfield.core.exchange import load_scene_bytes


def test_an_obj_face_with_the_index_0_is_refused_by_line():
    """Issue 59, item 12: OBJ counts vertices from 1; trimesh read 0 as the last vertex, a silent
    wrong triangle.  Negative (relative) indices stay valid."""
    obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf -1 -2 -3\nf 0 1 2\n"
    with pytest.raises(SceneLoadError, match=r"line 7: 'f 0 1 2' has the index 0"):
        load_scene_bytes(obj.encode(), "obj", "zero.obj")
    assert load_scene_bytes(obj.rsplit("f 0", 1)[0].encode(), "obj", "fine.obj").triangle_count == 2


def test_obj_relative_indices_count_back_from_the_face_not_from_the_end_of_the_file():
    """``f -3 -2 -1`` names the last three vertices read before it (the specification; three.js):
    trimesh counted back from the end of the file, so two objects written one after the other were
    the second one twice.  Texture coordinates and normals alike; one before the first is refused."""
    obj = (
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvn 0 0 1\no first\nf -3/-3/-1 -2/-2/-1 -1/-1/-1\n"
        "v 5 0 0\nv 6 0 0\nv 5 1 0\nvt 0.5 0.5\nvn 0 0 -1\no second\nf -3/-1/-1 -1/-1/-1 -2/-1/-1\n"
    )
    scene = load_scene_bytes(obj.encode(), "obj", "relative.obj")
    first, second = (scene.subset([name]).objects[0] for name in ("first", "second"))
    np.testing.assert_array_equal(first.vertices[first.faces[0]], [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    np.testing.assert_array_equal(second.vertices[second.faces[0]], [[5, 0, 0], [5, 1, 0], [6, 0, 0]])
    np.testing.assert_allclose(first.normals, [[0, 0, 1]] * 3)
    np.testing.assert_allclose(second.normals, [[0, 0, -1]] * 3)
    with pytest.raises(SceneLoadError, match=r"line 3: 'f -3 -2 -1' names vertex \(v\) -3, but only 2 v lines"):
        load_scene_bytes(b"v 0 0 0\nv 1 0 0\nf -3 -2 -1\nv 0 1 0\nf 1 2 3\n", "obj", "before.obj")


@pytest.mark.parametrize(
    "face, named",
    [
        ("f 1 2 4", "vertex \\(v\\) 4, but the file has 3 v lines"),
        ("f -4 -2 -1", "vertex \\(v\\) -4, but the file has 3 v lines"),
    ],
)
def test_an_obj_face_beyond_the_vertices_is_refused_by_line(face, named):
    """trimesh's parse failed with numpy's 'index 3 is out of bounds for axis 0 with size 3', which
    named neither the face nor its line."""
    obj = f"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n{face}\n"
    with pytest.raises(SceneLoadError, match=rf"line 5: '{face}' names {named}"):
        load_scene_bytes(obj.encode(), "obj", "beyond.obj")


def test_a_ply_declaring_more_elements_than_it_holds_is_refused():
    """Issue 59, item 12: a header declaring 2^31 faces over one face was accepted."""
    header = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
    body = "property list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    with pytest.raises(SceneLoadError, match="declares 2,147,483,648 face elements but the file holds 1"):
        load_scene_bytes((header + "element face 2147483648\n" + body).encode(), "ply", "liar.ply")
    assert load_scene_bytes((header + "element face 1\n" + body).encode(), "ply", "honest.ply").triangle_count == 1


def test_a_truncated_ascii_ply_with_crlf_lines_is_refused_not_read_short():
    """The Stanford bunny's header has CRLF lines, which the header's element counts were not read
    from: cut at 2,000,000 of its 3,138,605 bytes it loaded as 16,490 of its 69,451 triangles with
    no warning, and cut mid-line it failed with numpy's 'setting an array element with a sequence'."""
    header = (
        "ply\r\nformat ascii 1.0\r\nelement vertex 4\r\nproperty float x\r\nproperty float y\r\n"
        "property float z\r\nelement face 2\r\nproperty list uchar int vertex_indices\r\nend_header\r\n"
    )
    body = "0 0 0\r\n1 0 0\r\n0 1 0\r\n1 1 0\r\n3 0 1 2\r\n3 1 3 2\r\n"
    assert load_scene_bytes((header + body).encode(), "ply", "whole.ply").triangle_count == 2
    for cut in (len(body) - len("3 1 3 2\r\n"), len(body) - len("3 0 1 2\r\n3 1 3 2\r\n") - 3):
        with pytest.raises(SceneLoadError, match=r"declares 2 face elements but the file holds [01] \(truncated"):
            load_scene_bytes((header + body[:cut]).encode(), "ply", "cut.ply")


def test_a_truncated_binary_ply_is_refused_naming_the_header():
    header = (
        b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        b"property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
    )
    body = np.array([0, 0, 0, 1, 0, 0, 0, 1, 0], "<f4").tobytes() + b"\x03" + np.array([0, 1, 2], "<i4").tobytes()
    assert load_scene_bytes(header + body, "ply", "whole.ply").triangle_count == 1
    with pytest.raises(SceneLoadError, match="not the length the header's 3 vertex and 1 face elements need"):
        load_scene_bytes(header + body[:-5], "ply", "cut.ply")


def test_an_ascii_ply_cut_inside_its_last_line_is_refused():
    """Cut inside its last face line, an ASCII PLY still holds as many lines as its header declares;
    it loaded with the cut face's remaining indices."""
    header = (
        "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 2\nproperty list uchar int vertex_indices\nproperty uchar red\nend_header\n"
    )
    body = "0 0 0\n1 0 0\n0 1 0\n1 1 0\n3 0 1 2 9\n3 1 3 2 9\n"
    assert load_scene_bytes((header + body).encode(), "ply", "whole.ply").triangle_count == 2
    assert load_scene_bytes((header + body.rstrip("\n")).encode(), "ply", "no-final-newline.ply").triangle_count == 2
    for cut, values, needed in ((2, 4, 5), (5, 3, 5), (7, 2, 5), (9, 1, 5)):
        with pytest.raises(
            SceneLoadError, match=f"last face element has {values} values where its properties need {needed}"
        ):
            load_scene_bytes((header + body[: len(body) - cut]).encode(), "ply", "cut.ply")
    vertices_only = (
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
    )
    with pytest.raises(SceneLoadError, match="last vertex element has 2 values where its properties need 3"):
        load_scene_bytes((vertices_only + "0 0 0\n1 0").encode(), "ply", "cloud.ply")


@pytest.mark.parametrize("face", ["f -0 2 3", "f 1 -0 3\nv 5 5 5"])
def test_an_obj_index_minus_0_is_refused_like_0(face):
    """``-0`` counts back no vertex (as 0 names none): trimesh read it as the last vertex of the
    file, and the relative indices' rewrite (where a ``v`` line follows) as the one after the face's
    last, a silent wrong triangle either way."""
    obj = f"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n{face}\n"
    with pytest.raises(SceneLoadError, match=r"line 5: .* has the index 0"):
        load_scene_bytes(obj.encode(), "obj", "minus-zero.obj")


def test_an_obj_polygon_index_too_large_for_an_integer_is_refused_not_an_internal_error():
    """A concave polygon's corner index beyond 64 bits made the ear clipping's scan raise numpy's
    OverflowError (an internal error, not a 4xx) before trimesh's parse could name the problem."""
    obj = "v 0 0 0\nv 2 0 0\nv 2 1 0\nv 1 1 0\nv 1 2 0\nv 0 2 0\nf 2 3 4 5 6 99999999999999999999999\n"
    with pytest.raises(SceneLoadError, match=r"line 7: 'f 2 3 4 5 6 9+' names vertex \(v\) 9+, but the file has 6"):
        load_scene_bytes(obj.encode(), "obj", "huge.obj")


def test_an_obj_face_beyond_the_vertices_is_named_by_its_line_with_several_material_libraries():
    """With several ``mtllib`` the text trimesh parses has one library line in front: the line
    named was one past the face's."""
    obj = "mtllib a.mtl b.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 9\n"
    assets = {"a.mtl": b"newmtl a\nKd 1 0 0\n", "b.mtl": b"newmtl b\nKd 0 1 0\n"}
    with pytest.raises(SceneLoadError, match=r"line 6: 'f 1 2 9' names vertex \(v\) 9"):
        load_scene_bytes(obj.encode(), "obj", "libraries.obj", assets=assets)
