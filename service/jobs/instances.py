"""A cell of an instance baked once per prototype: the job's part is one instance of a mesh its
scene draws several times, and its technique shares a prototype's bake
(:class:`~farfield.core.techniques.base.Instancing`), so the prototype is baked once in its local
space for the cell moved there, stored under a key of the prototype's content (not the scene's),
and each instance's bundle is that impostor moved by the instance's matrix (docs/formats.md,
"Scene files: instancing").  The second instance of a tenant (in this scene, another job, or another scene
holding the same mesh) bakes nothing.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from farfield.core.impostor.bundle import MANIFEST_NAME, read_bundle, write_bundle
from farfield.core.impostor.impostor import Impostor
from farfield.core.scene import Scene
from farfield.core.techniques import get_technique
from farfield.core.techniques.instances import instance_part, prototype_scene
from farfield.core.viewcells import viewcell_from_dict
from farfield.service.blobs import BlobStore
from farfield.service.db import JobRow
from farfield.service.jobs.cells import result_key


def prototype_bake(
    blobs: BlobStore, job: JobRow, scene: Scene, viewcell: dict, progress
) -> tuple[Impostor, str, bool] | None:
    """(the instance's impostor, its prototype key, whether this call baked the prototype) for a
    cell of a job of views whose part is an instance its technique shares; None otherwise (the cell
    is baked as before).  The prototype's bundle is published under
    :func:`~farfield.service.jobs.cells.result_key` of ``"prototype:<key>"``, the job's type and
    parameters less ``objects``, and the cell in the prototype's space, within the job's tenant."""
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
            write_bundle(impostor, Path(tmp) / "bundle")
            blobs.publish_directory(shared, Path(tmp) / "bundle", last=MANIFEST_NAME)
        else:
            impostor = read_bundle(blobs.copy_to_directory(shared, Path(tmp) / "bundle"))
    return technique.instancing.moved(impostor, matrix, list(objects), scene.content_hash), key, baked
