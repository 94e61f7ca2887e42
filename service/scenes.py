"""Scene uploads: streamed to a local file, validated by parsing (in a child process, so the API's
memory stays flat), stored in the blob store, recorded in the database.  An upload may be several
files: a zip of a scene file and what it refers to, or several multipart files.

A failed upload (too large, empty, unparsable) leaves neither a row nor a blob behind.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import tempfile
import threading
import uuid
from collections import OrderedDict
from pathlib import Path, PurePath
from typing import BinaryIO

from sqlalchemy import func, select, text
from sqlalchemy.orm import undefer

from farfield.core.errors import ConflictError, NotFoundError, SceneLoadError, UploadTooLargeError
from farfield.core.exchange import DEFAULT_LIMITS, SceneLimits, load_scene_bytes, supported_extensions
from farfield.core.exchange.archive import (
    SCENE_EXTENSIONS,
    is_zip,
    parts_archive,
    read_assets_zip,
    unpack_scene_archive,
)
from farfield.core.exchange.export import scene_glb
from farfield.core.scene import Scene
from farfield.core.sidedness import DEFAULT_SIDES, double_sided
from farfield.service.blobs import BlobStore
from farfield.service.db import CELL_FINAL, Database, JobRow, SceneRow, now, owned_row, storable
from farfield.service.scene_check import SceneCheckGate, check_scene_file

# beside a stored scene file, in a folder (an upload's own name never holds a "/", so no upload
# can be called this): the loaded scene as GLB, written on first request
SCENE_GLB = "export/scene.glb"
ASSETS = "assets.zip"  # beside a stored scene file: the files it refers to, by the names it uses

# Longest stored file name: a blob file's temporary sibling adds a prefix and a suffix to it, and
# file systems stop at 255 bytes (a 242-character upload name failed with "File name too long").
MAX_FILE_NAME = 120


def safe_file_name(name: str) -> str:
    """The base name of an uploaded file with anything but letters, digits, ``.-_`` replaced, at
    most :data:`MAX_FILE_NAME` characters (the stem is shortened; the extension is kept).

    >>> safe_file_name("../x/my scene.GLB")
    'my_scene.GLB'
    >>> len(safe_file_name("a" * 300 + ".obj")), safe_file_name("a" * 300 + ".obj")[-6:]
    (120, 'aa.obj')
    """
    base = PurePath((name or "").replace("\\", "/")).name
    safe = re.sub(r"[^A-Za-z0-9._-]", "_", base).lstrip(".") or "scene"
    if len(safe) > MAX_FILE_NAME:
        stem, dot, extension = safe.rpartition(".")
        extension = extension[:16] if dot and stem else ""
        safe = safe[: MAX_FILE_NAME - len(extension) - (1 if extension else 0)] + ("." + extension if extension else "")
    return safe


MAX_ORIGINAL_NAME = 1024


def original_file_name(name: str | None) -> str:
    """The uploaded file name as sent, kept as metadata: at most :data:`MAX_ORIGINAL_NAME`
    characters, storable in any database (NUL and unencodable characters become U+FFFD).  Never
    used to build a path: :func:`safe_file_name` is.

    >>> original_file_name("../my scene.glb"), len(original_file_name("a" * 2000)), original_file_name("a\\x00b")
    ('../my scene.glb', 1024, 'a\ufffdb')
    """
    text = (name or "").encode("utf-8", "replace").decode("utf-8").replace("\x00", "\ufffd")
    return text[:MAX_ORIGINAL_NAME]


def scene_record(row: SceneRow) -> dict:
    """The API's view of a stored scene: a summary, without its object list (a scene of 10^5
    objects has megabytes of them); ``objects_url`` pages them (:func:`scene_objects`)."""
    return {
        "id": row.id, "name": row.name, "original_name": row.original_name, "size_bytes": row.size_bytes,
        "content_hash": row.content_hash, "object_count": row.object_count, "triangles": row.triangles,
        "bounds": row.bounds, "sides": row.sides, "created_at": row.created_at, "objects_url": f"/v1/scenes/{row.id}/objects",
    }  # fmt: skip


def _spool(source: BinaryIO, limit: int, directory: str) -> tuple[Path, int]:
    """Copy ``source`` into a temporary file in chunks, stopping past ``limit`` bytes."""
    fd, name = tempfile.mkstemp(prefix="farfield-upload-", dir=directory)
    size = 0
    with os.fdopen(fd, "wb") as out:
        while chunk := source.read(1 << 20):
            size += len(chunk)
            if size > limit:
                raise UploadTooLargeError(f"upload is larger than the limit of {limit // 2**20} MiB")
            out.write(chunk)
    return Path(name), size


def ingest_scene(
    db: Database,
    blobs: BlobStore,
    tenant_id: str,
    file_name: str,
    source: BinaryIO,
    limit: int,
    scene_limits: SceneLimits = DEFAULT_LIMITS,
    more: list[tuple[str, BinaryIO]] | None = None,
    sides: str = DEFAULT_SIDES,
    gate: SceneCheckGate | None = None,
) -> SceneRow:
    """Validate and store one uploaded scene; returns its row (``row.upload_warnings``: what the
    loader warned of, e.g. a missing texture).

    ``sides`` is the loader's option (``"one"`` or ``"both"``, :mod:`farfield.core.sidedness`): the
    sidedness of the objects of a format that states none (OBJ, PLY, STL).  It is kept on the row,
    and a worker loads the file with it again.

    The upload is one scene file, a zip of a scene file and the files it refers to
    (:mod:`farfield.core.exchange.archive`), or, with ``more``, several files (name, stream) of which one is
    the scene; ``limit`` bounds their bytes together, uncompressed.  The files a scene refers to are
    stored beside it as ``scenes/<id>/assets.zip``.

    ``gate`` (the API's :class:`~farfield.service.scene_check.SceneCheckGate`, whose place for this
    upload the API's body middleware took) bounds the uploads checked at once; without it the file
    is checked at once.

    Raises :class:`SceneLoadError` (bad format, empty, unparsable, an archive without exactly one
    scene file or with a name outside it, a ``sides`` other than ``"one"`` or ``"both"``),
    :class:`SceneTooCostlyError` (structure beyond ``scene_limits``), :class:`UploadTooLargeError`.
    """
    double_sided(sides)  # a bad value is refused before anything is read
    check = check_scene_file if gate is None else gate.check
    return _ingest(db, blobs, tenant_id, file_name, source, limit, scene_limits, more, sides, check)


def _ingest(db, blobs, tenant_id, file_name, source, limit, scene_limits, more, sides, check) -> SceneRow:
    """:func:`ingest_scene`'s work, the file checked by ``check`` (:func:`check_scene_file`'s signature)."""
    scene_id = uuid.uuid4().hex
    prefix = f"scenes/{scene_id}"
    work = tempfile.mkdtemp(prefix="farfield-ingest-")
    try:
        path, size = _spool(source, limit, work)
        archive = None
        if more:
            parts = [(file_name, path)]
            for part_name, part in more:
                part_path, part_size = _spool(part, limit - size, work)
                size += part_size
                parts.append((part_name, part_path))
            archive = parts_archive(parts, Path(work))
        elif PurePath(file_name).suffix.lower().lstrip(".") not in SCENE_EXTENSIONS and (
            file_name.lower().endswith(".zip") or (size and is_zip(path))
        ):
            archive = unpack_scene_archive(path, limit, Path(work), safe_file_name(file_name))
        original = archive.name if more else file_name  # several files: the scene's, not the first field's
        if archive is not None:
            name, path, assets = safe_file_name(archive.name), archive.scene, archive.assets
        else:
            name, assets = safe_file_name(file_name), None
        extension = PurePath(name).suffix.lower().lstrip(".")
        if extension not in supported_extensions():
            shown = f"'.{extension}'" if extension else "no extension"
            raise SceneLoadError(
                f"{name}: unsupported scene format {shown}; supported: "
                + ", ".join("." + e for e in supported_extensions())
                + ", or a .zip of one with its files"
            )
        if size == 0 or path.stat().st_size == 0:
            raise SceneLoadError(f"{name}: the file is empty")
        summary = check(path, extension, name, scene_limits, assets, sides)
        key = f"{prefix}/{name}"
        with open(path, "rb") as f:
            blobs.put_stream(key, f)
        if assets is not None:
            with open(assets, "rb") as f:
                blobs.put_stream(f"{prefix}/{ASSETS}", f)
        row = SceneRow(
            id=scene_id, tenant_id=tenant_id, name=name, original_name=original_file_name(original), extension=extension,
            blob_key=key, size_bytes=size, content_hash=summary["content_hash"], triangles=summary["triangles"],
            bounds=summary["bounds"], object_count=len(summary["objects"]), objects=summary["objects"], created_at=now(),
            sides=sides,
        )  # fmt: skip
        with db.session() as s:
            s.add(row)
    except BaseException:
        blobs.delete_prefix(prefix)
        raise
    finally:
        shutil.rmtree(work, ignore_errors=True)
    row.upload_warnings = list(summary.get("warnings", []))
    if archive is not None and archive.skipped:
        shown = ", ".join(archive.skipped[:5]) + (
            f" and {len(archive.skipped) - 5} more" if len(archive.skipped) > 5 else ""
        )
        row.upload_warnings.append(
            f"{len(archive.skipped)} file(s) of the archive lie outside the scene file's folder and were not used: {shown}"
        )
    return row


def get_scene_row(db: Database, tenant_id: str, scene_id: str, with_objects: bool = False) -> SceneRow:
    """The tenant's scene ``scene_id``; another tenant's id is not found.  Its deferred ``objects``
    are loaded only ``with_objects`` (reading them on a row fetched without raises)."""
    if not with_objects or not storable(scene_id):
        return owned_row(db, SceneRow, tenant_id, scene_id, "scene")
    with db.session() as s:
        row = s.get(SceneRow, scene_id, options=[undefer(SceneRow.objects)])
    if row is None or row.tenant_id != tenant_id:
        raise NotFoundError(f"scene {scene_id!r} not found")
    return row


def list_scene_rows(db: Database, tenant_id: str, limit: int = 100, offset: int = 0) -> list[SceneRow]:
    """The tenant's scenes, newest first, ``limit`` from ``offset`` (their objects not loaded)."""
    query = select(SceneRow).where(SceneRow.tenant_id == tenant_id).order_by(SceneRow.created_at.desc(), SceneRow.id)
    with db.session() as s:
        return list(s.scalars(query.limit(limit).offset(offset)))


