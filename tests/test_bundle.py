"""Impostor bundles and GLB: round trip, byte-identical output, glTF validity, bad bundles, atomic writes."""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import os
import shutil
import struct
import zipfile
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

import farfield.core.impostor.bundle
from farfield.core.errors import BundleFormatError
from farfield.core.impostor.bundle import (
    FORMAT_VERSION,
    GLB_NAME,
    MANIFEST_NAME,
    PAYLOAD_NAME,
    bundle_zip,
    page_file_name,
    read_bundle,
    stored_stats,
    write_bundle,
)
from farfield.core.impostor.glb import impostor_glb, page_png
from farfield.core.impostor.impostor import Impostor, MeshPayload, QuadPayload

ORIGIN = (0.0, 0.0, 0.0)
CONTINENTAL = (4.2e6, -1.3e6, 250.0)

# (layer, distance along the view axis in metres, page, texel rect [x0, y0, x1, y1) on that page)
QUADS = (
    (0, 20.0, 0, (0, 0, 5, 4)),
    (0, 20.0, 1, (1, 2, 6, 5)),
    (1, 45.0, 1, (0, 0, 3, 2)),
)
PAGE_SHAPES = ((6, 8, 4), (5, 7, 4))  # (H, W, 4): not square, so a swapped W/H shows


def make_impostor(viewpoint=ORIGIN, seed: int = 7, quads=QUADS, page_shapes=PAGE_SHAPES) -> Impostor:
    """3 quads on 2 layers over 2 random RGBA pages, seen from ``viewpoint`` looking along +y.

    Image x runs along +x and image y (top row first) along -z, so corners TL, TR, BR, BL are
    as seen from the viewpoint.
    """
    rng = np.random.default_rng(seed)
    vp = np.asarray(viewpoint, dtype=np.float64)
    right, forward, up = np.eye(3)
    corners, uvs = [], []
    for _layer, distance, page, (x0, y0, x1, y1) in quads:
        centre = vp + distance * forward + rng.normal(scale=3.0) * right + rng.normal(scale=2.0) * up
        half_w, half_h = rng.uniform(0.5, 2.0, size=2)
        corners.append(
            [
                centre - half_w * right + half_h * up,
                centre + half_w * right + half_h * up,
                centre + half_w * right - half_h * up,
                centre - half_w * right - half_h * up,
            ]
        )
        h, w = page_shapes[page][:2]
        u0, u1, v0, v1 = x0 / w, x1 / w, y0 / h, y1 / h
        uvs.append([[u0, v0], [u1, v0], [u1, v1], [u0, v1]])
    pages = []
    for shape in page_shapes:
        page = rng.integers(0, 256, size=shape, dtype=np.uint8)
        page[: shape[0] // 2, : shape[1] // 2, 3] = 0  # alpha-cut texels
        pages.append(page)
    return Impostor(
        technique="layered",
        viewcell={"kind": "box", "lo": (vp - 1.5).tolist(), "hi": (vp + 0.25).tolist()},
        reference_viewpoint=vp,
        resolution=512,
        fov_deg=60.0,
        pages=tuple(pages),
        payload=QuadPayload(
            corners=np.array(corners, dtype=np.float64).reshape(-1, 4, 3),
            uv=np.array(uvs, dtype=np.float64).reshape(-1, 4, 2),
            page=np.array([q[2] for q in quads], dtype=np.int64),
            layer=np.array([q[0] for q in quads], dtype=np.int64),
        ),
        layers=[
            {"distance": 20.0, "depth_range": [14.9, 31.3], "texels": 35},
            {"distance": 45.0, "depth_range": [31.3, 80.0], "texels": 6},
        ],
        stats={"quads": len(quads), "seconds": {"record": 0.0123, "pack": 1e-4}},
        parameters={"conservative": True, "max_layers": 4, "texel_ratio": 0.1},
        code_version="0.1.0+test",
    )


def make_mesh_impostor(viewpoint=CONTINENTAL, seed: int = 5, triangles: int = 40) -> Impostor:
    """A random textured mesh (a fan of triangles sharing vertices) over 2 pages, as a TDM would give."""
    rng = np.random.default_rng(seed)
    vp = np.asarray(viewpoint, dtype=np.float64)
    vertices = vp + [0.0, 30.0, 0.0] + rng.normal(scale=4.0, size=(triangles + 2, 3))
    tri = np.stack([np.zeros(triangles, np.int64), np.arange(1, triangles + 1), np.arange(2, triangles + 2)], axis=1)
    pages = tuple(rng.integers(0, 256, size=shape, dtype=np.uint8) for shape in PAGE_SHAPES)
    # Huge vertex indices are not needed to exercise <i8: the page/mesh labels stay small.
    payload = MeshPayload(
        vertices=vertices,
        uv=rng.uniform(0.0, 1.0, size=(triangles + 2, 2)),
        triangles=tri,
        page=rng.integers(0, 2, size=triangles),
        mesh=rng.integers(0, 3, size=triangles),
    )
    return Impostor(
        technique="tdm",
        viewcell={"kind": "box", "lo": (vp - 2.0).tolist(), "hi": (vp + 2.0).tolist()},
        reference_viewpoint=vp,
        resolution=256,
        fov_deg=45.0,
        pages=pages,
        payload=payload,
        layers=[{"distance": 30.0, "depth_range": [20.0, 40.0], "texels": 99}],
        stats={"triangles": triangles, "seconds": {"total": 0.5}},
        parameters={"enlargement": 2.0},
        code_version="0.1.0+test",
    )


def assert_impostors_equal(a: Impostor, b: Impostor) -> None:
    assert type(a.payload) is type(b.payload) and a.payload.kind == b.payload.kind
    x, y = a.reference_viewpoint, b.reference_viewpoint
    assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y)
    arrays_a, arrays_b = a.payload.arrays(), b.payload.arrays()
    assert list(arrays_a) == list(arrays_b)
    for name in arrays_a:
        x, y = arrays_a[name], arrays_b[name]
        assert x.dtype == y.dtype and x.shape == y.shape, name
        assert x.tobytes() == y.tobytes(), name  # bit-exact, not approximately
    assert len(a.pages) == len(b.pages)
    for x, y in zip(a.pages, b.pages):
        assert x.dtype == y.dtype == np.uint8 and np.array_equal(x, y)
    for name in ("technique", "viewcell", "resolution", "fov_deg", "layers", "parameters", "code_version"):
        assert getattr(a, name) == getattr(b, name), name
    assert stored_stats(a.stats) == stored_stats(b.stats)  # timings never reach a bundle


