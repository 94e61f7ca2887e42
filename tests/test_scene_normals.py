"""Shading normals as each loader reads them (glTF NORMAL, OBJ vn, PLY nx ny nz): moved by the inverse
transpose of the node transform, repaired where zero, carried by subsets, and hashed."""

from __future__ import annotations

import io
import struct
import warnings

import numpy as np
import PIL.Image
import pytest
from gltf_files import ELEMENT_ARRAY_BUFFER, USHORT, GltfBuilder

from farfield.core import procedural
from farfield.core.errors import SceneLoadError
from farfield.core.exchange import load_scene_bytes
from farfield.core.exchange.normals import normal_matrix, repair_normals
from farfield.core.placement.hierarchy import Elements
from farfield.core.scene import Scene, SceneObject, SceneWarning, object_hash


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _quaternion(axis, angle: float) -> list[float]:
    axis = _unit(axis)
    return [*(axis * np.sin(angle / 2)).tolist(), float(np.cos(angle / 2))]


def _rotation(axis, angle: float) -> np.ndarray:
    """(3, 3) rotation matrix (Rodrigues), independent of the reader's quaternion code."""
    x, y, z = _unit(axis)
    k = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def _analytic(normals, linear) -> np.ndarray:
    """The textbook rule, by an explicit inverse: n' = normalize(inv(L)^T n)."""
    return _unit(np.asarray(normals, dtype=np.float64) @ np.linalg.inv(linear))


def _glb(builder: GltfBuilder):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = load_scene_bytes(builder.glb(), "glb", "t.glb")
    return scene, [w for w in caught if issubclass(w.category, SceneWarning)]


def _face_normals(obj: SceneObject) -> np.ndarray:
    c = obj.vertices[obj.faces]
    return _unit(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]))


# Four distinct, non-axis normals for the four corners of GltfBuilder.quad, exact in float32 (as stored).
TILTED = (
    _unit([[0.3, 0.1, 1.0], [-0.4, 0.2, 1.0], [0.1, -0.5, 1.0], [0.6, 0.6, 0.8]]).astype(np.float32).astype(np.float64)
)


# --- glTF ---------------------------------------------------------------------------------------------


def test_gltf_without_normal_is_flat():
    b = GltfBuilder()
    b.quad("q", [0, 0, 0], 1.0, b.material())
    scene, _ = _glb(b)
    assert scene.objects[0].normals is None


def test_gltf_normals_follow_non_uniform_scale_rotation_and_parents():
    b = GltfBuilder()
    m = b.material()
    axis, angle, scale = [1.0, 2.0, 0.5], 0.7, [3.0, 0.5, 1.5]
    child = b.quad(
        "scaled", [0, 0, 0], 1.0, m, normals=TILTED, root=False, rotation=_quaternion(axis, angle), scale=scale
    )
    b.node(name="parent", children=[child], scale=[1.0, 2.0, 1.0], translation=[5.0, 0.0, 0.0])
    scene, caught = _glb(b)
    obj = scene.objects[0]
    linear = np.diag([1.0, 2.0, 1.0]) @ _rotation(axis, angle) @ np.diag(scale)
    expected = _analytic(TILTED, linear)
    np.testing.assert_allclose(obj.normals, expected, atol=1e-12)
    # Not merely the rotated normals: the scale tilts them (a plain rotation would be wrong here).
    assert np.abs(obj.normals - _unit(TILTED @ (linear / np.cbrt(np.linalg.det(linear))).T)).max() > 0.05
    np.testing.assert_allclose(np.linalg.norm(obj.normals, axis=1), 1.0, atol=1e-15)
    assert not caught


@pytest.mark.parametrize("diagonal", [[-1.0, 1.0, 1.0], [2.0, -0.5, 1.0], [-1.0, -1.0, -3.0]])
def test_gltf_mirrored_node_keeps_normals_on_the_front_of_its_reversed_winding(diagonal):
    b = GltfBuilder()
    linear = _rotation([0.2, 1.0, 0.3], 0.9) @ np.diag(diagonal)
    matrix = np.eye(4)
    matrix[:3, :3] = linear
    flat = np.tile([0.0, 0.0, 1.0], (4, 1))  # the quad's own face normal (+z, counter-clockwise)
    b.quad("mirror", [0, 0, 0], 1.0, b.material(), normals=flat, matrix=matrix.T.ravel().tolist())
    b.quad("tilted", [2, 0, 0], 1.0, b.material(), normals=TILTED, matrix=matrix.T.ravel().tolist())
    scene, _ = _glb(b)
    mirror, tilted = scene.objects
    assert np.linalg.det(linear) < 0
    # The geometric front: the reader reversed the faces, and the normals point to where they face.
    np.testing.assert_allclose(mirror.normals, np.repeat(_face_normals(mirror)[:1], 4, axis=0), atol=1e-12)
    np.testing.assert_allclose(tilted.normals, _analytic(TILTED, linear), atol=1e-12)


