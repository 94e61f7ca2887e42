"""The blob stores: the same behaviour from the local directory store and the S3 store.

The S3 store runs against a real S3-compatible server process: moto's server on a free local
port (no AWS, no network), driven through boto3 like MinIO would be.
"""

from __future__ import annotations

import io
import socket
import uuid
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from farfield.core.errors import NotFoundError, ServiceConfigError, UploadTooLargeError
from farfield.service.blobs import MIN_PART, BlobStore, LocalBlobStore, S3BlobStore, blob_store
from farfield.service.settings import Settings

KEY, SECRET, REGION = "farfield-test", "farfield-test-secret", "us-east-1"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def s3_endpoint():
    """The URL of a moto S3 server running for this module."""
    from moto.server import ThreadedMotoServer

    port = _free_port()
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False)
    server.start()
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.stop()


def _s3_client(endpoint: str):
    import boto3

    return boto3.client(
        "s3", endpoint_url=endpoint, aws_access_key_id=KEY, aws_secret_access_key=SECRET, region_name=REGION
    )


@pytest.fixture
def bucket(s3_endpoint):
    """A new, empty bucket on the S3 server."""
    name = f"farfield-{uuid.uuid4().hex[:16]}"
    _s3_client(s3_endpoint).create_bucket(Bucket=name)
    return name


@pytest.fixture(params=["local", "s3"])
def store(request, tmp_path) -> BlobStore:
    """Each behaviour test runs once against each store."""
    if request.param == "local":
        return LocalBlobStore(tmp_path / "blobs")
    endpoint = request.getfixturevalue("s3_endpoint")
    name = request.getfixturevalue("bucket")
    # The smallest part S3 allows, so that multipart uploads are exercised with small test data.
    return S3BlobStore(
        name, endpoint_url=endpoint, access_key=KEY, secret_key=SECRET, region=REGION, part_size=MIN_PART
    )


def _leftovers(store: BlobStore) -> list[str]:
    """Everything the store holds: files (hidden temporaries too), or objects and unfinished multipart uploads."""
    if isinstance(store, LocalBlobStore):
        return sorted(str(p.relative_to(store.root)) for p in store.root.rglob("*") if p.is_file())
    objects = store.client.list_objects_v2(Bucket=store.bucket).get("Contents", [])
    uploads = store.client.list_multipart_uploads(Bucket=store.bucket).get("Uploads", [])
    return sorted([o["Key"] for o in objects] + [f"upload:{u['Key']}" for u in uploads])


def test_both_stores_have_the_interface(store):
    assert isinstance(store, BlobStore)


def test_round_trip(store):
    store.put_bytes("scenes/a/scene.obj", b"v 0 0 0\n")
    assert store.read_bytes("scenes/a/scene.obj") == b"v 0 0 0\n"
    store.put_bytes("scenes/a/scene.obj", b"replaced")
    assert store.read_bytes("scenes/a/scene.obj") == b"replaced"
    with store.open("scenes/a/scene.obj") as f:
        assert f.read() == b"replaced"
    assert b"".join(store.iter_chunks("scenes/a/scene.obj")) == b"replaced"
    store.put_bytes("empty/blob", b"")
    assert store.read_bytes("empty/blob") == b""


@pytest.mark.invalid_glb  # stores made-up bytes under .glb names
@pytest.mark.slow
def test_put_stream_round_trip_small_and_multipart(store):
    small = bytes(range(256)) * 100
    assert store.put_stream("scenes/s/small.glb", io.BytesIO(small), limit=len(small)) == len(small)
    assert store.read_bytes("scenes/s/small.glb") == small
    # Over one S3 part (5 MiB in these tests) and not a multiple of it: several parts, the last short.
    big = (bytes(range(251)) * 50_000)[: 2 * MIN_PART + 12_345]
    assert store.put_stream("scenes/s/big.glb", io.BytesIO(big)) == len(big)
    assert store.read_bytes("scenes/s/big.glb") == big
    assert b"".join(store.iter_chunks("scenes/s/big.glb")) == big
    if isinstance(store, S3BlobStore):  # a multipart object's ETag ends in "-<parts>"
        assert store.client.head_object(Bucket=store.bucket, Key="scenes/s/big.glb")["ETag"].strip('"').endswith("-3")
    assert store.put_stream("scenes/s/empty.glb", io.BytesIO(b"")) == 0
    assert store.read_bytes("scenes/s/empty.glb") == b""
    assert store.list_files("scenes/s") == ["big.glb", "empty.glb", "small.glb"]


