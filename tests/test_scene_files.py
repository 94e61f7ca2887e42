"""Multi-file scenes (issue 30, item 1): a zip of a scene and the files it refers to, or several
multipart files; bounded unpacking (zip slip, zip bomb, too many files, the upload limit); the CLI
packing an OBJ's MTL and texture or a glTF's buffer and images; the stored scene loaded on a worker
with its files.  A scene uploaded with its files is the scene loaded from its folder: the same
content hash, textures included."""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import pytest
import trimesh
from scenes import SHARED_SCENES
from service_harness import service_on_sqlite, wait_for_job  # noqa: F401 - the service fixtures

from farfield.core.errors import SceneLoadError, UploadTooLargeError
from farfield.core.exchange import load_scene
from farfield.core.exchange.archive import MAX_FILES, member_path, pack_scene, referenced_files, unpack_scene_archive

DUCK = SHARED_SCENES / "duck" / "duck.obj"
HELMET = SHARED_SCENES / "damaged_helmet" / "DamagedHelmet.glb"
LIMIT = 64 << 20


def zipped(files: dict[str, bytes], method=zipfile.ZIP_DEFLATED) -> bytes:
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", method) as archive:
        for name, body in files.items():
            archive.writestr(name, body)
    return out.getvalue()


def duck_files() -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in DUCK.parent.iterdir()}


@pytest.fixture(scope="module")
def helmet_gltf(tmp_path_factory) -> Path:
    """The helmet as a .gltf with its buffer and images as files beside it (written by trimesh)."""
    folder = tmp_path_factory.mktemp("helmet-gltf")
    for name, body in trimesh.load(HELMET, force="scene").export(file_type="gltf").items():
        (folder / name).write_bytes(body)
    return folder / "model.gltf"


def unpack(tmp_path: Path, data: bytes, limit: int = LIMIT):
    """``unpack_scene_archive`` of ``data``: (the archive, its scene's bytes, its assets by name)."""
    source = tmp_path / "upload.zip"
    source.write_bytes(data)
    work = tmp_path / "work"
    work.mkdir(exist_ok=True)
    found = unpack_scene_archive(source, limit, work)
    assets = {}
    if found.assets is not None:
        with zipfile.ZipFile(found.assets) as archive:
            assets = {n: archive.read(n) for n in archive.namelist()}
    return found, found.scene.read_bytes(), assets


def test_member_names_outside_the_archive_are_refused(tmp_path):
    assert str(member_path("./a/b.png")) == "a/b.png"
    for name in ("../evil.png", "a/../../evil.png", "/etc/passwd", "C:\\evil.png", "..\\evil.png"):
        with pytest.raises(SceneLoadError, match="outside the archive"):
            member_path(name)
    with pytest.raises(SceneLoadError, match="outside the archive"):
        unpack(tmp_path, zipped({"duck.obj": b"v 0 0 0", "../../evil.mtl": b""}))
    assert not list((tmp_path / "work").rglob("evil*"))


def test_an_archive_holds_exactly_one_scene_and_its_folder_s_files(tmp_path):
    files = duck_files()
    found, scene, assets = unpack(
        tmp_path,
        zipped({f"models/{k}": v for k, v in files.items()} | {"readme.txt": b"hi", "__MACOSX/._duck.obj": b"junk"}),
    )
    assert found.name == "duck.obj" and scene == files["duck.obj"] and found.size == sum(len(v) for v in files.values())
    assert assets == {"duck.mtl": files["duck.mtl"], "duckCM.png": files["duckCM.png"]} and found.skipped == (
        "readme.txt",
    )
    with pytest.raises(SceneLoadError, match="exactly one scene file.*found none"):
        unpack(tmp_path, zipped({"duck.mtl": files["duck.mtl"]}))
    with pytest.raises(SceneLoadError, match="exactly one scene file.*a.obj, b.glb"):
        unpack(tmp_path, zipped({"a.obj": b"", "b.glb": b""}))
    with pytest.raises(SceneLoadError, match="not a readable zip"):
        unpack(tmp_path, b"PK\x03\x04 truncated")
    with pytest.raises(SceneLoadError, match="two members are named 'T.png'"):
        unpack(tmp_path, zipped({"a.obj": b"", "t.png": b"1", "./T.png": b"2"}))