@pytest.mark.parametrize("dtype, top", [(np.int8, 127), (np.int16, 32767)])
def test_gltf_quantized_normals(dtype, top):
    stored = np.array([[0, 0, top], [0, top // 2, top // 2], [top, 0, 0], [-top, -top, 0]], dtype=dtype)
    b = GltfBuilder()
    b.quad("q", [0, 0, 0], 1.0, b.material(), normals=stored, rotation=_quaternion([0, 0, 1], np.pi / 2))
    scene, _ = _glb(b)
    decoded = np.maximum(stored / top, -1.0)  # glTF §3.11 signed normalized
    np.testing.assert_allclose(
        scene.objects[0].normals, _analytic(decoded, _rotation([0, 0, 1], np.pi / 2)), atol=1e-12
    )


def test_gltf_sparse_normals():
    b = GltfBuilder()
    m = b.material()
    node = b.quad("q", [0, 0, 0], 1.0, m, normals=np.tile([0.0, 0.0, 1.0], (4, 1)))
    accessor = b.doc["meshes"][b.doc["nodes"][node]["mesh"]]["primitives"][0]["attributes"]["NORMAL"]
    b.sparse(accessor, [1, 3], [[0.0, 0.6, 0.8], [-0.8, 0.0, 0.6]])
    scene, _ = _glb(b)
    np.testing.assert_allclose(
        scene.objects[0].normals, [[0, 0, 1], [0, 0.6, 0.8], [0, 0, 1], [-0.8, 0, 0.6]], atol=1e-7
    )


def test_gltf_morph_target_normals_added_at_default_weights_then_renormalised():
    b = GltfBuilder()
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64)
    deltas = np.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 0], [-1, -1, 0]])
    attributes = {"POSITION": b.accessor(square, bounds=True), "NORMAL": b.normal_accessor(TILTED)}
    targets = [
        {"POSITION": b.accessor(np.zeros((4, 3))), "NORMAL": b.accessor(deltas)},
        {"POSITION": b.accessor(np.zeros((4, 3))), "NORMAL": b.accessor(deltas * 7.0)},
    ]
    indices = b.accessor(np.array([0, 1, 2, 0, 2, 3]), USHORT, target=ELEMENT_ARRAY_BUFFER)
    mesh = b.mesh([{"attributes": attributes, "indices": indices, "targets": targets}])
    b.doc["meshes"][mesh]["weights"] = [0.5, 0.0]  # the second target is off
    b.node(name="morph", mesh=mesh)
    scene, _ = _glb(b)
    np.testing.assert_allclose(scene.objects[0].normals, _unit(TILTED + 0.5 * deltas), atol=1e-7)


def test_gltf_instances_move_normals_by_their_own_rotation_and_scale():
    b = GltfBuilder()
    node = b.quad("tree", [0, 0, 0], 1.0, b.material(), normals=TILTED, scale=[1.0, 1.0, 2.0])
    rotations = [_quaternion([0, 0, 1], 0.0), _quaternion([1, 0, 0], 1.1)]
    scales = [[1.0, 1.0, 1.0], [4.0, 1.0, 0.25]]
    b.doc["nodes"][node]["extensions"] = {
        "EXT_mesh_gpu_instancing": {
            "attributes": {
                "TRANSLATION": b.accessor(np.array([[0.0, 0, 0], [3, 0, 0]]), target=None),
                "ROTATION": b.accessor(np.array(rotations), target=None),
                "SCALE": b.accessor(np.array(scales), target=None),
            }
        }
    }
    b.used.add("EXT_mesh_gpu_instancing")
    scene, _ = _glb(b)
    first, second = scene.objects
    assert (first.name, second.name) == ("tree@0", "tree@1")
    node_linear = np.diag([1.0, 1.0, 2.0])
    np.testing.assert_allclose(first.normals, _analytic(TILTED, node_linear), atol=1e-12)
    instance = _rotation([1, 0, 0], 1.1) @ np.diag(scales[1])
    # atol: the instance's rotation is stored as a float32 quaternion
    np.testing.assert_allclose(second.normals, _analytic(TILTED, node_linear @ instance), atol=1e-6)
    assert np.abs(second.normals - _unit(TILTED @ (node_linear @ _rotation([1, 0, 0], 1.1)).T)).max() > 0.1