def parse_glb(data: bytes) -> tuple[dict, bytes]:
    """The JSON document and BIN chunk of a GLB, checking the container as the spec states it."""
    magic, version, length = struct.unpack_from("<III", data, 0)
    assert magic == 0x46546C67 and data[:4] == b"glTF"
    assert version == 2
    assert length == len(data) and length % 4 == 0
    json_length, json_type = struct.unpack_from("<II", data, 12)
    assert json_type == 0x4E4F534A and json_length % 4 == 0
    text = data[20 : 20 + json_length]
    assert text.rstrip(b" ") == text.rstrip()  # padded with spaces only
    document = json.loads(text)
    offset = 20 + json_length
    binary = b""
    if offset < length:
        bin_length, bin_type = struct.unpack_from("<II", data, offset)
        assert bin_type == 0x004E4942 and bin_length % 4 == 0
        binary = data[offset + 8 : offset + 8 + bin_length]
        assert offset + 8 + bin_length == length
        assert document["buffers"][0]["byteLength"] <= bin_length
    return document, binary


def accessor_array(document: dict, binary: bytes, index: int) -> np.ndarray:
    accessor = document["accessors"][index]
    view = document["bufferViews"][accessor["bufferView"]]
    dtype = {5123: "<u2", 5125: "<u4", 5126: "<f4"}[accessor["componentType"]]
    width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3}[accessor["type"]]
    start = view["byteOffset"] + accessor.get("byteOffset", 0)
    assert start % np.dtype(dtype).itemsize == 0
    count = accessor["count"]
    assert count * width * np.dtype(dtype).itemsize <= view["byteLength"]
    return np.frombuffer(binary, dtype=dtype, count=count * width, offset=start).reshape(count, width)


@pytest.mark.parametrize("viewpoint", [ORIGIN, CONTINENTAL], ids=["origin", "continental"])
def test_round_trip_is_exact(tmp_path, viewpoint):
    impostor = make_impostor(viewpoint)
    paths = write_bundle(impostor, tmp_path / "cell-0")
    assert sorted(p.name for p in paths.directory.iterdir()) == [
        "atlas-000.png",
        "atlas-001.png",
        "impostor.glb",
        "manifest.json",
        "payload.bin",
    ]
    assert paths.manifest.is_file() and paths.glb.is_file() and paths.payload.is_file()
    assert all(p.is_file() for p in paths.pages)
    assert_impostors_equal(read_bundle(paths.directory), impostor)


@pytest.mark.parametrize("viewpoint", [ORIGIN, CONTINENTAL], ids=["origin", "continental"])
def test_mesh_round_trip_is_exact(tmp_path, viewpoint):
    impostor = make_mesh_impostor(viewpoint)
    paths = write_bundle(impostor, tmp_path / "m")
    back = read_bundle(paths.directory)
    assert isinstance(back.payload, MeshPayload) and back.triangle_count == 40 and back.quad_count == 0
    assert_impostors_equal(back, impostor)
    manifest = json.loads(paths.manifest.read_text("utf-8"))
    assert manifest["payload"]["kind"] == "mesh" and manifest["payload"]["counts"] == {"vertices": 42, "triangles": 40}
    with pytest.raises(AttributeError, match="mesh"):
        back.quad_corners  # noqa: B018  (a mesh has no quads to fake)


