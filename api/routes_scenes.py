"""``/v1/scenes``: upload (multipart, streamed to the blob store), list, get, delete."""

from __future__ import annotations

from fastapi import APIRouter, Depends, UploadFile

from farfield.core.errors import SceneLoadError
from farfield.service.scenes import delete_scene, get_scene_row, ingest_scene, list_scene_rows, scene_record

from farfield.api.deps import Services, services, tenant

router = APIRouter(prefix="/v1/scenes", tags=["scenes"])


@router.post("", status_code=201, summary="Upload a scene file (glb, gltf, obj, ply, stl)")
def upload_scene(file: UploadFile | None = None, tenant_id: str = Depends(tenant), svc: Services = Depends(services)) -> dict:
    if file is None:
        raise SceneLoadError("send the scene as multipart form field 'file'")
    return scene_record(ingest_scene(svc.db, svc.blobs, tenant_id, file.filename or "", file.file, svc.settings.max_upload_bytes, svc.settings.scene_limits))


@router.get("", summary="List scenes")
def list_scenes(tenant_id: str = Depends(tenant), svc: Services = Depends(services)) -> list[dict]:
    return [scene_record(row) for row in list_scene_rows(svc.db, tenant_id)]


@router.get("/{scene_id}", summary="One scene")
def get_scene(scene_id: str, tenant_id: str = Depends(tenant), svc: Services = Depends(services)) -> dict:
    return scene_record(get_scene_row(svc.db, tenant_id, scene_id))


@router.delete("/{scene_id}", status_code=204, summary="Delete a scene and its finished jobs")
def remove_scene(scene_id: str, tenant_id: str = Depends(tenant), svc: Services = Depends(services)) -> None:
    delete_scene(svc.db, svc.blobs, tenant_id, scene_id)