def test_unreadable_members_are_bad_input_not_a_crash(tmp_path):
    corrupt = bytearray(zipped({"a.obj": b"v 0 0 0\n" * 1000}, zipfile.ZIP_STORED))
    at = corrupt.index(b"v 0 0 0")
    corrupt[at : at + 7] = b"x 9 9 9"  # the stored bytes no longer match their CRC
    with pytest.raises(SceneLoadError, match="cannot be read .*BadZipFile"):
        unpack(tmp_path, bytes(corrupt))
    encrypted = bytearray(zipped({"a.obj": b"v 0 0 0\n"}, zipfile.ZIP_STORED))
    for at in (6, encrypted.index(b"PK\x01\x02") + 8):  # the encrypted flag, in the local and the central header
        encrypted[at] |= 1
    with pytest.raises(SceneLoadError, match="cannot be read"):
        unpack(tmp_path, bytes(encrypted))


def test_bombs_too_many_files_and_the_limit_are_refused_before_inflating(tmp_path):
    bomb = zipped({"scene.obj": b"v 0 0 0\n", "huge.png": bytes(64 << 20)})
    assert len(bomb) < 1 << 20
    with pytest.raises(UploadTooLargeError, match="inflates .* times"):
        unpack(tmp_path, bomb, 1 << 30)
    with pytest.raises(UploadTooLargeError, match=f"more than the {MAX_FILES}"):
        unpack(tmp_path, zipped({f"f{i}.txt": b"" for i in range(MAX_FILES + 1)} | {"a.obj": b""}, zipfile.ZIP_STORED))
    many = zipped(
        {f"d{i}/": b"" for i in range(3 * MAX_FILES)} | {"a.obj": b""}, zipfile.ZIP_STORED
    )  # entries counted before zipfile reads them
    with pytest.raises(UploadTooLargeError, match="entries, more than"):
        unpack(tmp_path, many)
    stored = zipped(
        {"scene.obj": b"v 0 0 0\n", "big.png": bytes(3 << 20)}, zipfile.ZIP_STORED
    )  # no ratio to catch: the limit does
    with pytest.raises(UploadTooLargeError, match="more than the upload limit uncompressed"):
        unpack(tmp_path, stored, 2 << 20)


def test_references_resolve_among_the_upload_s_files_as_other_tools_name_them():
    from farfield.core.exchange.trimesh_scene import asset_resolver, fetch

    resolver = asset_resolver(
        "scene.gltf", assets={"textures/Tex.png": b"png", "my buffer.bin": b"bin", "café.bin": b"cafe"}
    )
    for reference, body in (("textures/Tex.png", b"png"), ("./textures/tex.png", b"png"), ("textures\\Tex.png", b"png"), ("Tex.png", b"png"),
                            ("-s 1 1 1 textures/Tex.png", b"png"), ("my%20buffer.bin", b"bin"), ("caf%C3%A9.bin", b"cafe")):  # fmt: skip
        assert fetch(resolver, reference) == body, reference
    assert fetch(resolver, "other.png") is None