def test_payload_file_layout(tmp_path):
    """payload.bin is the arrays, little-endian, 8-byte aligned, as the manifest's table says."""
    big = make_mesh_impostor()
    # An integer array beyond int32 is written as <i8, the others as <i4, floats as <f8.
    mesh = dataclasses.replace(big.payload, mesh=big.payload.mesh + 2**40)
    impostor = dataclasses.replace(big, payload=mesh)
    paths = write_bundle(impostor, tmp_path / "m")
    entry = json.loads(paths.manifest.read_text("utf-8"))["payload"]
    data = paths.payload.read_bytes()
    assert entry["file"] == PAYLOAD_NAME and entry["nbytes"] == len(data)
    assert entry["sha256"] == hashlib.sha256(data).hexdigest()
    assert [(a["name"], a["dtype"]) for a in entry["arrays"]] == [
        ("vertices", "<f8"),
        ("uv", "<f8"),
        ("triangles", "<i4"),
        ("page", "<i4"),
        ("mesh", "<i8"),
    ]
    end = 0
    for a in entry["arrays"]:
        assert a["offset"] % 8 == 0 and a["offset"] == end + (-end % 8)
        assert data[end : a["offset"]] == b"\x00" * (a["offset"] - end)
        expected = getattr(mesh, a["name"])
        assert a["shape"] == list(expected.shape)
        stored = np.frombuffer(data, dtype=a["dtype"], count=expected.size, offset=a["offset"]).reshape(a["shape"])
        assert np.array_equal(stored, expected)
        end = a["offset"] + a["nbytes"]
    assert end == len(data)
    assert_impostors_equal(read_bundle(paths.directory), impostor)


def test_manifest_schema(tmp_path):
    impostor = make_impostor(CONTINENTAL)
    manifest = json.loads(write_bundle(impostor, tmp_path / "b").manifest.read_text("utf-8"))
    assert manifest["format"] == "farfield-impostor" and manifest["format_version"] == FORMAT_VERSION == 2
    assert set(manifest) == {
        "format",
        "format_version",
        "code_version",
        "technique",
        "viewcell",
        "reference_viewpoint",
        "resolution",
        "fov_deg",
        "layers",
        "payload",
        "pages",
        "glb",
        "stats",
        "parameters",
    }
    payload = manifest["payload"]
    assert set(payload) == {"kind", "counts", "file", "nbytes", "sha256", "arrays"}
    assert payload["kind"] == "quads" and payload["counts"] == {"quads": 3} and payload["file"] == PAYLOAD_NAME
    assert [(a["name"], a["dtype"], a["shape"]) for a in payload["arrays"]] == [
        ("corners", "<f8", [3, 4, 3]),
        ("uv", "<f8", [3, 4, 2]),
        ("page", "<i4", [3]),
        ("layer", "<i4", [3]),
    ]
    assert manifest["pages"] == [
        {"file": "atlas-000.png", "width": 8, "height": 6},
        {"file": "atlas-001.png", "width": 7, "height": 5},
    ]
    assert manifest["glb"] == GLB_NAME


def test_empty_impostor_round_trips(tmp_path):
    impostor = make_impostor(CONTINENTAL, quads=(), page_shapes=((2, 3, 4),))
    assert_impostors_equal(read_bundle(write_bundle(impostor, tmp_path / "b").directory), impostor)
    document, _ = parse_glb(impostor_glb(impostor))
    assert "meshes" not in document and len(document["materials"]) == 1


@pytest.mark.parametrize("make", [make_impostor, make_mesh_impostor], ids=["quads", "mesh"])
def test_writes_are_byte_identical(tmp_path, make):
    # Two impostors built alike, and the same in-memory impostor written twice.
    impostor = make(CONTINENTAL)
    first = write_bundle(impostor, tmp_path / "a")
    second = write_bundle(make(CONTINENTAL), tmp_path / "b")
    again = write_bundle(impostor, tmp_path / "c")
    names = sorted(p.name for p in first.directory.iterdir())
    assert PAYLOAD_NAME in names
    for other in (second, again):
        assert names == sorted(p.name for p in other.directory.iterdir())
        for name in names:
            assert (first.directory / name).read_bytes() == (other.directory / name).read_bytes(), name
        assert bundle_zip(first.directory) == bundle_zip(other.directory)
    # A different impostor changes the bytes (the comparison above is not vacuous).
    other = write_bundle(make(CONTINENTAL, seed=8), tmp_path / "d")
    assert other.glb.read_bytes() != first.glb.read_bytes()
    assert other.payload.read_bytes() != first.payload.read_bytes()


def test_parallel_and_serial_writes_give_the_same_bytes(tmp_path):
    # Pages encoded and files written on several threads give the bundle one thread writes, each
    # page's PNG under its own name.  The pages share a shape, so a page written under another's
    # name would change no size in the manifest, only the bytes.
    rng = np.random.default_rng(3)
    impostor = make_impostor(CONTINENTAL, page_shapes=((8, 8, 4),) * 2)
    impostor = dataclasses.replace(
        impostor, channels={"normal": tuple(rng.integers(0, 256, (8, 8, 4), dtype=np.uint8) for _ in range(2))}
    )
    serial = write_bundle(impostor, tmp_path / "serial", workers=1)
    parallel = write_bundle(impostor, tmp_path / "parallel", workers=4)
    names = sorted(p.name for p in serial.directory.iterdir())
    assert names == sorted(p.name for p in parallel.directory.iterdir())
    assert {"atlas-000.png", "atlas-001.png", "normal-000.png", "normal-001.png", GLB_NAME} <= set(names)
    for name in names:
        assert (serial.directory / name).read_bytes() == (parallel.directory / name).read_bytes(), name
    for bundle in (serial, parallel):
        for index, page in enumerate(impostor.pages):
            assert np.array_equal(np.asarray(Image.open(bundle.directory / page_file_name(index))), page)
        for index, page in enumerate(impostor.channels["normal"]):
            assert np.array_equal(np.asarray(Image.open(bundle.directory / f"normal-{index:03d}.png")), page)


