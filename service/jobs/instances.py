"""A cell of an instance baked once per prototype, and stored once: the job's part is one instance
of a mesh its scene draws several times, and its technique shares a prototype's bake
(:class:`~farfield.core.techniques.base.Instancing`), so the prototype is baked once in its local
space for the cell moved there, stored under a key of the prototype's content (not the scene's),
and each instance's impostor is that impostor moved by the instance's matrix (docs/formats.md,
"Scene files: instancing").  The second instance of a tenant (in this scene, another job, or another
scene holding the same mesh) bakes nothing.

An instance's stored bundle holds only what is its own: its ``manifest.json`` and ``payload.bin``
(the moved impostor's, as :func:`~farfield.core.impostor.bundle.write_bundle` writes them) and
``instance.json``, the blob prefix of its prototype's bundle, whose pages it shares; no pages and
no GLB (which embeds the pages).  Every reader of a cell's bundle goes through
:func:`copy_bundle`, :func:`bundle_file`, :func:`bundle_members` or
:func:`read_cell_impostor`, which give the same files,
byte for byte, as a whole bundle of the moved impostor: the pages are the prototype's files, the
GLB is written from the bundle read back.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from farfield.core.errors import NotFoundError
from farfield.core.impostor.bundle import (
    GLB_NAME,
    MANIFEST_NAME,
    PAYLOAD_NAME,
    encode_payload,
    manifest_bytes,
    read_bundle,
    write_bundle,
)
from farfield.core.impostor.glb import impostor_glb
from farfield.core.impostor.impostor import Impostor
from farfield.core.scene import Scene
from farfield.core.techniques import get_technique
from farfield.core.techniques.instances import instance_part, prototype_scene
from farfield.core.viewcells import viewcell_from_dict
from farfield.service.blobs import BlobStore
from farfield.service.db import JobRow
from farfield.service.jobs.cells import result_key

INSTANCE_NAME = "instance.json"  # an instance bundle's reference to its prototype's: {"prototype": prefix}
OWN_FILES = (MANIFEST_NAME, PAYLOAD_NAME)  # what an instance bundle stores of its own


@dataclass(frozen=True)
class PrototypeBake:
    """What :func:`prototype_bake` found for an instance's cell."""

    impostor: Impostor  # the prototype's impostor moved to the instance
    key: str  # the prototype's content key (``SceneObject.prototype``)
    baked: bool  # whether this call baked the prototype
    prefix: str  # the blob prefix of the prototype's bundle


def prototype_bake(blobs: BlobStore, job: JobRow, scene: Scene, viewcell: dict, progress) -> PrototypeBake | None:
    """The instance's impostor and its prototype for a cell of a job of views whose part is an
    instance its technique shares; None otherwise (the cell is baked as before).  The prototype's
    bundle is published under :func:`~farfield.service.jobs.cells.result_key` of
    ``"prototype:<key>"``, the job's type and parameters less ``objects``, and the cell in the
    prototype's space, within the job's tenant."""
    technique = get_technique(job.job_type)
    if technique.scope != "part" or technique.instancing is None:
        return None
    found = instance_part(scene, job.params.get("objects"))
    if found is None:
        return None
    key, matrix, objects = found
    options = technique.options_of(job.params)
    local = technique.instancing.local_cell(viewcell_from_dict(viewcell), matrix, options)
    if local is None:
        return None
    params = {k: v for k, v in job.params.items() if k != "objects"}
    shared = result_key(f"prototype:{key}", job.job_type, params, local.to_dict(), job.tenant_id)
    baked = not blobs.exists(f"{shared}/{MANIFEST_NAME}")
    with tempfile.TemporaryDirectory(prefix="farfield-prototype-") as tmp:
        if baked:
            impostor = technique.bake(prototype_scene(scene, key), local, options, None, progress)
            impostor.parameters["prototype"] = key
            write_bundle(impostor, Path(tmp) / "bundle", sync=False)  # the blob store's copy counts
            blobs.publish_directory(shared, Path(tmp) / "bundle", last=MANIFEST_NAME)
        else:
            impostor = read_bundle(blobs.copy_to_directory(shared, Path(tmp) / "bundle"))
    moved = technique.instancing.moved(impostor, matrix, list(objects), scene.content_hash)
    return PrototypeBake(moved, key, baked, shared)