def test_gltf_zero_and_nan_normals_are_repaired_with_one_warning():
    b = GltfBuilder()
    bad = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [np.nan, 0.0, 0.0], [0.0, 0.0, 0.0]])
    b.quad("q", [0, 0, 0], 1.0, b.material(), normals=bad)
    scene, caught = _glb(b)
    np.testing.assert_allclose(scene.objects[0].normals, np.tile([0.0, 0.0, 1.0], (4, 1)), atol=1e-15)
    messages = [str(w.message) for w in caught]
    assert len(messages) == 1 and "3 of 4 shading normals were zero or not finite" in messages[0]
    assert scene.warnings == (messages[0].split(": ", 1)[1],)


def test_a_gltf_normal_count_that_does_not_match_positions_is_shaded_flat_with_a_warning():
    """Normals only shade: a NORMAL of the wrong count leaves the primitive flat, not the file refused."""
    b = GltfBuilder()
    node = b.quad("q", [0, 0, 0], 1.0, b.material())
    mesh = b.doc["meshes"][b.doc["nodes"][node]["mesh"]]
    mesh["primitives"][0]["attributes"]["NORMAL"] = b.accessor(TILTED[:3])
    with pytest.warns(SceneWarning, match="NORMAL has 3 elements of 3, expected 4 of 3; shaded flat"):
        scene = load_scene_bytes(b.glb(), "glb", "t.glb")
    assert scene.objects[0].normals is None


# --- OBJ ----------------------------------------------------------------------------------------------


def _obj(text: str, assets: dict | None = None):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = load_scene_bytes(text.encode(), "obj", "t.obj", assets=assets)
    return scene, [w for w in caught if issubclass(w.category, SceneWarning)]


def _corners(obj: SceneObject, uv: bool = False) -> list[tuple]:
    """Every face corner as a rounded (position, [uv,] normal) tuple, sorted (a multiset)."""
    columns = [obj.vertices, obj.uv, obj.normals] if uv else [obj.vertices, obj.normals]
    rows = np.concatenate(columns, axis=1)[obj.faces.ravel()]
    return sorted(tuple(np.round(r, 9).tolist()) for r in rows)


SQUARE_V = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"


def test_obj_v_slash_slash_vn_with_a_position_of_two_normals_split():
    text = SQUARE_V + "vn 0 0 1\nvn 0 0.6 0.8\nf 1//1 2//1 3//1\nf 1//2 3//2 4//2\n"
    scene, caught = _obj(text)
    obj = scene.objects[0]
    # Positions 1 and 3 carry two normals each: six vertices, not four.
    assert len(obj.vertices) == 6 and not caught
    n1, n2 = [0.0, 0.0, 1.0], [0.0, 0.6, 0.8]
    p = [[0.0, 0, 0], [1.0, 0, 0], [1.0, 1, 0], [0.0, 1, 0]]
    expected = sorted(
        tuple(np.round(a + b, 9).tolist())
        for a, b in [(p[0], n1), (p[1], n1), (p[2], n1), (p[0], n2), (p[2], n2), (p[3], n2)]
    )
    assert _corners(obj) == expected


def test_obj_v_vt_vn_keeps_uv_and_normal_per_corner():
    image = io.BytesIO()
    PIL.Image.fromarray(np.arange(48, dtype=np.uint8).reshape(2, 2, 12)[..., :4] * 5).save(image, format="PNG")
    text = (
        "mtllib m.mtl\n" + SQUARE_V + "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvt 0.5 0.5\n"
        "vn 0 0 1\nvn 1 0 0\nusemtl tex\nf 1/1/1 2/2/1 3/3/1\nf 1/5/1 3/3/2 4/4/2\n"
    )
    scene, _ = _obj(text, {"m.mtl": b"newmtl tex\nmap_Kd t.png\n", "t.png": image.getvalue()})
    obj = scene.objects[0]
    assert obj.texture is not None
    rows = [
        ([0, 0, 0], [0, 0], [0, 0, 1]), ([1, 0, 0], [1, 0], [0, 0, 1]), ([1, 1, 0], [1, 1], [0, 0, 1]),
        ([0, 0, 0], [0.5, 0.5], [0, 0, 1]), ([1, 1, 0], [1, 1], [1, 0, 0]), ([0, 1, 0], [0, 1], [1, 0, 0]),
    ]  # fmt: skip
    assert _corners(obj, uv=True) == sorted(tuple(np.round(np.concatenate(r), 9).tolist()) for r in rows)
    assert len(obj.vertices) == 6  # corner 1 splits by uv, corner 3 by normal