def test_each_page_is_encoded_once(tmp_path, monkeypatch):
    # The bundle's page files and the GLB's images share one encoding of each page (a colour-only
    # impostor: its GLB holds exactly its pages).
    import farfield.core.impostor.png_pages as png_pages

    encoded = []
    real = png_pages.page_png
    monkeypatch.setattr(png_pages, "page_png", lambda page: encoded.append(page.shape) or real(page))
    impostor = make_impostor()
    paths = write_bundle(impostor, tmp_path / "b")
    assert len(encoded) == len(impostor.pages) == 2
    assert [p.read_bytes() for p in paths.pages] == [real(page) for page in impostor.pages]


def test_bundle_zip_is_the_bundle(tmp_path):
    paths = write_bundle(make_impostor(), tmp_path / "b")
    (paths.directory / "stray.txt").write_text("not part of the bundle")
    with zipfile.ZipFile(io.BytesIO(bundle_zip(paths.directory))) as archive:
        infos = archive.infolist()
        assert [i.filename for i in infos] == sorted(
            [MANIFEST_NAME, GLB_NAME, PAYLOAD_NAME, "atlas-000.png", "atlas-001.png"]
        )
        for info in infos:
            assert info.date_time == (1980, 1, 1, 0, 0, 0)
            assert archive.read(info) == (paths.directory / info.filename).read_bytes()


def assert_faces_viewpoint(positions: np.ndarray, indices: np.ndarray) -> None:
    """Every triangle counter-clockwise seen from the reference viewpoint (the local origin): its
    normal points at it."""
    tri = positions.astype(np.float64)[indices.reshape(-1, 3)]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert np.all(np.einsum("ij,ij->i", normals, -tri.mean(axis=1)) > 0)


@pytest.mark.parametrize("name", ["layered", "tdm"])
def test_glb_of_a_baked_impostor_faces_the_viewpoint(name):
    """The baked fixtures (tests/fixtures): a layered impostor's image x runs right to left seen
    from the viewpoint, a TDM's triangles wind both ways; the GLB's triangles all face it."""
    impostor = read_bundle(FIXTURES / f"bundle_v1_{name}")
    document, binary = parse_glb(impostor_glb(impostor))
    (mesh,) = document["meshes"]
    assert sum(document["accessors"][p["indices"]]["count"] for p in mesh["primitives"]) == 3 * impostor.triangle_count
    for primitive in mesh["primitives"]:
        positions = accessor_array(document, binary, primitive["attributes"]["POSITION"])
        assert_faces_viewpoint(positions, accessor_array(document, binary, primitive["indices"]))


@pytest.mark.parametrize("viewpoint", [ORIGIN, CONTINENTAL], ids=["origin", "continental"])
def test_glb_structure(viewpoint):
    impostor = make_impostor(viewpoint)
    document, binary = parse_glb(impostor_glb(impostor))
    assert document["asset"] == {"version": "2.0", "generator": "farfield 0.1.0+test"}
    assert document["extensionsUsed"] == ["KHR_materials_unlit"]
    (node,) = document["nodes"]
    assert node["translation"] == list(viewpoint)  # float64 JSON numbers, exact
    # Where the impostor is valid, for an engine: in the node's extras.
    assert node["extras"]["farfield"] == {
        "technique": impostor.technique, "viewcell": impostor.viewcell, "reference_viewpoint": list(viewpoint),
        "resolution": impostor.resolution, "fov_deg": impostor.fov_deg, "code_version": impostor.code_version,
    }  # fmt: skip
    (mesh,) = document["meshes"]
    assert len(mesh["primitives"]) == len(impostor.pages)
    for view in document["bufferViews"]:
        assert view["byteOffset"] % 4 == 0
        assert view["byteOffset"] + view["byteLength"] <= document["buffers"][0]["byteLength"]
    sampler = document["samplers"][0]
    assert (sampler["magFilter"], sampler["minFilter"], sampler["wrapS"], sampler["wrapT"]) == (
        9729,
        9729,
        33071,
        33071,
    )  # no mipmaps: they erode an alpha-cut silhouette
    for page_index, primitive in enumerate(mesh["primitives"]):
        assert primitive["material"] == page_index
        material = document["materials"][page_index]
        assert material["alphaMode"] == "MASK" and material["alphaCutoff"] == 0.5
        assert material["doubleSided"] is True and material["extensions"] == {"KHR_materials_unlit": {}}
        pbr = material["pbrMetallicRoughness"]
        assert pbr["baseColorFactor"] == [1.0, 1.0, 1.0, 1.0]
        assert (pbr["metallicFactor"], pbr["roughnessFactor"]) == (0.0, 1.0)
        texture = document["textures"][pbr["baseColorTexture"]["index"]]
        image = document["images"][texture["source"]]
        assert image["mimeType"] == "image/png"
        view = document["bufferViews"][image["bufferView"]]
        png = binary[view["byteOffset"] : view["byteOffset"] + view["byteLength"]]
        assert png == page_png(impostor.pages[page_index])
        assert np.array_equal(np.asarray(Image.open(io.BytesIO(png))), impostor.pages[page_index])

        quads = np.flatnonzero(impostor.payload.page == page_index)
        position_accessor = document["accessors"][primitive["attributes"]["POSITION"]]
        positions = accessor_array(document, binary, primitive["attributes"]["POSITION"])
        assert position_accessor["min"] == positions.min(axis=0).tolist()
        assert position_accessor["max"] == positions.max(axis=0).tolist()
        relative = (impostor.payload.corners[quads] - impostor.reference_viewpoint).reshape(-1, 3)
        assert np.array_equal(positions, relative.astype(np.float32))
        uv = accessor_array(document, binary, primitive["attributes"]["TEXCOORD_0"])
        assert np.array_equal(uv, impostor.payload.uv[quads].reshape(-1, 2).astype(np.float32))
        indices = accessor_array(document, binary, primitive["indices"]).reshape(-1, 3)
        assert indices.shape == (2 * quads.size, 3) and indices.max() < positions.shape[0]
        assert_faces_viewpoint(positions, indices)