def count_scenes(db: Database, tenant_id: str) -> int:
    with db.session() as s:
        return s.scalar(select(func.count()).select_from(SceneRow).where(SceneRow.tenant_id == tenant_id))


# One page of a scene's objects, sliced by the database from the stored JSON array, so the API
# never decodes the whole list (megabytes for 10^5 objects) to answer a page of it.
_OBJECTS_PAGE = {
    "sqlite": "SELECT j.value FROM scenes, json_each(scenes.objects) AS j WHERE scenes.id = :id ORDER BY j.key LIMIT :limit OFFSET :offset",
    "postgresql": "SELECT e.value FROM scenes, json_array_elements(scenes.objects) WITH ORDINALITY AS e(value, n) "
                  "WHERE scenes.id = :id ORDER BY e.n LIMIT :limit OFFSET :offset",
}  # fmt: skip


def scene_objects(
    db: Database, tenant_id: str, scene_id: str, limit: int = 100, offset: int = 0
) -> tuple[list[dict], int]:
    """``limit`` object summaries of the tenant's scene from ``offset``, in the scene's order, and
    how many it has."""
    row = get_scene_row(db, tenant_id, scene_id)
    sql = _OBJECTS_PAGE.get(db.engine.dialect.name)
    with db.session() as s:
        if sql is None:  # another database: sliced here
            return s.scalar(select(SceneRow.objects).where(SceneRow.id == scene_id))[
                offset : offset + limit
            ], row.object_count
        values = s.execute(text(sql), {"id": scene_id, "limit": limit, "offset": offset}).scalars().all()
    return [json.loads(v) if isinstance(v, str) else v for v in values], row.object_count


