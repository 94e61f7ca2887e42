"""Compressed impostor GLBs (:mod:`farfield.core.impostor.glb_compression`): meshopt geometry decodes back to the
plain GLB's bytes exactly (meshoptimizer's own decoder), KTX2 pages decode back to the PNG pages
within the codec's error (Basis Universal's transcoder), the PNG fallback is the plain PNG, the
bytes are deterministic, bad requests are refused, and ``farfield glb`` writes the file whole or
not at all.  three.js drawing the compressed GLBs: ``tests/test_threejs.py``."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys

import meshopt
import numpy as np
import pytest
from PIL import Image
from test_techniques import CASES

from farfield.core.errors import BundleFormatError
from farfield.core.impostor.bundle import write_bundle
from farfield.core.impostor.glb import impostor_glb
from farfield.core.impostor.glb_compression import BASISU, MESHOPT, compress_glb, decode_ktx2, read_glb, write_glb
from farfield.core.techniques import TECHNIQUES, get_technique

pytestmark = pytest.mark.slow  # ./run-tests --fast leaves it out (tests/conftest.py: the tiers)

RESOLUTION = 64


@pytest.fixture(scope="module")
def plain_glbs():
    """Per technique: the plain GLB of an impostor baked at 64 px."""
    out = {}
    for name in TECHNIQUES:
        technique = get_technique(name)
        make_scene, cell = CASES[technique.scope]
        out[name] = impostor_glb(technique.bake(make_scene(), cell, technique.options({}, RESOLUTION), None, None))
    return out


def view_bytes(document: dict, blob: bytes, n: int) -> bytes:
    view = document["bufferViews"][n]
    return blob[view.get("byteOffset", 0) : view.get("byteOffset", 0) + view["byteLength"]]


def rotated(triangles: np.ndarray) -> np.ndarray:
    """Each triangle's corners rotated (winding kept) to start at its smallest index."""
    first = np.argmin(triangles, axis=1)
    return np.stack([triangles[np.arange(len(triangles)), (first + k) % 3] for k in range(3)], axis=1)


def images(glb: bytes, mime: str) -> list[bytes]:
    document, blob = read_glb(glb)
    return [
        view_bytes(document, blob, img["bufferView"]) for img in document.get("images", []) if img["mimeType"] == mime
    ]


@pytest.mark.parametrize("name", list(TECHNIQUES))
def test_meshopt_geometry_decodes_to_the_plain_bytes(name, plain_glbs):
    plain = plain_glbs[name]
    packed = compress_glb(plain, "png", "meshopt")
    before, blob_before = read_glb(plain)
    after, blob_after = read_glb(packed)
    assert after["extensionsRequired"] == [MESHOPT] and MESHOPT in after["extensionsUsed"]
    assert after["buffers"][1] == {
        "byteLength": after["buffers"][1]["byteLength"],
        "extensions": {MESHOPT: {"fallback": True}},
    }
    assert len(after["bufferViews"]) == len(before["bufferViews"])
    compressed = set()
    for n, view in enumerate(after["bufferViews"]):
        ext = view.get("extensions", {}).get(MESHOPT)
        if ext is None:  # an image (or an accessor of elements meshopt cannot take): as it was
            assert view_bytes(after, blob_after, n) == view_bytes(before, blob_before, n)
            continue
        data = blob_after[ext["byteOffset"] : ext["byteOffset"] + ext["byteLength"]]
        decoded = np.asarray(meshopt.decode_gltf_buffer(data, ext["count"], ext["byteStride"], ext["mode"]))
        original = view_bytes(before, blob_before, n)
        if ext["mode"] == "TRIANGLES":  # meshopt's index codec may start a triangle at another corner (same winding)
            dtype = np.uint16 if ext["byteStride"] == 2 else np.uint32
            a, b = (np.frombuffer(x, dtype).reshape(-1, 3) for x in (decoded.tobytes(), original))
            assert np.array_equal(rotated(a), rotated(b)), n
        else:
            assert decoded.tobytes() == original, (n, ext["mode"])
        assert view["byteLength"] == ext["count"] * ext["byteStride"] and view["buffer"] == 1
        compressed.add(n)
    # Every vertex and index view; beside them only accessors' views (an octahedral impostor's
    # per-frame arrays, which its extension reads), never an image.
    geometry = {n for n, v in enumerate(before["bufferViews"]) if v.get("target") in (34962, 34963)}
    assert geometry <= compressed <= {a["bufferView"] for a in before.get("accessors", [])}
    assert [a["bufferView"] for a in after.get("accessors", [])] == [
        a["bufferView"] for a in before.get("accessors", [])
    ]


# Mean |RGB| error (0..255) on the texels the alpha cut keeps, per codec.  A point impostor's pages
# are rows of tiles a few texels wide: ETC1S's shared endpoints blur them (19 here), UASTC does not.
MEAN_ERROR = {"etc1s": 8.0, "uastc": 2.0, ("points", "etc1s"): 24.0}