@pytest.mark.parametrize("viewpoint", [ORIGIN, CONTINENTAL], ids=["origin", "continental"])
def test_glb_loads_in_trimesh_at_world_position(tmp_path, viewpoint):
    impostor = make_impostor(viewpoint)
    path = write_bundle(impostor, tmp_path / "b").glb
    scene = trimesh.load(path, force="scene")
    meshes = scene.dump()  # scene-graph transforms applied
    assert len(meshes) == len(impostor.pages)
    # float32 relative to the viewpoint: error scales with the distance from it, not with 4e6 m.
    # Storing world float32 would be off by up to 0.25 m here.
    reach = np.abs(impostor.payload.corners - impostor.reference_viewpoint).max()
    atol = 1e-6 * reach + 1e-9
    seen_pages = set()
    for mesh in meshes:
        texture = np.asarray(mesh.visual.material.baseColorTexture.convert("RGBA"))
        (page_index,) = [
            i for i, p in enumerate(impostor.pages) if p.shape == texture.shape and np.array_equal(p, texture)
        ]
        seen_pages.add(page_index)
        quads = np.flatnonzero(impostor.payload.page == page_index)
        world = impostor.payload.corners[quads].reshape(-1, 3)
        assert mesh.vertices.shape == world.shape
        assert np.allclose(mesh.vertices, world, rtol=0, atol=atol)
        uv = impostor.payload.uv[quads].reshape(-1, 2)
        # trimesh flips glTF's top-left V origin to bottom-left on import.
        assert np.allclose(mesh.visual.uv, np.column_stack([uv[:, 0], 1.0 - uv[:, 1]]), atol=1e-6)
        assert mesh.visual.material.alphaMode == "MASK"
    assert seen_pages == set(range(len(impostor.pages)))


@pytest.mark.parametrize("viewpoint", [ORIGIN, CONTINENTAL], ids=["origin", "continental"])
def test_glb_of_a_mesh_draws_its_triangles(tmp_path, viewpoint):
    impostor = make_mesh_impostor(viewpoint)
    mesh = impostor.payload
    document, binary = parse_glb(impostor_glb(impostor))
    (primitives,) = [m["primitives"] for m in document["meshes"]]
    assert [p["material"] for p in primitives] == [0, 1]
    relative = (mesh.vertices - impostor.reference_viewpoint).astype(np.float32)
    for primitive in primitives:
        page = primitive["material"]
        positions = accessor_array(document, binary, primitive["attributes"]["POSITION"])
        uv = accessor_array(document, binary, primitive["attributes"]["TEXCOORD_0"])
        indices = accessor_array(document, binary, primitive["indices"]).reshape(-1, 3).astype(np.int64)
        triangles = mesh.triangles[mesh.page == page]
        # Its own indexed triangles, each used vertex once, corners in order or the last two
        # swapped so that the triangle faces the reference viewpoint.
        assert indices.shape == triangles.shape
        assert positions.shape[0] == np.unique(triangles).size
        assert_faces_viewpoint(positions, indices)
        drawn = np.concatenate([positions[indices], uv[indices]], axis=2)
        stored = np.concatenate([relative[triangles], mesh.uv[triangles].astype(np.float32)], axis=2)
        swapped = stored[:, [0, 2, 1]]
        same = np.all(drawn == stored, axis=(1, 2))
        assert np.all(same | np.all(drawn == swapped, axis=(1, 2)))
        assert 0 < same.sum() < len(same)  # the random fan winds both ways: both cases are tested
    # trimesh sees the same triangles at their world positions.
    scene = trimesh.load(write_bundle(impostor, tmp_path / "m").glb, force="scene")
    assert sum(m.faces.shape[0] for m in scene.dump()) == mesh.triangle_count
    reach = np.abs(mesh.vertices - impostor.reference_viewpoint).max()
    for loaded in scene.dump():
        nearest = np.abs(loaded.vertices[:, None, :] - mesh.vertices[None, :, :]).max(axis=2).min(axis=1)
        assert np.all(nearest <= 1e-6 * reach + 1e-9)


def _longest_list(value) -> int:
    if isinstance(value, dict):
        return max((_longest_list(v) for v in value.values()), default=0)
    if isinstance(value, list):
        return max([len(value)] + [_longest_list(v) for v in value])
    return 0