def publish_instance(blobs: BlobStore, key: str, found: PrototypeBake) -> bool:
    """Store the bundle of an instance's cell under ``key``: its manifest and payload, and
    ``instance.json`` naming its prototype's bundle (published before: :func:`prototype_bake`);
    True if this call stored it (:meth:`~farfield.service.blobs.BlobStore.publish_directory`)."""
    payload, _ = encode_payload(found.impostor.payload)
    with tempfile.TemporaryDirectory(prefix="farfield-instance-") as tmp:
        folder = Path(tmp)
        (folder / MANIFEST_NAME).write_bytes(manifest_bytes(found.impostor))
        (folder / PAYLOAD_NAME).write_bytes(payload)
        (folder / INSTANCE_NAME).write_text(json.dumps({"prototype": found.prefix}, sort_keys=True))
        return blobs.publish_directory(key, folder, last=MANIFEST_NAME)


def prototype_prefix(blobs: BlobStore, key: str) -> str | None:
    """The blob prefix of the prototype's bundle whose pages the cell bundle under ``key`` shares;
    None for a bundle that holds all its files."""
    reference = f"{key}/{INSTANCE_NAME}"
    return json.loads(blobs.read_bytes(reference))["prototype"] if blobs.exists(reference) else None


def bundle_stored(blobs: BlobStore, key: str) -> bool:
    """Whether the cell bundle under ``key`` is there whole: its manifest, and an instance's
    prototype's (a prototype removed by hand is baked again)."""
    if not blobs.exists(f"{key}/{MANIFEST_NAME}"):
        return False
    prototype = prototype_prefix(blobs, key)
    return prototype is None or blobs.exists(f"{prototype}/{MANIFEST_NAME}")


def copy_bundle(blobs: BlobStore, key: str, directory: str | Path) -> Path:
    """The cell bundle under ``key`` as a bundle folder at ``directory``: the files a whole bundle
    of its impostor has (:func:`~farfield.core.impostor.bundle.write_bundle`), byte for byte."""
    prototype = prototype_prefix(blobs, key)
    if prototype is None:
        return blobs.copy_to_directory(key, directory)
    out = Path(directory)
    (out / GLB_NAME).write_bytes(impostor_glb(_instance_files(blobs, key, prototype, out)))
    return out


def read_cell_impostor(blobs: BlobStore, key: str, directory: str | Path) -> Impostor:
    """The impostor of the cell bundle under ``key``, its files copied to ``directory`` (an
    instance's GLB left out: :func:`read_bundle` does not read it)."""
    prototype = prototype_prefix(blobs, key)
    if prototype is None:
        return read_bundle(blobs.copy_to_directory(key, directory))
    return _instance_files(blobs, key, prototype, Path(directory))


def _instance_files(blobs: BlobStore, key: str, prototype: str, out: Path) -> Impostor:
    """An instance's bundle at ``out``, its prototype's pages and its own manifest and payload, read
    back (no GLB there: :func:`read_bundle`, which only asks that it exist, is given an empty stand-in)."""
    shared = [name for name in blobs.list_files(prototype) if name not in (*OWN_FILES, GLB_NAME)]
    if not shared:
        raise NotFoundError(f"no blobs under {prototype!r}, the prototype of {key!r}")
    out.mkdir(parents=True, exist_ok=True)
    for name in shared:  # the pages
        with open(out / name, "wb") as target:
            target.writelines(blobs.iter_chunks(f"{prototype}/{name}"))
    for name in OWN_FILES:
        (out / name).write_bytes(blobs.read_bytes(f"{key}/{name}"))
    (out / GLB_NAME).write_bytes(b"")
    try:
        return read_bundle(out)
    finally:
        (out / GLB_NAME).unlink()


def bundle_file(blobs: BlobStore, key: str, name: str) -> bytes:
    """The bytes of the file ``name`` of the cell bundle under ``key`` (NotFoundError when it has none)."""
    prototype = prototype_prefix(blobs, key)
    if prototype is None or name in OWN_FILES:
        return blobs.read_bytes(f"{key}/{name}")
    if name == GLB_NAME:  # written from the bundle read back, as write_bundle wrote it
        with tempfile.TemporaryDirectory(prefix="farfield-instance-") as tmp:
            return impostor_glb(_instance_files(blobs, key, prototype, Path(tmp)))
    return blobs.read_bytes(f"{prototype}/{name}")  # a page: the prototype's


def bundle_members(blobs: BlobStore, key: str) -> Iterator[tuple[str, Iterable[bytes]]]:
    """(name, its bytes in chunks) for each file of the cell bundle under ``key``, sorted by name."""
    if prototype_prefix(blobs, key) is None:
        for name in blobs.list_files(key):
            yield name, blobs.iter_chunks(f"{key}/{name}")
        return
    tmp = tempfile.mkdtemp(prefix="farfield-instance-")
    try:
        folder = copy_bundle(blobs, key, Path(tmp))
        for file in sorted(folder.iterdir()):
            yield file.name, (file.read_bytes(),)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
