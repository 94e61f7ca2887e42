"""The blob store: scene uploads, impostor bundles and job indexes, by key.

Keys are ``/``-separated relative paths (``scenes/<id>/scene.glb``,
``impostors/<digest>/manifest.json``).  Every write goes to a temporary sibling and is renamed
into place, so a reader never sees half a blob and a redelivered task that writes the same key
again replaces identical bytes.  The local directory store is the embedded default; an S3 store
with the same four methods is the multi-machine option still to come.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from core.errors import NotFoundError, UploadTooLargeError

CHUNK = 1 << 20


class LocalBlobStore:
    """Blobs as files under one root directory."""

    def __init__(self, root: str | os.PathLike) -> None:
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)

    def path(self, key: str) -> Path:
        """The file of ``key``; refuses keys that would leave the root."""
        parts = key.split("/")
        if not key or any(p in ("", ".", "..") for p in parts):
            raise ValueError(f"bad blob key {key!r}")
        return self.root.joinpath(*parts)

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
                        raise UploadTooLargeError(f"upload is larger than the limit of {limit // 2**20} MiB")
                    out.write(chunk)
            os.replace(tmp, target)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        return size

    def put_directory(self, prefix: str, directory: str | os.PathLike) -> list[str]:
        """Store every file directly in ``directory`` under ``prefix/``; returns the keys."""
        keys = []
        for file in sorted(Path(directory).iterdir()):
            if file.is_file():
                key = f"{prefix}/{file.name}"
                self.put_bytes(key, file.read_bytes())
                keys.append(key)
        return keys

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
