"""Results: per-cell bundle (zip), manifest, atlas pages, GLB; a job's whole impostor database; lookup;
a placement job's map and clusters.  The documents are the service's (:mod:`farfield.service.jobs.index`,
:mod:`farfield.service.placement.documents`, each placement algorithm's own); a route validates, authorises
and calls."""

from __future__ import annotations

import json
import math
import tempfile
import zipfile
from pathlib import Path
from typing import Annotated, Literal

from fastapi import APIRouter, Depends, Query
from fastapi import Path as PathParam
from fastapi.responses import FileResponse, Response
from starlette.background import BackgroundTask

from farfield.api.deps import Services, services, tenant
from farfield.core.errors import BundleFormatError, ConflictError, InternalError, NotFoundError, ViewCellError
from farfield.core.impostor.bundle import GLB_NAME, MANIFEST_NAME, PAYLOAD_NAME, bundle_zip, page_file_name
from farfield.core.impostor.glb_compression import compress_glb
from farfield.service.db import JobRow
from farfield.service.jobs.index import bundled_cells, lookup_view
from farfield.service.jobs.instances import bundle_file, bundle_members, copy_bundle
from farfield.service.jobs.records import cell_record, get_cell_row, get_job_row, job_cells
from farfield.service.placement import documents

router = APIRouter(prefix="/v1/jobs/{job_id}", tags=["results"])

TenantDep = Annotated[str, Depends(tenant)]
ServicesDep = Annotated[Services, Depends(services)]
CellIndex = PathParam(ge=0, le=2**31 - 1, description="the cell's index in its job")
PageIndex = PathParam(ge=0, le=2**31 - 1, description="atlas page number")


def _result(svc: Services, tenant_id: str, job_id: str, index: int) -> str:
    cell = get_cell_row(svc.db, tenant_id, job_id, index)
    if cell.result_key is None:
        raise NotFoundError(f"cell {index} of job {job_id!r} has no impostor yet (state {cell.state})")
    return cell.result_key


@router.get("/cells/{index}/bundle.zip", summary="A cell's impostor bundle as a zip")
def cell_bundle(
    job_id: str, index: int = CellIndex, tenant_id: str = Depends(tenant), svc: Services = Depends(services)
) -> Response:
    key = _result(svc, tenant_id, job_id, index)
    with tempfile.TemporaryDirectory(prefix="farfield-zip-") as tmp:
        data = bundle_zip(copy_bundle(svc.blobs, key, tmp))
    return Response(
        data,
        media_type="application/zip",
        headers={"Content-Disposition": f'attachment; filename="cell-{index:05d}.zip"'},
    )


@router.get("/cells/{index}/manifest.json", summary="A cell's bundle manifest")
def cell_manifest(
    job_id: str, index: int = CellIndex, tenant_id: str = Depends(tenant), svc: Services = Depends(services)
) -> Response:
    return Response(
        svc.blobs.read_bytes(f"{_result(svc, tenant_id, job_id, index)}/{MANIFEST_NAME}"), media_type="application/json"
    )


@router.get(
    "/cells/{index}/payload.bin",
    summary="A cell's payload arrays (little-endian; the manifest's 'payload' names their dtypes, shapes and offsets)",
)
def cell_payload(
    job_id: str, index: int = CellIndex, tenant_id: str = Depends(tenant), svc: Services = Depends(services)
) -> Response:
    return Response(
        svc.blobs.read_bytes(f"{_result(svc, tenant_id, job_id, index)}/{PAYLOAD_NAME}"),
        media_type="application/octet-stream",
    )


@router.get("/cells/{index}/atlas/{page}.png", summary="One atlas page of a cell (RGBA PNG)")
def cell_atlas(
    job_id: str,
    index: int = CellIndex,
    page: int = PageIndex,
    tenant_id: str = Depends(tenant),
    svc: Services = Depends(services),
) -> Response:
    key = _result(svc, tenant_id, job_id, index)
    try:
        return Response(bundle_file(svc.blobs, key, page_file_name(page)), media_type="image/png")
    except NotFoundError:  # a page past the cell's last: named by page, not by the blob store's key
        pages = len(json.loads(bundle_file(svc.blobs, key, MANIFEST_NAME)).get("pages", []))
        have = f"page 0 to {pages - 1}" if pages > 1 else "page 0" if pages == 1 else "no page"
        raise NotFoundError(
            f"cell {index} of job {job_id!r} has no atlas page {page}; it has {pages} ({have})"
        ) from None


@router.get(
    "/cells/{index}/impostor.glb",
    summary="A cell's impostor as GLB: plain (PNG pages) by default, or with KTX2 pages and meshopt geometry",
)
def cell_glb(
    job_id: str, index: int = CellIndex, tenant_id: str = Depends(tenant), svc: Services = Depends(services),
    textures: Literal["png", "ktx2", "ktx2+png"] = Query("png", description="ktx2: Basis Universal pages (KHR_texture_basisu, required); ktx2+png: the PNG kept as fallback"),
    geometry: Literal["plain", "meshopt"] = Query("plain", description="meshopt: EXT_meshopt_compression (lossless, required)"),
    codec: Literal["etc1s", "uastc"] = Query("etc1s", description="Basis Universal's codec for ktx2 pages"),
) -> Response:  # fmt: skip
    result = _result(svc, tenant_id, job_id, index)
    if textures == "png" and geometry == "plain":
        data = bundle_file(svc.blobs, result, GLB_NAME)
    else:  # encoded on first request, then kept beside the bundle (a folder its listing leaves out)
        variant = f"{result}/variants/{textures}-{geometry}-{codec}.glb"
        if svc.blobs.exists(variant):
            data = svc.blobs.read_bytes(variant)
        else:
            try:
                data = compress_glb(bundle_file(svc.blobs, result, GLB_NAME), textures, geometry, codec)
            except BundleFormatError as error:  # farfield wrote this GLB: one that does not compress is a bug
                raise InternalError(f"cell {index} of job {job_id!r}: its GLB does not compress: {error}") from error
            svc.blobs.put_bytes(variant, data)
    return Response(
        data,
        media_type="model/gltf-binary",
        headers={"Content-Disposition": f'attachment; filename="cell-{index:05d}.glb"'},
    )


