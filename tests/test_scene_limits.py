"""Scene files whose structure would cost far more than their size: refused from the glTF JSON before
the full parse, with the count and the limit in the message (issue 24's deep node chain, many
primitives and many instanced nodes)."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
from scenes import city, write_scene

from farfield.core.errors import ErrorKind, SceneLoadError, SceneTooCostlyError
from farfield.core.exchange import DEFAULT_LIMITS, SceneLimits, load_scene, load_scene_bytes


def gltf_bytes(nodes: list[dict], roots: list[int], primitives: int = 1) -> bytes:
    """A .gltf whose one mesh (a triangle in a data URI) has ``primitives`` primitives."""
    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype="<f4").tobytes()
    import base64

    document = {
        "asset": {"version": "2.0"},
        "scenes": [{"nodes": roots}],
        "scene": 0,
        "nodes": nodes,
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}} for _ in range(primitives)]}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]}
        ],
        "bufferViews": [{"buffer": 0, "byteLength": len(positions)}],
        "buffers": [
            {
                "byteLength": len(positions),
                "uri": "data:application/octet-stream;base64," + base64.b64encode(positions).decode(),
            }
        ],
    }
    return json.dumps(document).encode()


def test_a_deep_node_chain_is_refused_at_once():
    """The campaign's 100,000-deep chain took 40 s to parse; now it is refused from its JSON."""
    for depth, message in (
        (100_000, r"glTF nodes: 100,000 is beyond the limit of 50,000 \(FARFIELD_MAX_SCENE_NODES\)"),
        (1_000, r"glTF node nesting: 129 is beyond the limit of 128 \(FARFIELD_MAX_SCENE_DEPTH\)"),
    ):
        nodes = [{"children": [i + 1]} for i in range(depth - 1)] + [{"mesh": 0}]
        start = time.perf_counter()
        with pytest.raises(SceneTooCostlyError, match=message) as error:
            load_scene_bytes(gltf_bytes(nodes, [0]), "gltf", "deep.gltf")
        assert time.perf_counter() - start < 10  # a sanity bound against the 40 s parse, not a timing test
        assert error.value.kind is ErrorKind.TOO_LARGE and error.value.kind.http_status == 413
        assert str(error.value).startswith("deep.gltf: ")


def test_many_primitives_and_instanced_nodes_are_refused():
    with pytest.raises(SceneTooCostlyError, match="glTF primitives once instancing is applied: 50,001"):
        load_scene_bytes(gltf_bytes([{"mesh": 0}], [0], primitives=50_001), "gltf", "prims.gltf")
    # 300 nodes each holding the one 200-primitive mesh: 60,000 primitives drawn.
    nodes = [{"mesh": 0} for _ in range(300)]
    with pytest.raises(SceneTooCostlyError, match="primitives once instancing"):
        load_scene_bytes(gltf_bytes(nodes, list(range(300)), primitives=200), "gltf", "instanced.gltf")


def test_a_node_under_two_parents_is_counted_per_path():
    """glTF forbids a node with two parents; listed so, twenty levels of doubling would be 2^20
    draws: counting every path refuses it before it expands."""
    nodes = [{"children": [i + 1, i + 1]} for i in range(20)] + [{"mesh": 0}]
    with pytest.raises(SceneTooCostlyError, match="glTF nodes once instancing is applied: 50,001"):
        load_scene_bytes(gltf_bytes(nodes, [0]), "gltf", "doubling.gltf")


def test_a_cycle_in_the_node_hierarchy_is_bad_input():
    nodes = [{"children": [1]}, {"children": [0], "mesh": 0}]
    with pytest.raises(SceneLoadError, match="its own ancestor"):
        load_scene_bytes(gltf_bytes(nodes, [0]), "gltf", "cycle.gltf")


def test_limits_hold_for_every_format_after_the_parse(tmp_path):
    scene = city(buildings=30)
    for extension in ("glb", "obj"):
        path = write_scene(scene, tmp_path, extension)
        assert load_scene(path).object_count == scene.object_count == 31  # 30 buildings and the ground
        with pytest.raises(SceneTooCostlyError, match="objects: 31 is beyond the limit of 20|glTF nodes: 3"):
            load_scene(path, limits=SceneLimits(nodes=20))
        with pytest.raises(SceneTooCostlyError, match="triangles"):
            load_scene(path, limits=SceneLimits(triangles=100))


def test_limits_must_be_positive_integers():
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="positive integer"):
            SceneLimits(nodes=bad)
    assert DEFAULT_LIMITS.depth == 128
