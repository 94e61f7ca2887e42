"""The blob store: scene uploads, impostor bundles and job indexes, by key.

Keys are ``/``-separated relative paths (``scenes/<id>/scene.glb``,
``impostors/<digest>/manifest.json``).  A reader never sees half a blob, and a redelivered task
that writes the same key again replaces identical bytes:

- :class:`LocalBlobStore` (the embedded default) writes every blob to a temporary sibling and
  renames it into place;
- :class:`S3BlobStore` (``FARFIELD_S3_*``, for API and workers on several machines) keeps blobs in
  one bucket of an S3-compatible server (MinIO, AWS S3, ...), where an object appears whole when its
  upload completes.

Both implement :class:`BlobStore`; :func:`blob_store` makes the one the settings ask for.  Callers
use only that interface (``list_files`` instead of looking at directories), so they work with both.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, BinaryIO, Protocol, runtime_checkable

from farfield.core.errors import NotFoundError, UploadTooLargeError

if TYPE_CHECKING:
    from farfield.service.settings import Settings

CHUNK = 1 << 20
log = logging.getLogger("farfield.blobs")


def check_key(key: str) -> str:
    """``key`` itself when it is a valid blob key (no empty, ``.`` or ``..`` parts); ValueError otherwise."""
    parts = key.split("/")
    if not key or any(p in ("", ".", "..") for p in parts):
        raise ValueError(f"bad blob key {key!r}")
    return key


@runtime_checkable
class BlobStore(Protocol):
    """What the service needs of a blob store (see the module docstring)."""

    def put_bytes(self, key: str, data: bytes) -> None: ...

    def put_stream(self, key: str, source: BinaryIO, limit: int | None = None) -> int: ...

    def publish_directory(self, prefix: str, directory: str | os.PathLike, last: str) -> bool: ...

    def exists(self, key: str) -> bool: ...

    def read_bytes(self, key: str) -> bytes: ...

    def open(self, key: str) -> BinaryIO: ...

    def iter_chunks(self, key: str) -> Iterator[bytes]: ...

    def list_files(self, prefix: str) -> list[str]: ...

    def delete_prefix(self, prefix: str) -> None: ...

    def copy_to_directory(self, prefix: str, directory: str | os.PathLike) -> Path: ...


def blob_store(settings: Settings, outage_s: float = 0.0) -> BlobStore:
    """The blob store of ``settings``: the S3 bucket when ``FARFIELD_S3_BUCKET`` is set (each request
    waiting up to ``outage_s`` for a server it cannot reach: :class:`S3BlobStore`), else the local directory."""
    if settings.s3_bucket:
        return S3BlobStore(
            bucket=settings.s3_bucket, endpoint_url=settings.s3_endpoint, access_key=settings.s3_key,
            secret_key=settings.s3_secret, region=settings.s3_region or "us-east-1", outage_s=outage_s,
        )  # fmt: skip
    return LocalBlobStore(settings.blob_dir)


def _link_or_copy(source: Path, destination: Path) -> None:
    """A hard link of ``source`` at ``destination`` (no second write of the bytes: a worker's bundle
    is written to its temporary folder, on the same disk as the blob directory under ``farfield
    up``), else a copy (another file system, or one without hard links).  The caller's files are
    never written again (a link shares them)."""
    try:
        os.link(source, destination)
    except OSError:
        shutil.copyfile(source, destination)


def _too_large(limit: int) -> UploadTooLargeError:
    return UploadTooLargeError(f"upload is larger than the limit of {limit // 2**20} MiB")


class LocalBlobStore:
    """Blobs as files under one root directory."""

    def __init__(self, root: str | os.PathLike) -> None:
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)

    def __repr__(self) -> str:
        return f"LocalBlobStore({str(self.root)!r})"

    def path(self, key: str) -> Path:
        """The file of ``key``; refuses keys that would leave the root."""
        return self.root.joinpath(*check_key(key).split("/"))

    def _atomic(self, key: str) -> tuple[Path, BinaryIO, str]:
        target = self.path(key)
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", dir=target.parent)
        return target, os.fdopen(fd, "wb"), tmp

    def put_bytes(self, key: str, data: bytes) -> None:
        target, out, tmp = self._atomic(key)
        try:
            with out:
                out.write(data)
            os.replace(tmp, target)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

    def put_stream(self, key: str, source: BinaryIO, limit: int | None = None) -> int:
        """Copy ``source`` into ``key`` in chunks; returns the size.

        Raises :class:`UploadTooLargeError` (and writes nothing) past ``limit`` bytes.
        """
        target, out, tmp = self._atomic(key)
        size = 0
        try:
            with out:
                while chunk := source.read(CHUNK):
                    size += len(chunk)
                    if limit is not None and size > limit:
                        raise _too_large(limit)
                    out.write(chunk)
            os.replace(tmp, target)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        return size

    def publish_directory(self, prefix: str, directory: str | os.PathLike, last: str) -> bool:
        """Store the files of ``directory`` under ``prefix/`` all at once, unless a complete set is
        there already (its ``last`` file exists); True if this call stored them.

        The files go to a hidden staging folder beside ``prefix`` that is renamed into place, so
        readers see all of them or none, and of two workers publishing the same prefix at once,
        exactly one set wins whole.
        """
        target = self.path(prefix)
        if (target / last).is_file():
            return False
        target.parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=f".{target.name}.staging-", dir=target.parent))
        try:
            for file in Path(directory).iterdir():
                if file.is_file():
                    _link_or_copy(file, staging / file.name)
            if target.is_dir() and not (target / last).is_file():
                shutil.rmtree(target, ignore_errors=True)  # an incomplete set from before this scheme
            os.rename(staging, target)  # fails when another publisher's set is already in place
            return True
        except OSError:
            if (target / last).is_file():
                return False
            raise
        finally:
            shutil.rmtree(staging, ignore_errors=True)

    def exists(self, key: str) -> bool:
        return self.path(key).is_file()

    def read_bytes(self, key: str) -> bytes:
        try:
            return self.path(key).read_bytes()
        except FileNotFoundError:
            raise NotFoundError(f"blob {key!r} not found") from None

    def open(self, key: str) -> BinaryIO:
        try:
            return self.path(key).open("rb")
        except FileNotFoundError:
            raise NotFoundError(f"blob {key!r} not found") from None

    def iter_chunks(self, key: str) -> Iterator[bytes]:
        with self.open(key) as f:
            while chunk := f.read(CHUNK):
                yield chunk

    def list_files(self, prefix: str) -> list[str]:
        """The names of the blobs directly under ``prefix/``, sorted (``[]`` when there are none)."""
        folder = self.path(prefix)
        if not folder.is_dir():
            return []
        return sorted(f.name for f in folder.iterdir() if f.is_file() and not f.name.startswith("."))

    def delete_prefix(self, prefix: str) -> None:
        """Remove every blob under ``prefix`` (a key or a folder of keys)."""
        target = self.path(prefix)
        if target.is_dir():
            shutil.rmtree(target, ignore_errors=True)
        else:
            target.unlink(missing_ok=True)

    def copy_to_directory(self, prefix: str, directory: str | os.PathLike) -> Path:
        """Copy the blobs directly under ``prefix`` into ``directory`` (for core functions that read files)."""
        out = Path(directory)
        out.mkdir(parents=True, exist_ok=True)
        source = self.path(prefix)
        if not source.is_dir():
            raise NotFoundError(f"no blobs under {prefix!r}")
        for file in source.iterdir():
            if file.is_file() and not file.name.startswith("."):
                shutil.copyfile(file, out / file.name)
        return out


# S3 refuses multipart parts under 5 MiB (except the last); uploads up to one part are a single PUT.
MIN_PART = 5 * 2**20
PART = 8 * 2**20
_MISSING_CODES = {"404", "NoSuchKey", "NotFound"}


class S3BlobStore:
    """Blobs as objects in one bucket of an S3-compatible server (MinIO, AWS S3, ...).

    Keys are object keys as they are.  ``endpoint_url`` ``None`` means AWS itself; with an endpoint
    (MinIO) the client uses path-style addressing (``http://host:9000/bucket/key``), which needs no
    wildcard DNS.  The boto3 client is thread-safe; make the store after any ``fork``.

    ``outage_s``: how long each request waits for a server it cannot reach (refused or cut
    connections, timeouts: botocore's connection errors, after botocore's own few retries), trying
    again with backoff (0.5 s doubling to 5 s), before it raises.  Workers wait
    (``FARFIELD_S3_OUTAGE_S``): an S3 server restarting for half a minute would otherwise fail every
    attempt of the cells that start or end meanwhile.  0 (the API's): fail at once.
    """

    page_size = 1000  # keys per ListObjectsV2 page and per DeleteObjects request (the S3 maximum)

    def __init__(
        self, bucket: str, endpoint_url: str | None = None, access_key: str | None = None, secret_key: str | None = None,
        region: str = "us-east-1", part_size: int = PART, client: Any = None, outage_s: float = 0.0,
    ) -> None:  # fmt: skip
        if part_size < MIN_PART:
            raise ValueError(f"part_size must be at least {MIN_PART} bytes (the S3 minimum), got {part_size}")
        self.bucket = bucket
        self.endpoint_url = endpoint_url
        self.part_size = part_size
        self.outage_s = outage_s
        if client is None:
            import boto3
            from botocore.config import Config

            options = {
                "region_name": region,
                "s3": {"addressing_style": "path" if endpoint_url else "auto"},
                "retries": {"max_attempts": 5, "mode": "standard"},
                "connect_timeout": 10,
                "read_timeout": 60,
            }
            if "request_checksum_calculation" in Config.OPTION_DEFAULTS:  # botocore >= 1.36
                # Checksums only where S3 requires them: several S3-compatible servers refuse or
                # ignore the trailing checksums botocore sends by default since 1.36.
                options.update(
                    request_checksum_calculation="when_required", response_checksum_validation="when_required"
                )
            config = Config(**options)
            client = boto3.client(
                "s3", endpoint_url=endpoint_url or None, aws_access_key_id=access_key, aws_secret_access_key=secret_key, config=config,
            )  # fmt: skip
        self.client = client

    def __repr__(self) -> str:
        return f"S3BlobStore(bucket={self.bucket!r}, endpoint_url={self.endpoint_url!r})"

    # -- errors ------------------------------------------------------------------------------

    def _translate(self, error: Exception, key: str) -> Exception:
        """:class:`NotFoundError` for a botocore ``ClientError`` that says ``key`` is missing, else the error itself.

        Other errors (a missing bucket, refused credentials, an unreachable server) stay botocore
        errors: they are the operator's to fix, reported as server errors, and retried by workers.
        """
        response = getattr(error, "response", None) or {}
        if str(response.get("Error", {}).get("Code", "")) in _MISSING_CODES:
            return NotFoundError(f"blob {key!r} not found")
        return error

    def _call(self, operation: str, **arguments: Any) -> Any:
        """``self.client.<operation>(**arguments)``, tried again while the server cannot be reached,
        for up to ``outage_s`` seconds (class docstring)."""
        from botocore.exceptions import ConnectionError as Unreachable
        from botocore.exceptions import HTTPClientError  # a cut connection, a read timeout

        deadline, delay = time.monotonic() + self.outage_s, 0.5
        while True:
            try:
                return getattr(self.client, operation)(**arguments)
            except (Unreachable, HTTPClientError) as error:
                if time.monotonic() + delay > deadline:
                    raise
                log.warning("S3 %s: %s; tried again in %g s", operation, error, delay)
                time.sleep(delay)
                delay = min(2 * delay, 5.0)

    def _client_error(self) -> type[Exception]:
        from botocore.exceptions import ClientError

        return ClientError

    # -- writing -----------------------------------------------------------------------------

    def put_bytes(self, key: str, data: bytes) -> None:
        try:
            self._call("put_object", Bucket=self.bucket, Key=check_key(key), Body=bytes(data))
        except self._client_error() as error:
            raise self._translate(error, key) from error

    def put_stream(self, key: str, source: BinaryIO, limit: int | None = None) -> int:
        """Copy ``source`` into ``key`` in parts; returns the size.

        Up to one part it is a single PUT; beyond, a multipart upload that becomes the object only
        when it completes.  Raises :class:`UploadTooLargeError` past ``limit`` bytes, and then (as
        on any failure) aborts the multipart upload, so nothing is left behind.
        """
        check_key(key)
        ClientError = self._client_error()
        size = 0
        buffer = bytearray()
        upload_id: str | None = None
        parts: list[dict] = []
        try:
            while chunk := source.read(CHUNK):
                size += len(chunk)
                if limit is not None and size > limit:
                    raise _too_large(limit)
                buffer += chunk
                while len(buffer) >= self.part_size:
                    if upload_id is None:
                        upload_id = self._call("create_multipart_upload", Bucket=self.bucket, Key=key)["UploadId"]
                    body, buffer = bytes(buffer[: self.part_size]), buffer[self.part_size :]
                    self._upload_part(key, upload_id, parts, body)
            if upload_id is None:
                self._call("put_object", Bucket=self.bucket, Key=key, Body=bytes(buffer))
            else:
                if buffer:  # the last part, shorter than the others
                    self._upload_part(key, upload_id, parts, bytes(buffer))
                self._call(
                    "complete_multipart_upload",
                    Bucket=self.bucket, Key=key, UploadId=upload_id, MultipartUpload={"Parts": parts},
                )  # fmt: skip
        except BaseException as error:
            if upload_id is not None:
                with contextlib.suppress(Exception):  # the first error is the one to report
                    self.client.abort_multipart_upload(Bucket=self.bucket, Key=key, UploadId=upload_id)
            if isinstance(error, ClientError):
                raise self._translate(error, key) from error
            raise
        return size

    def _upload_part(self, key: str, upload_id: str, parts: list[dict], body: bytes) -> None:
        number = len(parts) + 1
        etag = self._call("upload_part", Bucket=self.bucket, Key=key, UploadId=upload_id, PartNumber=number, Body=body)[
            "ETag"
        ]
        parts.append({"ETag": etag, "PartNumber": number})

    def publish_directory(self, prefix: str, directory: str | os.PathLike, last: str) -> bool:
        """Store the files of ``directory`` under ``prefix/``, the ``last`` one last, unless it exists
        already; True if this call stored them.  Each object appears whole, and a set is complete
        once ``last`` exists; S3 has no rename, so two publishers racing on one prefix may both
        write (their files are the same bytes when their renderers agree)."""
        if self.exists(f"{prefix}/{last}"):
            return False
        files = sorted((p for p in Path(directory).iterdir() if p.is_file()), key=lambda p: (p.name == last, p.name))
        for file in files:
            with file.open("rb") as source:
                self.put_stream(f"{prefix}/{file.name}", source)
        return True

    # -- reading -----------------------------------------------------------------------------

    def exists(self, key: str) -> bool:
        try:
            self._call("head_object", Bucket=self.bucket, Key=check_key(key))
        except self._client_error() as error:
            translated = self._translate(error, key)
            if isinstance(translated, NotFoundError):
                return False
            raise translated from error
        return True

    def open(self, key: str) -> BinaryIO:
        """A readable binary stream of ``key`` (botocore's streaming body; close it when done)."""
        try:
            return self._call("get_object", Bucket=self.bucket, Key=check_key(key))["Body"]
        except self._client_error() as error:
            raise self._translate(error, key) from error

    def read_bytes(self, key: str) -> bytes:
        with self.open(key) as body:
            return body.read()

    def iter_chunks(self, key: str) -> Iterator[bytes]:
        with self.open(key) as body:
            while chunk := body.read(CHUNK):
                yield chunk

    def _keys(self, prefix: str, delimiter: bool) -> Iterator[str]:
        """Every key under ``prefix`` (only those directly under it with ``delimiter``)."""
        arguments = {"Bucket": self.bucket, "Prefix": prefix, "MaxKeys": self.page_size}
        if delimiter:
            arguments["Delimiter"] = "/"
        try:
            while True:
                page = self._call("list_objects_v2", **arguments)
                for item in page.get("Contents", ()):
                    yield item["Key"]
                if not page.get("IsTruncated"):
                    break
                arguments["ContinuationToken"] = page["NextContinuationToken"]
        except self._client_error() as error:
            raise self._translate(error, prefix) from error

    def list_files(self, prefix: str) -> list[str]:
        """The names of the blobs directly under ``prefix/``, sorted (``[]`` when there are none)."""
        start = check_key(prefix) + "/"
        names = (key[len(start) :] for key in self._keys(start, delimiter=True))
        return sorted(name for name in names if name and not name.startswith("."))

    def delete_prefix(self, prefix: str) -> None:
        """Remove every blob under ``prefix`` (the key ``prefix`` itself and every key under ``prefix/``)."""
        check_key(prefix)
        keys = [prefix, *self._keys(prefix + "/", delimiter=False)]
        try:
            for i in range(0, len(keys), self.page_size):  # missing keys are no error
                batch = [{"Key": k} for k in keys[i : i + self.page_size]]
                response = self._call("delete_objects", Bucket=self.bucket, Delete={"Objects": batch, "Quiet": True})
                if response.get("Errors"):
                    failed = response["Errors"][0]
                    raise OSError(
                        f"could not delete blob {failed.get('Key')!r}: {failed.get('Code')} {failed.get('Message')}"
                    )
        except self._client_error() as error:
            raise self._translate(error, prefix) from error

    def copy_to_directory(self, prefix: str, directory: str | os.PathLike) -> Path:
        """Copy the blobs directly under ``prefix`` into ``directory`` (for core functions that read files)."""
        names = self.list_files(prefix)
        if not names:
            raise NotFoundError(f"no blobs under {prefix!r}")
        out = Path(directory)
        out.mkdir(parents=True, exist_ok=True)
        for name in names:
            with open(out / name, "wb") as target:
                target.writelines(self.iter_chunks(f"{prefix}/{name}"))
        return out