def delete_scene(db: Database, blobs: BlobStore, tenant_id: str, scene_id: str) -> None:
    """Delete a scene, its finished jobs' rows and their blobs (``jobs/<id>/``: a job's index, its
    placement documents); refused while one of its jobs still runs.  Cell results are content
    addressed and may serve other jobs: they stay."""
    row = get_scene_row(db, tenant_id, scene_id)
    with db.session() as s:
        jobs = list(s.scalars(select(JobRow).where(JobRow.scene_id == scene_id)))
        active = [job.id for job in jobs if job.state not in CELL_FINAL]
        if active:
            raise ConflictError(f"scene {scene_id!r} is used by unfinished jobs {active}; cancel them first")
        for job in jobs:
            s.delete(job)
        s.delete(s.get(SceneRow, scene_id))
    blobs.delete_prefix(row.blob_key.rsplit("/", 1)[0])
    for job in jobs:  # after the rows: a job without its row is never read (issue 59, item 10)
        blobs.delete_prefix(f"jobs/{job.id}")


# A stored scene passed the limits in force when it was uploaded; a worker loads it whatever they are now.
ADMITTED = SceneLimits(
    nodes=2**62,
    depth=2**62,
    primitives=2**62,
    accessors=2**62,
    triangles=2**62,
    texture_pixels=2**62,
    texture_pixels_total=2**62,
)

