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


def _png_header(width: int, height: int) -> bytes:
    """A PNG that declares ``width`` x ``height`` RGBA texels (its header; the data is a stub): what a
    decompression bomb shows before it is decoded."""
    import struct
    import zlib

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 6, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b"")


def test_a_texture_bomb_is_refused_from_its_header_before_it_is_decoded(tmp_path):
    """Issue 59, item 4: a 421 KB GLB held a 12000 x 12000 PNG whose decoding took 2.3 GiB.  The
    texel count is read from the image's header and refused (HTTP 413) before decoding, in glTF and
    OBJ alike; the limit is FARFIELD_MAX_SCENE_TEXTURE_PIXELS (SceneLimits.texture_pixels)."""
    from gltf_files import SQUARE_UV, GltfBuilder

    bomb = _png_header(12000, 12000)
    b = GltfBuilder()
    image = b._add("images", {"bufferView": b.view(bomb), "mimeType": "image/png"})
    b.quad("q", [0, 0, 0], 1.0, b.material(texture=b.texture(image)), uv=SQUARE_UV)
    with pytest.raises(SceneTooCostlyError, match="12000 x 12000 texels.*FARFIELD_MAX_SCENE_TEXTURE_PIXELS"):
        load_scene_bytes(b.glb(), "glb", "bomb.glb")
    obj = "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nusemtl a\nf 1/1 2/2 3/3\n"
    assets = {"m.mtl": b"newmtl a\nmap_Kd bomb.png\n", "bomb.png": bomb}
    with pytest.raises(SceneTooCostlyError, match="12000 x 12000"):
        load_scene_bytes(obj.encode(), "obj", "bomb.obj", assets)
    small = SceneLimits(texture_pixels=100)
    with pytest.raises(SceneTooCostlyError, match="16 x 16"):
        load_scene_bytes(_textured_glb(), "glb", "small.glb", limits=small)


def _textured_glb() -> bytes:
    from gltf_files import SQUARE_UV, GltfBuilder, gradient

    b = GltfBuilder()
    b.quad("q", [0, 0, 0], 1.0, b.material(texture=b.texture(b.image(gradient(16)))), uv=SQUARE_UV)
    return b.glb()


def test_all_of_a_scenes_textures_together_are_bounded_too(tmp_path):
    """Issue 59, item 4: textures that pass one by one can still decode to gigabytes together
    (forty of 8192 x 8192: 10 GiB).  Their sum is bounded as they are read, in glTF and OBJ alike
    (FARFIELD_MAX_SCENE_TEXTURE_PIXELS_TOTAL, SceneLimits.texture_pixels_total); a texture used
    twice counts once."""
    from gltf_files import SQUARE_UV, GltfBuilder, gradient

    b = GltfBuilder()
    for k in range(4):  # four textures of 16 x 16 = 256 texels
        image = b.image(gradient(16) // 2 + k)  # four different images
        b.quad(f"q{k}", [2.0 * k, 0, 0], 1.0, b.material(texture=b.texture(image)), uv=SQUARE_UV)
    shared = b.material(texture=b.texture(0))  # the first image again
    b.quad("again", [10.0, 0, 0], 1.0, shared, uv=SQUARE_UV)
    data = b.glb()
    assert len(load_scene_bytes(data, "glb", "four.glb", limits=SceneLimits(texture_pixels_total=256 * 4)).objects) == 5
    with pytest.raises(SceneTooCostlyError, match="1,023 for all of a scene's textures together"):
        load_scene_bytes(data, "glb", "four.glb", limits=SceneLimits(texture_pixels_total=256 * 4 - 1))
    import io

    from PIL import Image

    def png(k: int) -> bytes:
        out = io.BytesIO()
        Image.fromarray(gradient(16) // 2 + k).save(out, format="PNG")
        return out.getvalue()

    obj = "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n" + "".join(
        f"o t{k}\nusemtl m{k}\nf 1/1 2/2 3/3\n" for k in range(3)
    )
    mtl = "".join(f"newmtl m{k}\nmap_Kd t{k}.png\n" for k in range(3)).encode()
    assets = {"m.mtl": mtl, **{f"t{k}.png": png(k) for k in range(3)}}
    load_scene_bytes(obj.encode(), "obj", "three.obj", assets, limits=SceneLimits(texture_pixels_total=256 * 3))
    with pytest.raises(SceneTooCostlyError, match="FARFIELD_MAX_SCENE_TEXTURE_PIXELS_TOTAL"):
        load_scene_bytes(obj.encode(), "obj", "three.obj", assets, limits=SceneLimits(texture_pixels_total=256 * 3 - 1))