@pytest.mark.parametrize("size", [1000, 2 * MIN_PART + 1], ids=["one-part", "multipart"])
def test_put_stream_over_the_limit_leaves_nothing(store, size):
    with pytest.raises(UploadTooLargeError):
        store.put_stream("scenes/x/too-big.glb", io.BytesIO(b"x" * size), limit=size - 1)
    assert not store.exists("scenes/x/too-big.glb")
    assert _leftovers(store) == []
    with pytest.raises(NotFoundError):
        store.read_bytes("scenes/x/too-big.glb")


def test_put_stream_failure_in_the_source_leaves_nothing(store):
    class Broken(io.RawIOBase):
        def __init__(self):
            self.sent = 0

        def readable(self):
            return True

        def read(self, n=-1):
            if self.sent > MIN_PART + 1:
                raise ConnectionResetError("client went away")
            self.sent += 1 << 20
            return b"y" * (1 << 20)

    with pytest.raises(ConnectionResetError):
        store.put_stream("scenes/x/broken.glb", Broken())
    assert _leftovers(store) == []


def test_exists(store):
    assert not store.exists("impostors/d/manifest.json")
    store.put_bytes("impostors/d/manifest.json", b"{}")
    assert store.exists("impostors/d/manifest.json")
    assert not store.exists("impostors/d")  # a prefix is not a blob
    assert not store.exists("impostors/d/manifest")


def test_missing_key_is_not_found(store, tmp_path):
    with pytest.raises(NotFoundError):
        store.read_bytes("scenes/nope/scene.glb")
    with pytest.raises(NotFoundError):
        store.open("scenes/nope/scene.glb")
    with pytest.raises(NotFoundError):
        list(store.iter_chunks("scenes/nope/scene.glb"))
    with pytest.raises(NotFoundError):
        store.copy_to_directory("scenes/nope", tmp_path / "out")


def test_bad_keys_are_refused(store):
    for key in ("", "../x", "a//b", "a/./b", "/abs"):
        with pytest.raises(ValueError):
            store.put_bytes(key, b"x")


def test_list_files(store):
    assert store.list_files("impostors/d") == []
    store.put_bytes("impostors/d/page-0000.png", b"p0")
    store.put_bytes("impostors/d/manifest.json", b"{}")
    store.put_bytes("impostors/d/sub/deeper.bin", b"z")  # not directly under the prefix
    store.put_bytes("impostors/dd/other.json", b"{}")  # a sibling prefix that starts the same
    assert store.list_files("impostors/d") == ["manifest.json", "page-0000.png"]
    assert store.list_files("impostors/d/sub") == ["deeper.bin"]
    assert store.list_files("impostors/dd") == ["other.json"]


def test_publish_directory_and_copy_to_directory(store, tmp_path):
    source = tmp_path / "bundle"
    source.mkdir()
    (source / "manifest.json").write_bytes(b'{"a": 1}')
    (source / "page-0000.png").write_bytes(b"\x89PNG" + bytes(1000))
    (source / "nested").mkdir()
    assert store.publish_directory("impostors/b", source, last="manifest.json")
    assert store.list_files("impostors/b") == ["manifest.json", "page-0000.png"]
    out = store.copy_to_directory("impostors/b", tmp_path / "copy")
    assert sorted(p.name for p in out.iterdir()) == ["manifest.json", "page-0000.png"]
    assert (out / "manifest.json").read_bytes() == b'{"a": 1}'
    assert (out / "page-0000.png").read_bytes() == b"\x89PNG" + bytes(1000)


def test_a_local_store_publishes_a_folder_by_hard_links(tmp_path):
    # The bytes are not written twice (a worker's bundle, written to its temporary folder on the
    # same disk); the published file is the source's inode, whose folder can then be deleted.
    store = LocalBlobStore(tmp_path / "blobs")
    source = tmp_path / "bundle"
    source.mkdir()
    (source / "manifest.json").write_bytes(b'{"a": 1}')
    assert store.publish_directory("impostors/l", source, last="manifest.json")
    assert store.path("impostors/l/manifest.json").stat().st_ino == (source / "manifest.json").stat().st_ino
    (source / "manifest.json").unlink()
    assert store.read_bytes("impostors/l/manifest.json") == b'{"a": 1}'