def test_manifest_stays_small_for_a_mesh(tmp_path):
    """No per-vertex or per-triangle data in the JSON: the v1 TDM fixture's 31 kB manifest of
    corner lists becomes a few kB (its parameters and layers), the arrays go to payload.bin."""
    v1 = FIXTURES / "bundle_v1_tdm"
    impostor = read_bundle(v1)
    paths = write_bundle(impostor, tmp_path / "m")
    text = paths.manifest.read_text("utf-8")
    manifest = json.loads(text)
    assert "quads" not in manifest and set(manifest["payload"]) == {
        "kind",
        "counts",
        "file",
        "nbytes",
        "sha256",
        "arrays",
    }
    for key in ('"corners":[', '"uv":[', '"vertices":[', '"triangles":[', '"page":[', '"mesh":['):
        assert key not in text, key
    # Outside the per-layer lists and the parameters, no JSON list longer than the payload's table.
    rest = {k: v for k, v in manifest.items() if k not in ("layers", "parameters")}
    assert _longest_list(rest) == len(manifest["payload"]["arrays"]) == 5
    layers = len(json.dumps(manifest["layers"])) + len(json.dumps(manifest["parameters"]["plan"]))
    assert len(text) - layers < 4096 < (v1 / MANIFEST_NAME).stat().st_size
    # A thousand times the triangles would not grow it: only the counts and table numbers change.
    big = make_mesh_impostor(triangles=60000)
    assert len(write_bundle(big, tmp_path / "big").manifest.read_bytes()) < 2048


def _rewrite_manifest(directory: Path, change) -> None:
    path = directory / MANIFEST_NAME
    manifest = json.loads(path.read_text("utf-8"))
    change(manifest)
    path.write_text(json.dumps(manifest), "utf-8")


def _truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def _rewrite_payload(directory: Path, name: str, change) -> None:
    """Change one array of payload.bin in place (``change(array)``) and keep the manifest's digest
    in step, so only the change itself is wrong."""
    manifest = json.loads((directory / MANIFEST_NAME).read_text("utf-8"))
    (entry,) = [a for a in manifest["payload"]["arrays"] if a["name"] == name]
    data = bytearray((directory / PAYLOAD_NAME).read_bytes())
    count = entry["nbytes"] // np.dtype(entry["dtype"]).itemsize
    array = np.frombuffer(bytes(data), dtype=entry["dtype"], count=count, offset=entry["offset"]).copy()
    change(array)
    data[entry["offset"] : entry["offset"] + entry["nbytes"]] = array.tobytes()
    (directory / PAYLOAD_NAME).write_bytes(bytes(data))
    _rewrite_manifest(directory, lambda m: m["payload"].update(sha256=hashlib.sha256(bytes(data)).hexdigest()))