def test_obj_faces_without_normal_indices_get_their_face_normal():
    # A quad without vn beside a triangle with them; the quad faces +y (counter-clockwise seen from +y).
    text = SQUARE_V + "v 0 0 1\nv 1 0 1\nvn 0 0 1\nf 1//1 2//1 3//1\nf 1 5 6 2\n"
    scene, caught = _obj(text)
    obj = scene.objects[0]
    assert obj.normals is not None and not caught
    np.testing.assert_allclose(obj.normals[obj.faces[0]], np.tile([0.0, 0.0, 1.0], (3, 1)))
    for face in obj.faces[1:]:  # the quad's two triangles: their own face normal at every corner
        np.testing.assert_allclose(obj.normals[face], np.tile([0.0, 1.0, 0.0], (3, 1)), atol=1e-15)
    np.testing.assert_allclose(_face_normals(obj)[1:], [[0.0, 1.0, 0.0]] * 2, atol=1e-15)


def test_obj_without_vn_is_flat_and_unchanged():
    scene, _ = _obj(SQUARE_V + "f 1 2 3 4\n")
    assert scene.objects[0].normals is None and len(scene.objects[0].vertices) == 4


@pytest.mark.parametrize(
    "face", ["f 1//1 2//1 3//3", "f 1//1 2//-5 3//1", "f 1/1/1 2/1/9 3/1/1", "f 1//1 2//1 3//99999999999999999999999"]
)
def test_obj_vn_index_out_of_range_is_refused(face):
    text = SQUARE_V + "vt 0 0\nvn 0 0 1\nvn 0 1 0\n" + face + "\n"
    with pytest.raises(
        SceneLoadError, match=r"t\.obj: line 8: face corner .* names normal \(vn\) .*, but the file has 2 vn lines"
    ):
        load_scene_bytes(text.encode(), "obj", "t.obj")


def test_obj_zero_vn_repaired_with_one_warning_per_object():
    text = SQUARE_V + "vn 0 0 0\nvn 0 0 1\no a\nf 1//1 2//1 3//2\no b\nf 1//1 3//1 4//1\n"
    scene, caught = _obj(text)
    a, b = scene.objects
    np.testing.assert_allclose(a.normals, np.tile([0.0, 0.0, 1.0], (len(a.normals), 1)))
    np.testing.assert_allclose(b.normals, np.tile([0.0, 0.0, 1.0], (len(b.normals), 1)))
    messages = sorted(str(w.message) for w in caught)
    assert len(messages) == 2
    assert "object 'a': 2 of 3 shading normals" in messages[0] and "object 'b': 3 of 3 shading normals" in messages[1]


# --- PLY ----------------------------------------------------------------------------------------------

PLY_POSITIONS = [(0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (1.0, 1.0, 0.3)]


def _ply(form: str, kind: str, normals, faces=((0, 1, 2), (1, 3, 2))) -> bytes:
    head = (
        f"ply\nformat {form} 1.0\nelement vertex {len(normals)}\nproperty float x\nproperty float y\nproperty float z\n"
        f"property {kind} nx\nproperty {kind} ny\nproperty {kind} nz\nelement face {len(faces)}\n"
        "property list uchar int vertex_indices\nend_header\n"
    )
    if form == "ascii":
        body = "".join(f"{' '.join(map(str, p))} {' '.join(map(str, n))}\n" for p, n in zip(PLY_POSITIONS, normals))
        return (head + body + "".join(f"3 {a} {b} {c}\n" for a, b, c in faces)).encode()
    code = {"float": "f", "double": "d", "short": "h", "char": "b"}[kind]
    order = "<" if form == "binary_little_endian" else ">"
    body = b"".join(struct.pack(order + "fff" + code * 3, *p, *n) for p, n in zip(PLY_POSITIONS, normals))
    return head.encode() + body + b"".join(struct.pack(order + "Biii", 3, *f) for f in faces)


@pytest.mark.parametrize("form", ["ascii", "binary_little_endian", "binary_big_endian"])
@pytest.mark.parametrize("kind", ["float", "double", "short", "char"])
def test_ply_normals_of_any_numeric_type(form, kind):
    unit = _unit([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, -0.6, 0.8], [-0.48, 0.36, 0.8]])
    top = {"short": 32767, "char": 127}.get(kind)
    stored = unit if top is None else np.round(unit * top).astype(int)
    scene = load_scene_bytes(_ply(form, kind, stored.tolist()), "ply", "t.ply")
    np.testing.assert_allclose(scene.objects[0].normals, unit, atol=1e-6 if top is None else 2.0 / top)


