"""Results: per-cell bundle (zip), manifest, atlas pages, GLB; a job's whole impostor database; lookup."""

from __future__ import annotations

import tempfile
import zipfile
from pathlib import Path

from fastapi import APIRouter, Depends, Path as PathParam
from fastapi.responses import FileResponse, Response
from starlette.background import BackgroundTask

from farfield.core.bundle import GLB_NAME, MANIFEST_NAME, PAYLOAD_NAME, bundle_zip, page_file_name
from farfield.core.errors import ConflictError, NotFoundError
from farfield.service.jobs import cell_record, get_cell_row, get_job_row, job_cells, lookup

from farfield.api.deps import Services, services, tenant

router = APIRouter(prefix="/v1/jobs/{job_id}", tags=["results"])

CellIndex = PathParam(ge=0, le=2**31 - 1, description="the cell's index in its job")
PageIndex = PathParam(ge=0, le=2**31 - 1, description="atlas page number")


def _result(svc: Services, tenant_id: str, job_id: str, index: int) -> str:
    cell = get_cell_row(svc.db, tenant_id, job_id, index)
    if cell.result_key is None:
        raise NotFoundError(f"cell {index} of job {job_id!r} has no impostor yet (state {cell.state})")
    return cell.result_key


@router.get("/cells/{index}/bundle.zip", summary="A cell's impostor bundle as a zip")
def cell_bundle(job_id: str, index: int = CellIndex, tenant_id: str = Depends(tenant), svc: Services = Depends(services)) -> Response:
    key = _result(svc, tenant_id, job_id, index)
    with tempfile.TemporaryDirectory(prefix="farfield-zip-") as tmp:
        data = bundle_zip(svc.blobs.copy_to_directory(key, tmp))
    return Response(data, media_type="application/zip", headers={"Content-Disposition": f'attachment; filename="cell-{index:05d}.zip"'})


@router.get("/cells/{index}/manifest.json", summary="A cell's bundle manifest")
def cell_manifest(job_id: str, index: int = CellIndex, tenant_id: str = Depends(tenant), svc: Services = Depends(services)) -> Response:
    return Response(svc.blobs.read_bytes(f"{_result(svc, tenant_id, job_id, index)}/{MANIFEST_NAME}"), media_type="application/json")


@router.get("/cells/{index}/payload.bin", summary="A cell's payload arrays (little-endian; the manifest's 'payload' names their dtypes, shapes and offsets)")
def cell_payload(job_id: str, index: int = CellIndex, tenant_id: str = Depends(tenant), svc: Services = Depends(services)) -> Response:
    return Response(svc.blobs.read_bytes(f"{_result(svc, tenant_id, job_id, index)}/{PAYLOAD_NAME}"), media_type="application/octet-stream")


@router.get("/cells/{index}/atlas/{page}.png", summary="One atlas page of a cell (RGBA PNG)")
def cell_atlas(job_id: str, index: int = CellIndex, page: int = PageIndex, tenant_id: str = Depends(tenant), svc: Services = Depends(services)) -> Response:
    key = f"{_result(svc, tenant_id, job_id, index)}/{page_file_name(page)}"
    return Response(svc.blobs.read_bytes(key), media_type="image/png")


@router.get("/cells/{index}/impostor.glb", summary="A cell's impostor as GLB")
def cell_glb(job_id: str, index: int = CellIndex, tenant_id: str = Depends(tenant), svc: Services = Depends(services)) -> Response:
    key = f"{_result(svc, tenant_id, job_id, index)}/{GLB_NAME}"
    return Response(svc.blobs.read_bytes(key), media_type="model/gltf-binary", headers={"Content-Disposition": f'attachment; filename="cell-{index:05d}.glb"'})


@router.get("/cells/{index}", summary="One cell: state, statistics")
def cell_info(job_id: str, index: int = CellIndex, tenant_id: str = Depends(tenant), svc: Services = Depends(services)) -> dict:
    return cell_record(get_cell_row(svc.db, tenant_id, job_id, index))


@router.get("/database.zip", summary="The job's whole impostor database: index.json and every cell's bundle")
def job_database(job_id: str, tenant_id: str = Depends(tenant), svc: Services = Depends(services)) -> FileResponse:
    job = get_job_row(svc.db, tenant_id, job_id)
    if job.index_key is None:
        raise ConflictError(f"job {job_id!r} is {job.state}; its impostor database is written when it ends")
    out = tempfile.NamedTemporaryFile(prefix="farfield-db-", suffix=".zip", delete=False)
    try:
        with out, zipfile.ZipFile(out, "w", zipfile.ZIP_STORED) as archive:  # PNG and GLB are compressed already
            archive.writestr("index.json", svc.blobs.read_bytes(job.index_key))
            for cell in job_cells(svc.db, job_id):
                if cell.result_key is None:
                    continue
                for name in svc.blobs.list_files(cell.result_key):
                    with archive.open(f"cells/{cell.index:05d}/{name}", "w") as member:
                        for chunk in svc.blobs.iter_chunks(f"{cell.result_key}/{name}"):
                            member.write(chunk)
    except BaseException:
        Path(out.name).unlink(missing_ok=True)
        raise
    return FileResponse(out.name, media_type="application/zip", filename=f"job-{job_id}.zip", background=BackgroundTask(Path(out.name).unlink, missing_ok=True))


@router.get("/lookup", summary="Which impostors serve this viewpoint")
def lookup_viewpoint(job_id: str, x: float, y: float, z: float, tenant_id: str = Depends(tenant), svc: Services = Depends(services)) -> list[dict]:
    get_job_row(svc.db, tenant_id, job_id)
    return [cell_record(cell) for cell in lookup(job_cells(svc.db, job_id), (x, y, z))]