def test_packing_finds_an_obj_s_mtl_and_texture_and_a_gltf_s_buffer_and_images(helmet_gltf, tmp_path):
    assert referenced_files(DUCK) == ["duck.mtl", "duckCM.png"]
    with zipfile.ZipFile(io.BytesIO(pack_scene(DUCK))) as archive:
        assert sorted(archive.namelist()) == ["duck.mtl", "duck.obj", "duckCM.png"]
    document = json.loads(helmet_gltf.read_text())
    wanted = {b["uri"] for b in document["buffers"]} | {i["uri"] for i in document.get("images", []) if "uri" in i}
    assert wanted and set(referenced_files(helmet_gltf)) == wanted
    # no references that leave the folder, none that are URIs, none that do not exist
    (tmp_path / "x.obj").write_text("mtllib ../outside.mtl missing.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    assert referenced_files(tmp_path / "x.obj") == [] and pack_scene(tmp_path / "x.obj") is None
    # names are the rest of the line, as the loader reads them; a map's options are skipped
    (tmp_path / "my mat.mtl").write_text("newmtl a\nmap_Kd my tex.png\nnewmtl b\nmap_Kd -s 1 1 1 plain.png\n")
    (tmp_path / "my tex.png").write_bytes(b"1")
    (tmp_path / "plain.png").write_bytes(b"2")
    (tmp_path / "y.obj").write_text("  mtllib my mat.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    assert referenced_files(tmp_path / "y.obj") == ["my mat.mtl", "my tex.png", "plain.png"]
    assert pack_scene(HELMET) is None  # a .glb holds its files


@pytest.mark.slow
def test_a_stored_multi_file_scene_loads_on_a_worker_with_its_texture(tmp_path):
    from farfield.service.blobs import LocalBlobStore
    from farfield.service.db import Database
    from farfield.service.keys import tenant_named
    from farfield.service.scenes import _CACHE, ingest_scene, load_stored_scene

    home = tmp_path / "home"
    db = Database(f"sqlite:///{tmp_path / 'db.sqlite'}")
    db.migrate()
    blobs = LocalBlobStore(home)
    tenant = tenant_named(db, "files").id
    local = load_scene(DUCK)
    assert local.objects[0].texture is not None
    row = ingest_scene(db, blobs, tenant, "duck.zip", io.BytesIO(pack_scene(DUCK)), LIMIT)
    assert row.name == "duck.obj" and row.content_hash == local.content_hash and row.upload_warnings == []
    _CACHE.clear()
    loaded = load_stored_scene(blobs, row)
    assert loaded.content_hash == local.content_hash and loaded.objects[0].texture is not None
    parts = [(n, io.BytesIO(b)) for n, b in duck_files().items() if n != "duck.obj"]
    again = ingest_scene(db, blobs, tenant, "duck.obj", io.BytesIO(DUCK.read_bytes()), LIMIT, more=parts)
    assert again.content_hash == local.content_hash
    bare = ingest_scene(
        db,
        blobs,
        tenant,
        "duck.obj",
        io.BytesIO(DUCK.read_bytes()),
        LIMIT,
        more=[("duck.mtl", io.BytesIO(duck_files()["duck.mtl"]))],
    )
    assert bare.content_hash != local.content_hash and any("duckCM.png" in w for w in bare.upload_warnings)
    db.dispose()


def test_multi_file_scenes_over_rest_and_the_cli_and_bad_archives_leave_nothing(service, helmet_gltf, tmp_path):
    with service.client() as client:
        local = load_scene(DUCK)
        as_zip = client.post("/v1/scenes", files={"file": ("duck.zip", pack_scene(DUCK), "application/zip")})
        assert as_zip.status_code == 201, as_zip.text
        assert as_zip.json()["content_hash"] == local.content_hash and as_zip.json()["warnings"] == []
        several = client.post("/v1/scenes", files=[("file", (n, b)) for n, b in duck_files().items()])
        assert several.status_code == 201, several.text
        assert several.json()["content_hash"] == local.content_hash and several.json()["name"] == "duck.obj"
        # the scene's name as uploaded, whatever field comes first (it was the first field's: "duckCM.png")
        texture_first = sorted(duck_files().items(), key=lambda item: not item[0].endswith(".png"))
        texture_first = client.post("/v1/scenes", files=[("file", item) for item in texture_first])
        assert texture_first.json()["original_name"] == "duck.obj", texture_first.text
        missing = client.post(
            "/v1/scenes", files=[("file", (n, b)) for n, b in duck_files().items() if n != "duckCM.png"]
        )
        assert missing.status_code == 201 and any("duckCM.png" in w for w in missing.json()["warnings"])
        helmet = load_scene(helmet_gltf)
        gltf = client.post(
            "/v1/scenes", files=[("file", (p.name, p.read_bytes())) for p in helmet_gltf.parent.iterdir()]
        )
        assert gltf.status_code == 201, gltf.text
        assert gltf.json()["content_hash"] == helmet.content_hash and gltf.json()["triangles"] == helmet.triangle_count

        before = client.get("/v1/scenes").json()
        slip = client.post(
            "/v1/scenes", files={"file": ("slip.zip", zipped({"duck.obj": DUCK.read_bytes(), "../../evil.png": b"x"}))}
        )
        assert slip.status_code == 422 and "outside the archive" in slip.json()["detail"]
        bomb = client.post(
            "/v1/scenes",
            files={"file": ("bomb.zip", zipped({"duck.obj": DUCK.read_bytes(), "big.png": bytes(32 << 20)}))},
        )
        assert bomb.status_code == 413 and "zip bomb" in bomb.json()["detail"]
        two = client.post("/v1/scenes", files=[("file", ("a.obj", b"v 0 0 0")), ("file", ("b.obj", b"v 0 0 0"))])
        assert two.status_code == 422 and "exactly one scene file" in two.json()["detail"]
        assert client.get("/v1/scenes").json() == before  # nothing stored

        # The CLI packs the OBJ's files; the job's worker loads them (the cell is textured).
        auth = ("--url", service.url, "--key", service.env["FARFIELD_ADMIN_KEY"])
        done = service.cli(
            "submit",
            str(DUCK),
            "--grid",
            "-0.2,0.7,2.5,0.2,1.1,2.9,1,1,1",
            "--resolution",
            "32",
            "--wait",
            "--json",
            *auth,
        )
        assert done.returncode == 0, done.stderr
        job = json.loads(done.stdout.strip().splitlines()[-1])
        assert job["state"] == "done"
        scene = client.get(f"/v1/scenes/{job['scene_id']}").json()
        assert scene["content_hash"] == local.content_hash
        assert wait_for_job(client, job["id"])["state"] == "done"


# --- farfield scenes demo (issue 30, item 5) -------------------------------------------------


@pytest.mark.parametrize(
    "name, extra", [("city", ["--size", "9", "--detail", "4"]), ("house", []), ("forest", ["--size", "12"])]
)
def test_scenes_demo_writes_the_procedural_scene_as_a_glb_that_loads_back(tmp_path, name, extra):
    from click.testing import CliRunner

    from farfield.cli.main import _register, cli
    from farfield.core.procedural import demo_scene

    _register()
    out = tmp_path / "sub" / f"{name}.glb"
    result = CliRunner().invoke(cli, ["scenes", "demo", name, "--out", str(out), "--json", *extra])
    assert result.exit_code == 0, result.output
    made = json.loads(result.output)
    size = int(extra[extra.index("--size") + 1]) if "--size" in extra else None
    detail = int(extra[extra.index("--detail") + 1]) if "--detail" in extra else 1
    expected = demo_scene(name, size, None, detail)
    loaded = load_scene(out)
    assert (
        made["triangles"] == loaded.triangle_count == expected.triangle_count
        and made["objects"] == expected.object_count
    )
    assert sorted(loaded.names) == sorted(expected.names)
    assert loaded.bounds == pytest.approx(expected.bounds, abs=1e-4)  # float32 in the GLB
    assert not list(out.parent.glob(".*.part"))


@pytest.mark.parametrize(
    "args, message",
    [
        (["scenes", "demo", "castle", "--out", "x.glb"], "NAME is one of city"),
        (["scenes", "demo", "city"], "needs --out"),
        (["scenes", "demo", "city", "--out", "x.obj"], "give a .glb file name"),
        (["scenes", "demo", "house", "--out", "x.glb", "--size", "3"], "not the house"),
        (["scenes", "abc", "--out", "x.glb"], "go with 'farfield scenes demo NAME'"),
        (["scenes", "a", "b"], "expected one SCENE_ID"),
    ],
)
def test_scenes_demo_bad_input_is_one_line_and_writes_nothing(tmp_path, monkeypatch, args, message):
    from click.testing import CliRunner

    from farfield.cli.main import _register, cli

    _register()
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 2 and message in result.output, result.output
    assert list(tmp_path.iterdir()) == []
