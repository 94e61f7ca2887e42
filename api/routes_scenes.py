"""``/v1/scenes``: upload (multipart, streamed to the blob store), list, get, page a scene's objects, delete.

Scenes are summaries (object count, triangles, bounds); a scene's object list is its own paged route.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, File, Form, Request, Response, UploadFile

from farfield.api.deps import Services, services, tenant
from farfield.api.paging import DEFAULT_PAGE, PAGED, Limit, Offset, set_page_headers
from farfield.core.errors import SceneLoadError
from farfield.core.sidedness import DEFAULT_SIDES, SIDES_HELP
from farfield.service.scenes import (
    count_scenes,
    delete_scene,
    get_scene_row,
    ingest_scene,
    list_scene_rows,
    scene_objects,
    scene_record,
    stored_scene_glb,
)

router = APIRouter(prefix="/v1/scenes", tags=["scenes"])


@router.post(
    "", status_code=201,
    summary="Upload a scene: one file (glb, gltf, obj, ply, stl), a zip of one with the files it refers to, or several 'file' fields",
)  # fmt: skip
def upload_scene(
    file: Annotated[list[UploadFile] | None, File(description="the scene file; or a .zip of it and its MTL, textures, buffers; or one field per file")] = None,
    sides: Annotated[str, Form(description=SIDES_HELP)] = DEFAULT_SIDES,
    tenant_id: str = Depends(tenant), svc: Services = Depends(services),
) -> dict:  # fmt: skip
    if not file:
        raise SceneLoadError(
            "file: missing from the form; send the scene as multipart form field "
            "'file' (a scene file, a .zip of one and its files, or one 'file' field per file)"
        )
    first, more = file[0], [(f.filename or "", f.file) for f in file[1:]]
    row = ingest_scene(
        svc.db,
        svc.blobs,
        tenant_id,
        first.filename or "",
        first.file,
        svc.settings.max_upload_bytes,
        svc.settings.scene_limits,
        more,
        sides,
        svc.scene_checks,
    )
    return {**scene_record(row), "warnings": getattr(row, "upload_warnings", [])}


@router.get("", summary="List scenes, newest first: summaries, paged (X-Total-Count, Link)", responses=PAGED)
def list_scenes(
    request: Request, response: Response, limit: Limit = DEFAULT_PAGE, offset: Offset = 0,
    tenant_id: str = Depends(tenant), svc: Services = Depends(services),
) -> list[dict]:  # fmt: skip
    set_page_headers(request, response, count_scenes(svc.db, tenant_id), limit, offset)
    return [scene_record(row) for row in list_scene_rows(svc.db, tenant_id, limit, offset)]


@router.get("/{scene_id}", summary="One scene's summary (its objects: objects_url)")
def get_scene(scene_id: str, tenant_id: str = Depends(tenant), svc: Services = Depends(services)) -> dict:
    return scene_record(get_scene_row(svc.db, tenant_id, scene_id))


@router.get(
    "/{scene_id}/objects",
    summary="A scene's objects in file order: name, triangles, bounds, ...; paged (X-Total-Count, Link)",
    responses=PAGED,
)
def list_scene_objects(
    scene_id: str, request: Request, response: Response, limit: Limit = DEFAULT_PAGE, offset: Offset = 0,
    tenant_id: str = Depends(tenant), svc: Services = Depends(services),
) -> list[dict]:  # fmt: skip
    objects, total = scene_objects(svc.db, tenant_id, scene_id, limit, offset)
    set_page_headers(request, response, total, limit, offset)
    return objects


@router.get(
    "/{scene_id}/scene.glb",
    summary="The scene as loaded, as GLB: one node per object, its name in the mesh's extras (farfield_object); what the 3D view draws",
)
def get_scene_glb(scene_id: str, tenant_id: str = Depends(tenant), svc: Services = Depends(services)) -> Response:
    data = stored_scene_glb(svc.blobs, get_scene_row(svc.db, tenant_id, scene_id))
    return Response(
        data,
        media_type="model/gltf-binary",
        headers={"Content-Disposition": f'attachment; filename="scene-{scene_id}.glb"'},
    )


@router.delete("/{scene_id}", status_code=204, summary="Delete a scene and its finished jobs")
def remove_scene(scene_id: str, tenant_id: str = Depends(tenant), svc: Services = Depends(services)) -> None:
    delete_scene(svc.db, svc.blobs, tenant_id, scene_id)