@pytest.mark.parametrize("codec", ["etc1s", "uastc"])
@pytest.mark.parametrize("name", list(TECHNIQUES))
def test_ktx2_pages_decode_to_the_png_pages_within_the_codecs_error(name, codec, plain_glbs):
    mean_error = MEAN_ERROR.get((name, codec), MEAN_ERROR[codec])
    plain = plain_glbs[name]
    packed = compress_glb(plain, "ktx2", "plain", codec)
    document, _ = read_glb(packed)
    assert BASISU in document["extensionsRequired"] and not images(packed, "image/png")
    assert all(set(t) == {"sampler", "extensions"} for t in document.get("textures", []))  # no PNG source left
    pngs = [np.asarray(Image.open(io.BytesIO(data)).convert("RGBA")) for data in images(plain, "image/png")]
    pages = [decode_ktx2(data) for data in images(packed, "image/ktx2")]
    assert len(pages) == len(pngs) and pngs
    for png, page in zip(pngs, pages):
        # KHR_texture_basisu: whole 4 x 4 blocks; a page grows right and down by repeating its edge
        h, w = png.shape[:2]
        assert page.shape == (h + -h % 4, w + -w % 4, 4), (page.shape, png.shape)
        page = page[:h, :w]
        kept = png[..., 3] >= 128
        error = np.abs(png[..., :3].astype(int) - page[..., :3].astype(int))[kept]
        assert error.mean() <= mean_error, (name, codec, error.mean())
        flips = int((kept != (page[..., 3] >= 128)).sum())
        # The alpha cut holds where the page is an image of the impostor; a point impostor's pages
        # are rows of small tiles, where the codec's 4 x 4 blocks straddle tile borders.
        assert flips == 0 or name == "points", (name, codec, flips)


def test_pages_grown_to_whole_blocks_keep_their_texture_coordinates(plain_glbs):
    """A page whose sides are not multiples of 4 grows; the coordinates that use it shrink by the
    same factor, so every texel stays where it was (three.js checks the drawing: test_threejs)."""
    grown = 0
    for name, plain in {**plain_glbs, "odd page": odd_page_glb()}.items():
        before, blob_before = read_glb(plain)
        after, blob_after = read_glb(compress_glb(plain, "ktx2"))
        sizes = [
            Image.open(io.BytesIO(view_bytes(before, blob_before, img["bufferView"]))).size
            for img in before.get("images", [])
        ]
        for mesh_before, mesh_after in zip(before.get("meshes", []), after.get("meshes", [])):
            for p, q in zip(mesh_before["primitives"], mesh_after["primitives"]):
                if "TEXCOORD_0" not in p["attributes"]:
                    continue
                w, h = sizes[
                    before["textures"][
                        before["materials"][p["material"]]["pbrMetallicRoughness"]["baseColorTexture"]["index"]
                    ]["source"]
                ]
                uv_before = np.frombuffer(
                    view_bytes(before, blob_before, before["accessors"][p["attributes"]["TEXCOORD_0"]]["bufferView"]),
                    "<f4",
                ).reshape(-1, 2)
                uv_after = np.frombuffer(
                    view_bytes(after, blob_after, after["accessors"][q["attributes"]["TEXCOORD_0"]]["bufferView"]),
                    "<f4",
                ).reshape(-1, 2)
                factor = np.array([w / (w + -w % 4), h / (h + -h % 4)], "<f4")
                assert np.array_equal(uv_after, (uv_before * factor).astype("<f4")), name
                grown += bool(w % 4 or h % 4)
    assert grown > 0, "no page of the cases has a side that is not a multiple of 4"


def odd_page_glb() -> bytes:
    """A quad impostor whose one page is 10 x 6 texels (neither side a multiple of 4): a face of
    four colour bands, transparent at its left column."""
    from farfield.core.impostor.impostor import Impostor, QuadPayload

    page = np.zeros((6, 10, 4), np.uint8)
    page[..., 3] = 255
    page[:, 0, 3] = 0
    for k, colour in enumerate(([220, 40, 40], [40, 200, 60], [50, 80, 230], [240, 220, 40])):
        page[:, 1 + 2 * k + (k > 0) :, :3] = colour
    quad = np.array([[[-2.0, 1.2, 5.0], [2.0, 1.2, 5.0], [2.0, -1.2, 5.0], [-2.0, -1.2, 5.0]]])
    uv = np.array([[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]])
    return impostor_glb(
        Impostor(
            "billboard",
            {},
            np.zeros(3),
            64,
            60.0,
            (page,),
            QuadPayload(quad, uv, np.zeros(1, np.int64), np.zeros(1, np.int64)),
        )
    )