@router.get("/cells/{index}", summary="One cell: state, statistics")
def cell_info(
    job_id: str, index: int = CellIndex, tenant_id: str = Depends(tenant), svc: Services = Depends(services)
) -> dict:
    return cell_record(get_cell_row(svc.db, tenant_id, job_id, index))


def _not_written(job: JobRow, what: str) -> ConflictError:
    """The 409 for a job with no database index: one that has not ended yet, or one that ended without it."""
    if job.state in ("cancelled", "failed"):
        return ConflictError(f"job {job.id!r} is {job.state}; it ended without an {what}")
    return ConflictError(f"job {job.id!r} is {job.state}; its {what} is written when it ends")


@router.get(
    "/index.json",
    summary="The job's impostor database index (format farfield-impostor-database): its cells, their view cells, bundles and neighbours; a placement job's CPVs",
)
def job_index(job_id: str, tenant_id: str = Depends(tenant), svc: Services = Depends(services)) -> Response:
    job = get_job_row(svc.db, tenant_id, job_id)
    if job.index_key is None:
        raise _not_written(job, "impostor database index")
    return Response(svc.blobs.read_bytes(job.index_key), media_type="application/json")


@router.get("/database.zip", summary="The job's whole impostor database: index.json and every cell's bundle")
def job_database(job_id: str, tenant_id: str = Depends(tenant), svc: Services = Depends(services)) -> FileResponse:
    job = get_job_row(svc.db, tenant_id, job_id)
    if job.index_key is None:
        raise _not_written(job, "impostor database")
    out = tempfile.NamedTemporaryFile(prefix="farfield-db-", suffix=".zip", delete=False)
    try:
        with out, zipfile.ZipFile(out, "w", zipfile.ZIP_STORED) as archive:  # PNG and GLB are compressed already
            index = svc.blobs.read_bytes(job.index_key)
            archive.writestr("index.json", index)
            shipped = bundled_cells(index)
            for cell in job_cells(svc.db, job_id):
                if cell.result_key is None or (shipped is not None and cell.index not in shipped):
                    continue
                for name, chunks in bundle_members(svc.blobs, cell.result_key):
                    with archive.open(f"cells/{cell.index:05d}/{name}", "w") as member:
                        for chunk in chunks:
                            member.write(chunk)
    except BaseException:
        Path(out.name).unlink(missing_ok=True)
        raise
    return FileResponse(
        out.name,
        media_type="application/zip",
        filename=f"job-{job_id}.zip",
        background=BackgroundTask(Path(out.name).unlink, missing_ok=True),
    )


@router.get(
    "/placement", summary="A placement job's CPVs, impostors, unsolvable regions and totals (the dashboard's map)"
)
def job_placement(job_id: str, tenant_id: TenantDep, svc: ServicesDep) -> dict:
    return documents.placement_document(svc.blobs, get_job_row(svc.db, tenant_id, job_id))


@router.get(
    "/lookup",
    summary="Which impostors serve this view: by position for grid jobs, by position and direction for placement jobs",
)
def lookup_viewpoint(
    job_id: str,
    tenant_id: TenantDep,
    svc: ServicesDep,
    x: float,
    y: float,
    z: float,
    dx: float | None = None,
    dy: float | None = None,
    dz: float | None = None,
) -> list[dict] | dict:
    """A grid job's answer is the cells whose view cell holds (x, y, z).  A placement job's is
    :meth:`PlacementLookup.find` for the view (``cpv``, ``status``, ``impostors``, ``replaced``,
    ``time_estimated``) plus ``cells``: the record of each impostor to draw; everything not in
    ``replaced`` is drawn as geometry.  A placement planned with visibility adds ``pvs``: the
    potentially visible set of the smallest region holding (x, y, z) (``region``, ``box``, ``count``,
    ``of``, element ``ids`` and ``elements`` names; null outside every region): only those elements
    are drawn as geometry."""
    job = get_job_row(svc.db, tenant_id, job_id)
    given = (("x", x), ("y", y), ("z", z), ("dx", dx), ("dy", dy), ("dz", dz))
    not_finite = [f"{name}={value!r}" for name, value in given if value is not None and not math.isfinite(value)]
    if not_finite:
        raise ViewCellError(f"the lookup's coordinates must be finite numbers, got {', '.join(not_finite)}")
    return lookup_view(svc.db, svc.blobs, job, (x, y, z), (dx, dy, dz))


@router.get(
    "/clusters",
    summary="A placement job's clusters of split objects: each one's object and face ranges (what a runtime hides when an impostor replaces a cluster)",
)
def placement_clusters(job_id: str, tenant_id: TenantDep, svc: ServicesDep) -> dict:
    """``{"cluster_triangles": n, "clusters": {name: {"object": name, "faces": [[start, end), ...]}}}``:
    the lookup's ``replaced`` names elements; an element that is not a whole object of the scene is
    one of these clusters (:meth:`farfield.core.placement.hierarchy.Elements.clusters`)."""
    return documents.placement_clusters(svc.db, svc.blobs, get_job_row(svc.db, tenant_id, job_id))
