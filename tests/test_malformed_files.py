"""Scene files that are wrong in ways a parser silently accepted (issue 59, item 12): each is refused
with a message naming what is wrong, not read as something else."""

from __future__ import annotations

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


def test_a_ply_declaring_more_elements_than_it_holds_is_refused():
    """Issue 59, item 12: a header declaring 2^31 faces over one face was accepted."""
    header = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
    body = "property list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    with pytest.raises(SceneLoadError, match="declares 2,147,483,648 face elements but the file holds 1"):
        load_scene_bytes((header + "element face 2147483648\n" + body).encode(), "ply", "liar.ply")
    assert load_scene_bytes((header + "element face 1\n" + body).encode(), "ply", "honest.ply").triangle_count == 1