def test_an_empty_point_impostor_compresses_to_a_valid_file(gltf_validator, tmp_path):
    from farfield.core.impostor.impostor import Impostor, PointPayload

    empty = impostor_glb(
        Impostor(
            "points", {"kind": "box", "lo": [0, 0, 0], "hi": [1, 1, 1]}, np.zeros(3), 64, 45.0, (), PointPayload.empty()
        )
    )
    path = tmp_path / "empty.glb"
    path.write_bytes(compress_glb(empty, "ktx2", "meshopt"))
    document, blob = read_glb(path.read_bytes())
    assert "buffers" not in document and blob == b"" and BASISU not in document.get("extensionsUsed", [])
    (report,) = gltf_validator.validate([path])
    assert report.get("errors") == 0 and report.get("warnings") == 0, report


def test_ktx2_with_the_png_kept_as_fallback(plain_glbs):
    plain = plain_glbs["layered"]
    packed = compress_glb(plain, "ktx2+png")
    document, _ = read_glb(packed)
    assert BASISU in document["extensionsUsed"] and "extensionsRequired" not in document
    kept = [np.asarray(Image.open(io.BytesIO(d))) for d in images(packed, "image/png")]
    for page, png in zip(kept, (np.asarray(Image.open(io.BytesIO(d))) for d in images(plain, "image/png"))):
        assert np.array_equal(
            page[: png.shape[0], : png.shape[1]], png
        )  # the same texels (grown alike when not whole blocks)
    for texture in document["textures"]:
        assert document["images"][texture["source"]]["mimeType"] == "image/png"
        assert document["images"][texture["extensions"][BASISU]["source"]]["mimeType"] == "image/ktx2"
    assert len(packed) > len(plain)  # the fallback costs bytes: what it saves is GPU memory


def test_the_same_glb_compresses_to_the_same_bytes(plain_glbs):
    plain = plain_glbs["envmap"]
    assert compress_glb(plain, "ktx2", "meshopt") == compress_glb(plain, "ktx2", "meshopt")
    assert compress_glb(plain, "png", "plain") == plain


@pytest.mark.parametrize(
    "args, message",
    [
        (("webp", "plain"), "textures must be one of"),
        (("png", "draco"), "geometry must be one of"),
        (("ktx2", "plain", "bc7"), "codec must be one of"),
    ],
)
def test_bad_requests_are_refused(plain_glbs, args, message):
    with pytest.raises(BundleFormatError, match=message):
        compress_glb(plain_glbs["layered"], *args)


def test_what_cannot_be_compressed_is_refused(plain_glbs):
    packed = compress_glb(plain_glbs["layered"], "ktx2", "meshopt")
    with pytest.raises(BundleFormatError, match="compressed already"):
        compress_glb(packed, "ktx2", "meshopt")
    with pytest.raises(BundleFormatError, match="not a GLB"):
        compress_glb(b"not a glb at all, just bytes", "ktx2")
    document, blob = read_glb(plain_glbs["layered"])
    document["images"][0]["bufferView"] = document["accessors"][0]["bufferView"]  # the "PNG" is index bytes
    with pytest.raises(BundleFormatError, match="not one this can compress"):
        compress_glb(write_glb(document, blob), "ktx2")


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "farfield.cli.main", *args], capture_output=True, text=True, timeout=300
    )


def test_the_command_writes_a_compressed_glb_from_a_bundle(tmp_path):
    technique = get_technique("layered")
    make_scene, cell = CASES["part"]
    bundle = write_bundle(
        technique.bake(make_scene(), cell, technique.options({}, RESOLUTION), None, None), tmp_path / "bundle"
    )
    out = tmp_path / "out" / "cell.glb"
    done = run_cli("glb", str(bundle.directory), "--out", str(out), "--json")
    assert done.returncode == 0, done.stderr
    figures = json.loads(done.stdout)
    assert figures["bytes_after"] == out.stat().st_size and figures["bytes_before"] == bundle.glb.stat().st_size
    assert read_glb(out.read_bytes())[0]["extensionsRequired"] == [MESHOPT, BASISU]
    done = run_cli(
        "glb", str(bundle.glb), "--out", str(tmp_path / "fallback.glb"), "--textures", "ktx2+png", "--geometry", "plain"
    )
    assert done.returncode == 0 and "fallback.glb:" in done.stdout, done.stderr
    assert (out.stat().st_mode & 0o777) == 0o666 & ~current_umask()
    # bad input: one line, a non-zero exit, nothing written
    (tmp_path / "folder.glb").mkdir()
    for args in (["glb", str(tmp_path / "missing"), "--out", str(tmp_path / "x.glb")], ["glb", str(out), "--out", str(tmp_path / "y.glb")],
                 ["glb", str(bundle.glb), "--out", str(tmp_path / "folder.glb")]):  # fmt: skip
        failed = run_cli(*args)
        assert (
            failed.returncode != 0 and failed.stderr.count("\n") == 1 and failed.stderr.startswith("farfield: error:")
        ), failed.stderr
    assert not (tmp_path / "x.glb").exists() and not (tmp_path / "y.glb").exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == [] and list(
        (tmp_path / "folder.glb").iterdir()
    ) == []


def current_umask() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return umask