# Scenes parsed in this process, by tenant and content hash: a worker loads each scene once, not once
# per cell.  The tenant is in the key so that a cell's time never says whether another tenant's
# cell loaded the same content just before (issue 59, item 9).
_CACHE: OrderedDict[str, Scene] = OrderedDict()
_CACHE_LOCK = threading.Lock()
CACHED_SCENES = 2


def _cache_key(row: SceneRow) -> str:
    return f"{row.tenant_id}:{row.content_hash}"


def _remember(row: SceneRow, scene: Scene) -> None:
    with _CACHE_LOCK:
        _CACHE[_cache_key(row)] = scene
        _CACHE.move_to_end(_cache_key(row))
        while len(_CACHE) > CACHED_SCENES:
            _CACHE.popitem(last=False)


def load_stored_scene(blobs: BlobStore, row: SceneRow) -> Scene:
    """The parsed scene of ``row`` (parsed once per process)."""
    with _CACHE_LOCK:
        scene = _CACHE.get(_cache_key(row))
    if scene is None:
        assets_key = f"{row.blob_key.rsplit('/', 1)[0]}/{ASSETS}"
        assets = read_assets_zip(blobs.read_bytes(assets_key)) if blobs.exists(assets_key) else None
        scene = load_scene_bytes(
            blobs.read_bytes(row.blob_key), row.extension, row.name, assets, limits=ADMITTED, sides=row.sides
        )
        _remember(row, scene)
    return scene


def stored_scene_glb(blobs: BlobStore, row: SceneRow) -> bytes:
    """The loaded scene of ``row`` as GLB (:func:`farfield.core.exchange.export.scene_glb`: one node per
    object, its name in the mesh's extras), written beside the scene file on first request and
    read from there afterwards; deleted with the scene."""
    key = f"{row.blob_key.rsplit('/', 1)[0]}/{SCENE_GLB}"
    if blobs.exists(key):
        return blobs.read_bytes(key)
    data = scene_glb(load_stored_scene(blobs, row))
    blobs.put_bytes(key, data)
    return data