def test_delete_prefix(store):
    for name in ("scene.glb", "a.png", "b.png"):
        store.put_bytes(f"scenes/one/{name}", name.encode())
    store.put_bytes("scenes/one/sub/c.png", b"c")
    store.put_bytes("scenes/onex/keep.glb", b"keep")  # shares the prefix's first characters only
    store.delete_prefix("scenes/one")
    assert store.list_files("scenes/one") == []
    assert store.list_files("scenes/one/sub") == []
    assert not store.exists("scenes/one/scene.glb")
    assert store.read_bytes("scenes/onex/keep.glb") == b"keep"
    store.delete_prefix("scenes/onex/keep.glb")  # a single key
    assert not store.exists("scenes/onex/keep.glb")
    store.delete_prefix("scenes/never-there")  # no error
    assert _leftovers(store) == []


@pytest.mark.slow
def test_s3_lists_and_deletes_page_by_page(s3_endpoint, bucket):
    store = S3BlobStore(bucket, endpoint_url=s3_endpoint, access_key=KEY, secret_key=SECRET)
    store.page_size = 7  # S3 pages by 1000 keys; the same loops with small pages
    for i in range(30):
        store.put_bytes(f"jobs/j/cells/{i:05d}", b"x")
    store.put_bytes("jobs/j/index.json", b"[]")
    assert store.list_files("jobs/j/cells") == [f"{i:05d}" for i in range(30)]
    assert store.list_files("jobs/j") == ["index.json"]
    store.delete_prefix("jobs/j")
    assert _leftovers(store) == []


def test_s3_waits_out_a_server_that_refuses_for_a_while(s3_endpoint, bucket):
    """A worker's store (``outage_s``) waits for a server that refuses connections and goes on when it
    answers again; the API's (no ``outage_s``) fails at once.  The server is behind a TCP gate that
    is closed (refusing, as a server restarting) and opened again 2 s later, its objects kept."""
    import threading

    from botocore.exceptions import EndpointConnectionError
    from cluster_harness import TcpGate

    gate = TcpGate(int(s3_endpoint.rsplit(":", 1)[1])).open()
    through = f"http://127.0.0.1:{gate.port}"
    patient = S3BlobStore(bucket, endpoint_url=through, access_key=KEY, secret_key=SECRET, outage_s=30)
    at_once = S3BlobStore(bucket, endpoint_url=through, access_key=KEY, secret_key=SECRET)
    try:
        patient.put_bytes("scenes/s/scene.glb", b"before")
        gate.close()
        with pytest.raises(EndpointConnectionError):
            at_once.read_bytes("scenes/s/scene.glb")
        reopen = threading.Timer(2.0, gate.open)
        reopen.start()
        patient.put_bytes("impostors/d/manifest.json", b"during")  # waits for the gate
        reopen.join()
        assert patient.read_bytes("scenes/s/scene.glb") == b"before"
        assert at_once.list_files("impostors/d") == ["manifest.json"]
    finally:
        gate.close()


# -- settings and the factory -------------------------------------------------------------


def test_factory_gives_the_local_store_by_default(tmp_path):
    store = blob_store(Settings.from_env({"FARFIELD_HOME": str(tmp_path)}))
    assert isinstance(store, LocalBlobStore)
    assert store.root == tmp_path / "blobs"