def _flip_a_byte(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x01
    path.write_bytes(bytes(data))


def _array_entry(name: str, **change):
    def spoil(manifest):
        (entry,) = [a for a in manifest["payload"]["arrays"] if a["name"] == name]
        entry.update(change)

    return spoil


BAD_BUNDLES = {
    "missing manifest": (lambda d: (d / MANIFEST_NAME).unlink(), MANIFEST_NAME),
    "manifest not JSON": (lambda d: (d / MANIFEST_NAME).write_text('{"format": '), MANIFEST_NAME),
    "manifest not an object": (lambda d: (d / MANIFEST_NAME).write_text("[1, 2]"), MANIFEST_NAME),
    "wrong format": (lambda d: _rewrite_manifest(d, lambda m: m.update(format="gltf")), MANIFEST_NAME),
    "wrong format_version": (lambda d: _rewrite_manifest(d, lambda m: m.update(format_version=3)), MANIFEST_NAME),
    "format_version true": (lambda d: _rewrite_manifest(d, lambda m: m.update(format_version=True)), MANIFEST_NAME),
    "missing key": (lambda d: _rewrite_manifest(d, lambda m: m.pop("technique")), MANIFEST_NAME),
    "missing payload": (lambda d: _rewrite_manifest(d, lambda m: m.pop("payload")), MANIFEST_NAME),
    "unknown payload kind": (
        lambda d: _rewrite_manifest(d, lambda m: m["payload"].update(kind="points")),
        MANIFEST_NAME,
    ),
    "payload count mismatch": (
        lambda d: _rewrite_manifest(d, lambda m: m["payload"]["counts"].update(quads=4)),
        MANIFEST_NAME,
    ),
    "array shape mismatch": (
        lambda d: _rewrite_manifest(d, _array_entry("uv", shape=[3, 4, 3], nbytes=288)),
        MANIFEST_NAME,
    ),
    "array shapes disagree": (lambda d: _rewrite_manifest(d, _array_entry("uv", shape=[2, 6, 2])), MANIFEST_NAME),
    "array big-endian": (lambda d: _rewrite_manifest(d, _array_entry("corners", dtype=">f8")), MANIFEST_NAME),
    "array misaligned": (lambda d: _rewrite_manifest(d, _array_entry("uv", offset=292)), MANIFEST_NAME),
    "arrays out of order": (lambda d: _rewrite_manifest(d, lambda m: m["payload"]["arrays"].reverse()), MANIFEST_NAME),
    "missing payload file": (lambda d: (d / PAYLOAD_NAME).unlink(), PAYLOAD_NAME),
    "truncated payload": (lambda d: _truncate(d / PAYLOAD_NAME), PAYLOAD_NAME),
    "corrupt payload": (lambda d: _flip_a_byte(d / PAYLOAD_NAME), PAYLOAD_NAME),
    "page out of range": (lambda d: _rewrite_payload(d, "page", lambda a: a.__setitem__(0, 5)), MANIFEST_NAME),
    "corner not finite": (lambda d: _rewrite_payload(d, "corners", lambda a: a.__setitem__(4, np.nan)), MANIFEST_NAME),
    "page size mismatch": (lambda d: _rewrite_manifest(d, lambda m: m["pages"][1].update(width=9)), "atlas-001.png"),
    "page file renamed": (
        lambda d: _rewrite_manifest(d, lambda m: m["pages"][0].update(file="../x.png")),
        MANIFEST_NAME,
    ),
    "truncated PNG": (lambda d: _truncate(d / "atlas-001.png"), "atlas-001.png"),
    "not a PNG": (lambda d: (d / "atlas-000.png").write_bytes(b"hello"), "atlas-000.png"),
    "missing page file": (lambda d: (d / "atlas-000.png").unlink(), "atlas-000.png"),
    "grey page": (lambda d: Image.new("L", (8, 6)).save(d / "atlas-000.png"), "atlas-000.png"),
    "missing GLB": (lambda d: (d / GLB_NAME).unlink(), GLB_NAME),
}


@pytest.mark.parametrize("name", list(BAD_BUNDLES))
def test_bad_bundle_raises_naming_the_file(tmp_path, name):
    spoil, culprit = BAD_BUNDLES[name]
    directory = write_bundle(make_impostor(), tmp_path / "b").directory
    read_bundle(directory)  # good before it is spoiled
    spoil(directory)
    with pytest.raises(BundleFormatError, match=culprit.replace(".", r"\.")):
        read_bundle(directory)


def test_mesh_index_out_of_range_raises(tmp_path):
    directory = write_bundle(make_mesh_impostor(), tmp_path / "m").directory
    _rewrite_payload(directory, "triangles", lambda a: a.__setitem__(7, 42))
    with pytest.raises(BundleFormatError, match="triangles index"):
        read_bundle(directory)


# ---- format version 1: bundles written by the previous writer (tests/fixtures/README.md) ----

FIXTURES = Path(__file__).parent / "fixtures"
V1_EXPECTED = json.loads((FIXTURES / "bundle_v1_expected.json").read_text("utf-8"))


def _digest(array: np.ndarray, dtype: str) -> str:
    return hashlib.sha256(np.ascontiguousarray(array, dtype=dtype).tobytes()).hexdigest()


@pytest.mark.parametrize("name", ["layered", "tdm"])
def test_reads_version_1_bundles(tmp_path, name):
    expected = V1_EXPECTED[name]
    directory = FIXTURES / f"bundle_v1_{name}"
    assert json.loads((directory / MANIFEST_NAME).read_text("utf-8"))["format_version"] == 1
    impostor = read_bundle(directory)
    assert impostor.technique == expected["technique"] == name
    assert impostor.triangle_count == expected["triangles"]
    assert [list(p.shape) for p in impostor.pages] == expected["pages"]
    assert [hashlib.sha256(p.tobytes()).hexdigest() for p in impostor.pages] == expected["pages_sha256"]
    payload = impostor.payload
    if name == "layered":
        assert isinstance(payload, QuadPayload) and impostor.quad_count == expected["quads"]
        corners, uv, page, layer = payload.corners, payload.uv, payload.page, payload.layer
    else:
        # A v1 TDM's repeated-corner quads come back as the mesh of its real triangles.
        assert isinstance(payload, MeshPayload) and impostor.quad_count == 0
        assert payload.count == expected["quads"] == expected["stats_triangles"]
        assert payload.vertices.shape[0] < 3 * payload.count  # welded: triangles share vertices
        corners = payload.triangle_corners()[:, [0, 1, 2, 2]]
        uv = payload.triangle_uv()[:, [0, 1, 2, 2]]
        page, layer = payload.page, payload.mesh
    assert float(np.sum(corners)) == expected["corners_sum"]
    assert _digest(corners, "<f8") == expected["corners_sha256"]
    assert _digest(uv, "<f8") == expected["uv_sha256"]
    assert _digest(page, "<i8") == expected["page_sha256"]
    assert _digest(layer, "<i8") == expected["layer_sha256"]
    # Rewritten, it is a version 2 bundle holding the same impostor.
    paths = write_bundle(impostor, tmp_path / "v2")
    assert json.loads(paths.manifest.read_text("utf-8"))["format_version"] == 2
    assert_impostors_equal(read_bundle(paths.directory), impostor)
    assert bundle_zip(directory) != bundle_zip(paths.directory)
    with zipfile.ZipFile(io.BytesIO(bundle_zip(directory))) as archive:
        assert PAYLOAD_NAME not in archive.namelist() and MANIFEST_NAME in archive.namelist()


V1_BAD = {
    "quad count mismatch": lambda m: m["quads"]["corners"].pop(),
    "ragged corners": lambda m: m["quads"]["uv"][0].pop(),
    "page out of range": lambda m: m["quads"]["page"].__setitem__(0, 5),
    "count not a count": lambda m: m["quads"].update(count="14"),
}


@pytest.mark.parametrize("name", list(V1_BAD))
def test_bad_version_1_bundle_raises(tmp_path, name):
    directory = tmp_path / "v1"
    shutil.copytree(FIXTURES / "bundle_v1_layered", directory)
    _rewrite_manifest(directory, V1_BAD[name])
    with pytest.raises(BundleFormatError, match=MANIFEST_NAME.replace(".", r"\.")):
        read_bundle(directory)


def test_bundle_zip_refuses_a_non_bundle(tmp_path):
    with pytest.raises(BundleFormatError, match="manifest"):
        bundle_zip(tmp_path)


def _bad_page_impostor() -> Impostor:
    good = make_impostor()
    return Impostor(
        **{name: getattr(good, name) for name in Impostor.__dataclass_fields__}
        | {"pages": (good.pages[0], good.pages[1].astype(np.float32))}
    )


def _siblings(path: Path) -> list[str]:
    return sorted(p.name for p in path.parent.iterdir())


def test_failed_write_leaves_nothing(tmp_path):
    destination = tmp_path / "out" / "cell-0"
    with pytest.raises(BundleFormatError, match="page 1"):
        write_bundle(_bad_page_impostor(), destination)
    assert not os.path.lexists(destination)
    assert not (tmp_path / "out").exists() or _siblings(destination) == []


def test_failed_write_keeps_the_old_bundle(tmp_path, monkeypatch):
    impostor = make_impostor()
    paths = write_bundle(impostor, tmp_path / "cell-0")
    before = {p.name: p.read_bytes() for p in paths.directory.iterdir()}
    with pytest.raises(BundleFormatError):
        write_bundle(_bad_page_impostor(), paths.directory)

    # A failure after some files are on disk (disk full) removes the staging directory too.
    real_write = farfield.core.impostor.bundle._write_file
    calls = []

    def failing_write(path, data):
        calls.append(path)
        if len(calls) == 3:
            raise OSError(28, "No space left on device", str(path))
        real_write(path, data)

    monkeypatch.setattr(farfield.core.impostor.bundle, "_write_file", failing_write)
    with pytest.raises(OSError, match="No space"):
        write_bundle(make_impostor(seed=9), paths.directory)
    assert len(calls) >= 3  # the files are written several at a time: the others may go on
    assert _siblings(paths.directory) == ["cell-0"]
    assert {p.name: p.read_bytes() for p in paths.directory.iterdir()} == before
    assert_impostors_equal(read_bundle(paths.directory), impostor)


def test_rewrite_replaces_the_whole_directory(tmp_path):
    destination = tmp_path / "cell-0"
    write_bundle(make_impostor(), destination)
    (destination / "stray.txt").write_text("left over")
    smaller = make_impostor(quads=QUADS[:1], page_shapes=PAGE_SHAPES[:1])
    paths = write_bundle(smaller, destination)
    assert sorted(p.name for p in destination.iterdir()) == [page_file_name(0), GLB_NAME, MANIFEST_NAME, PAYLOAD_NAME]
    assert paths.pages == (destination / page_file_name(0),)
    assert _siblings(destination) == ["cell-0"]
    assert_impostors_equal(read_bundle(destination), smaller)
    # A plain file in the way is replaced too.
    blocked = tmp_path / "blocked"
    blocked.write_text("a file")
    write_bundle(smaller, blocked)
    assert_impostors_equal(read_bundle(blocked), smaller)


def test_the_manifest_holds_no_timings(tmp_path):
    write_bundle(make_mesh_impostor(), tmp_path / "b")
    manifest = json.loads((tmp_path / "b" / MANIFEST_NAME).read_text())
    assert "seconds" not in manifest["stats"] and manifest["stats"]["triangles"] > 0


def test_page_pngs_remembered_by_a_bake_are_not_encoded_again_and_go_with_their_page():
    """envmap measures its pages' PNG size with PagePngs(remember=True); the bundle writer's own
    PagePngs then takes those bytes instead of encoding each page again, and they are forgotten
    when their page is (no leak across bakes); a PagePngs without ``remember`` leaves nothing."""
    import gc

    from farfield.core.impostor import png_pages

    page = np.random.default_rng(3).integers(0, 256, (64, 64, 4), dtype=np.uint8)
    other = page.copy()
    (measured,) = png_pages.PagePngs(workers=1, remember=True).encode([page])
    written, fresh = png_pages.PagePngs(workers=1).encode([page, other])
    assert written is measured and fresh is not measured and fresh == measured  # the same bytes, not re-encoded
    png_pages.PagePngs(workers=1).encode([other])
    assert id(page) in png_pages._REMEMBERED and id(other) not in png_pages._REMEMBERED
    key = id(page)
    del page
    gc.collect()
    assert key not in png_pages._REMEMBERED


def test_a_folder_of_bundles_is_refused_naming_them(tmp_path):
    """``farfield bake --instances --out DIR`` writes one bundle per prototype under DIR: reading DIR
    itself said only "DIR/manifest.json: missing, not a bundle", not where the bundles are."""
    write_bundle(make_impostor(), tmp_path / "out" / "d8eb37e615278b10")
    write_bundle(make_impostor(seed=8), tmp_path / "out" / "0a1b2c3d4e5f6071")
    with pytest.raises(BundleFormatError, match=r"holds 2 bundles: .*0a1b2c3d4e5f6071.*d8eb37e615278b10"):
        read_bundle(tmp_path / "out")
    with pytest.raises(BundleFormatError, match=r"missing, not a bundle$"):
        read_bundle(tmp_path / "empty")