def test_ply_zero_normal_repaired_with_the_area_weighted_mean():
    normals = [[0.0, 0.0, 1.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]]
    with pytest.warns(SceneWarning, match="1 of 4 shading normals were zero") as caught:
        scene = load_scene_bytes(_ply("ascii", "float", normals), "ply", "t.ply")
    obj = scene.objects[0]
    # vertex 1 is used by both triangles: the mean of their face normals weighted by area
    c = obj.vertices[obj.faces]
    cross = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    np.testing.assert_allclose(obj.normals[1], _unit(cross.sum(axis=0)), atol=1e-12)
    assert sum(1 for w in caught if issubclass(w.category, SceneWarning)) == 1


def test_ply_without_normals_is_flat():
    text = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    assert load_scene_bytes(text, "ply", "t.ply").objects[0].normals is None


def test_stl_has_no_normals():
    text = b"solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\nendsolid t\n"
    assert load_scene_bytes(text, "stl", "t.stl").objects[0].normals is None


# --- the repair, the matrix, subsets and hashes -------------------------------------------------------


def test_repair_falls_back_to_an_adjacent_face_then_up():
    # vertex 0's two triangles cancel (back to back); vertex 4 is used by none.
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5], [9, 9, 9]])
    faces = np.array([[0, 1, 2], [0, 2, 1], [3, 1, 2]])
    fixed, warning = repair_normals(
        "x", v, faces, np.array([[0.0, 0, 0], [1, 0, 0], [1, 0, 0], [1, 0, 0], [np.inf, 0, 0]])
    )
    np.testing.assert_allclose(fixed[0], [0.0, 0.0, 1.0])  # the first face's normal (not normalised yet)
    np.testing.assert_allclose(fixed[4], [0.0, 0.0, 1.0])
    assert fixed[1:4].tolist() == [[1.0, 0, 0]] * 3 and "2 of 5" in warning
    assert repair_normals("x", v, faces, np.ones((5, 3)))[1] is None


def test_normal_matrix_is_the_inverse_transpose_up_to_a_positive_factor():
    rng = np.random.default_rng(7)
    for _ in range(20):
        linear = rng.normal(size=(3, 3))
        ratio = normal_matrix(linear) / np.linalg.inv(linear).T
        assert np.allclose(ratio, ratio[0, 0]) and ratio[0, 0] > 0
    assert (normal_matrix(np.diag([1.0, 1.0, 0.0])) @ [0, 0, 1]).tolist() == [0.0, 0.0, 1.0]  # singular: still a normal


def test_clusters_of_a_scene_carry_their_vertices_normals():
    v, f = procedural.subdivided_box([0.0, 0.0, 0.0], [1.0, 1.0, 1.0], 8)
    centre = np.array([0.5, 0.5, 0.5])
    scene = Scene.from_objects([SceneObject("box", v, f, normals=v - centre)], "box")
    elements = Elements.of(scene, cluster_triangles=300)
    parts = elements.scene_of(scene, range(elements.count)).objects
    assert len(parts) > 1
    for part in parts:
        np.testing.assert_allclose(part.normals, _unit(part.vertices - centre), atol=1e-15)


def test_content_hash_counts_normals_and_is_stable():
    v, f = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]])
    flat = SceneObject("t", v, f)
    smooth = SceneObject("t", v, f, normals=[[0, 0, 1], [0, 0.6, 0.8], [0, 0, 1]])
    again = SceneObject("t", v, f, normals=[[0, 0, 2], [0, 3, 4], [0, 0, 9]])  # the same after normalising
    assert object_hash(flat) != object_hash(smooth) == object_hash(again)
    text = SQUARE_V + "vn 0 0 1\nvn 0 0.6 0.8\nf 1//1 2//1 3//2\n"
    first, second = (load_scene_bytes(text.encode(), "obj", "t.obj").content_hash for _ in range(2))
    without = load_scene_bytes((SQUARE_V + "f 1 2 3\n").encode(), "obj", "t.obj").content_hash
    assert first == second != without


def test_negative_normal_indices_keep_their_normals_when_faces_without_any_get_appended_ones():
    """``f 1//-1`` names the last ``vn`` before the faces; the face normals appended for a face
    without normals must not move what it names (written absolute first)."""
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 0 1 1\nvn 0 0 1\nf 1//-1 2//-1 3//-1\nf 4 6 5\n"
    (obj,) = load_scene_bytes(text.encode(), "obj", "t.obj").objects
    assert np.allclose(obj.normals[:3], [0.0, 0.0, 1.0]) and np.allclose(obj.normals[3:], [0.0, 0.0, -1.0])