def test_factory_gives_the_s3_store_from_the_environment(tmp_path, s3_endpoint, bucket):
    env = {
        "FARFIELD_HOME": str(tmp_path), "FARFIELD_S3_ENDPOINT": s3_endpoint, "FARFIELD_S3_BUCKET": bucket,
        "FARFIELD_S3_KEY": KEY, "FARFIELD_S3_SECRET": SECRET,
    }  # fmt: skip
    settings = Settings.from_env(env)
    assert (settings.s3_endpoint, settings.s3_bucket, settings.s3_key, settings.s3_region) == (
        s3_endpoint,
        bucket,
        KEY,
        "us-east-1",
    )
    assert SECRET not in repr(settings)
    store = blob_store(settings)
    assert isinstance(store, S3BlobStore)
    store.put_bytes("jobs/j/index.json", b"[]")
    assert _s3_client(s3_endpoint).get_object(Bucket=bucket, Key="jobs/j/index.json")["Body"].read() == b"[]"
    # A child process (a worker) gets the same settings from settings.environment().
    child = Settings.from_env(settings.environment())
    assert (child.s3_endpoint, child.s3_bucket, child.s3_key, child.s3_secret, child.s3_region) == (
        s3_endpoint,
        bucket,
        KEY,
        SECRET,
        REGION,
    )
    assert isinstance(blob_store(child), S3BlobStore)


@pytest.mark.parametrize(
    ("env", "message"),
    [
        ({"FARFIELD_S3_BUCKET": "farfield"}, "FARFIELD_S3_KEY and FARFIELD_S3_SECRET are not"),
        ({"FARFIELD_S3_BUCKET": "farfield", "FARFIELD_S3_KEY": "k"}, "FARFIELD_S3_SECRET is not"),
        ({"FARFIELD_S3_BUCKET": "farfield", "FARFIELD_S3_SECRET": "s"}, "FARFIELD_S3_KEY is not"),
        ({"FARFIELD_S3_ENDPOINT": "http://minio:9000", "FARFIELD_S3_KEY": "k"}, "without FARFIELD_S3_BUCKET"),
        ({"FARFIELD_S3_BUCKET": "Not_A_Bucket", "FARFIELD_S3_KEY": "k", "FARFIELD_S3_SECRET": "s"}, "bucket name"),
        (
            {
                "FARFIELD_S3_BUCKET": "farfield",
                "FARFIELD_S3_KEY": "k",
                "FARFIELD_S3_SECRET": "s",
                "FARFIELD_S3_ENDPOINT": "minio:9000",
            },
            "http:// or https://",
        ),
    ],
)
def test_incomplete_s3_settings_are_refused(tmp_path, env, message):
    with pytest.raises(ServiceConfigError, match=message):
        Settings.from_env({"FARFIELD_HOME": str(tmp_path), **env})


def test_local_settings_pass_no_s3_variables(tmp_path):
    env = Settings.from_env({"FARFIELD_HOME": str(tmp_path)}).environment()
    assert not [name for name in env if name.startswith("FARFIELD_S3_")]


def _bundle_dir(root: Path, tag: str) -> Path:
    root.mkdir(parents=True)
    for name in ("atlas-000.png", "impostor.glb", "manifest.json"):
        (root / name).write_bytes(f"{tag}:{name}".encode() * 1000)
    return root


@pytest.mark.invalid_glb  # stores made-up bytes under .glb names
def test_publish_directory_stores_a_set_once(store, tmp_path):
    first, second = _bundle_dir(tmp_path / "a", "a"), _bundle_dir(tmp_path / "b", "b")
    assert store.publish_directory("impostors/k", first, last="manifest.json")
    assert not store.publish_directory("impostors/k", second, last="manifest.json")
    assert store.list_files("impostors/k") == ["atlas-000.png", "impostor.glb", "manifest.json"]
    assert {store.read_bytes(f"impostors/k/{n}")[:1] for n in store.list_files("impostors/k")} == {b"a"}
    assert _leftovers(store) == ["impostors/k/atlas-000.png", "impostors/k/impostor.glb", "impostors/k/manifest.json"]


@pytest.mark.invalid_glb  # stores made-up bytes under .glb names
def test_local_publishers_racing_never_mix_their_files(tmp_path):
    store = LocalBlobStore(tmp_path / "blobs")
    sources = [_bundle_dir(tmp_path / f"s{i}", str(i)) for i in range(8)]
    with ThreadPoolExecutor(8) as pool:
        won = list(
            pool.map(lambda source: store.publish_directory("impostors/k", source, last="manifest.json"), sources)
        )
    assert sum(won) == 1
    tags = {store.read_bytes(f"impostors/k/{n}")[:1] for n in store.list_files("impostors/k")}
    assert len(tags) == 1 and len(store.list_files("impostors/k")) == 3
    assert [p.name for p in (tmp_path / "blobs" / "impostors").iterdir()] == ["k"]  # no staging left
