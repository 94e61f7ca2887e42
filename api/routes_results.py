"""Results: per-cell bundle (zip), manifest, atlas pages, GLB; a job's whole impostor database; lookup;
a placement job's CPVs and what to draw in a view (:mod:`farfield.core.placement.database`)."""

from __future__ import annotations

import json
import math
import tempfile
import threading
import zipfile
from collections import OrderedDict
from pathlib import Path
from typing import Annotated, Literal

from fastapi import APIRouter, Depends, Path as PathParam, Query
from fastapi.responses import FileResponse, Response
from sqlalchemy import select
from starlette.background import BackgroundTask

from farfield.core.impostor.bundle import GLB_NAME, MANIFEST_NAME, PAYLOAD_NAME, bundle_zip, page_file_name
from farfield.core.impostor.glb_compression import compress_glb
from farfield.core.errors import BundleFormatError, ConflictError, InternalError, NotFoundError, ViewCellError
from farfield.core.placement.database import PlacementLookup
from farfield.core.placement.hierarchy import Elements, PlacementError
from farfield.core.placement.image_database import image_lookup, placement_of_index
from farfield.service.db import CellRow, JobRow
from farfield.service.jobs import cell_record, get_cell_row, get_job_row, job_cells, lookup
from farfield.service.placement_jobs import PRIMITIVE_INDEX_KIND
from farfield.service.scenes import get_scene_row, load_stored_scene

from farfield.api.deps import Services, services, tenant

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


@router.get("/cells/{index}/impostor.glb", summary="A cell's impostor as GLB: plain (PNG pages) by default, or with KTX2 pages and meshopt geometry")
def cell_glb(
    job_id: str, index: int = CellIndex, tenant_id: str = Depends(tenant), svc: Services = Depends(services),
    textures: Literal["png", "ktx2", "ktx2+png"] = Query("png", description="ktx2: Basis Universal pages (KHR_texture_basisu, required); ktx2+png: the PNG kept as fallback"),
    geometry: Literal["plain", "meshopt"] = Query("plain", description="meshopt: EXT_meshopt_compression (lossless, required)"),
    codec: Literal["etc1s", "uastc"] = Query("etc1s", description="Basis Universal's codec for ktx2 pages"),
) -> Response:  # fmt: skip
    result = _result(svc, tenant_id, job_id, index)
    if textures == "png" and geometry == "plain":
        data = svc.blobs.read_bytes(f"{result}/{GLB_NAME}")
    else:  # encoded on first request, then kept beside the bundle (a folder its listing leaves out)
        variant = f"{result}/variants/{textures}-{geometry}-{codec}.glb"
        if svc.blobs.exists(variant):
            data = svc.blobs.read_bytes(variant)
        else:
            try:
                data = compress_glb(svc.blobs.read_bytes(f"{result}/{GLB_NAME}"), textures, geometry, codec)
            except BundleFormatError as error:  # farfield wrote this GLB: one that does not compress is a bug
                raise InternalError(f"cell {index} of job {job_id!r}: its GLB does not compress: {error}") from error
            svc.blobs.put_bytes(variant, data)
    return Response(data, media_type="model/gltf-binary", headers={"Content-Disposition": f'attachment; filename="cell-{index:05d}.glb"'})


@router.get("/cells/{index}", summary="One cell: state, statistics")
def cell_info(job_id: str, index: int = CellIndex, tenant_id: str = Depends(tenant), svc: Services = Depends(services)) -> dict:
    return cell_record(get_cell_row(svc.db, tenant_id, job_id, index))


def _not_written(job: JobRow, what: str) -> ConflictError:
    """The 409 for a job with no database index: one that has not ended yet, or one that ended without it."""
    if job.state in ("cancelled", "failed"):
        return ConflictError(f"job {job.id!r} is {job.state}; it ended without an {what}")
    return ConflictError(f"job {job.id!r} is {job.state}; its {what} is written when it ends")


@router.get("/index.json", summary="The job's impostor database index (format farfield-impostor-database): its cells, their view cells, bundles and neighbours; a placement job's CPVs")
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
            shipped = _bundled_cells(index)
            for cell in job_cells(svc.db, job_id):
                if cell.result_key is None or (shipped is not None and cell.index not in shipped):
                    continue
                for name in svc.blobs.list_files(cell.result_key):
                    with archive.open(f"cells/{cell.index:05d}/{name}", "w") as member:
                        for chunk in svc.blobs.iter_chunks(f"{cell.result_key}/{name}"):
                            member.write(chunk)
    except BaseException:
        Path(out.name).unlink(missing_ok=True)
        raise
    return FileResponse(out.name, media_type="application/zip", filename=f"job-{job_id}.zip", background=BackgroundTask(Path(out.name).unlink, missing_ok=True))


def _bundled_cells(index: bytes) -> set[int] | None:
    """The cells a placement database ships (those its index gives a bundle: an impostor no CPV
    draws has none); None for any other database (every baked cell)."""
    doc = json.loads(index)
    if doc.get("kind") != "placement":
        return None
    return {int(c["index"]) for c in doc.get("cells", []) if c.get("bundle")}


PLACEMENT = "placement"  # the job type of a placement job (its cells are the placement's impostors)
LOOKUP_CACHE_SIZE = 16  # placement databases kept parsed in this process


class _LookupCache:
    """The parsed index and :class:`PlacementLookup` of recent placement jobs, least recently used
    out first.  Keyed by the index blob's key and the job's end (a retried job writes its index
    again under the same key), so a runtime polling the lookup does not re-read the blob each call."""

    def __init__(self, size: int) -> None:
        self.size = size
        self.entries: OrderedDict[tuple, tuple[dict, PlacementLookup]] = OrderedDict()
        self.lock = threading.Lock()
        self.reads = 0  # blobs read and parsed (tests: a second call reads nothing)

    def get(self, svc: Services, job: JobRow) -> tuple[dict, PlacementLookup]:
        key = (job.index_key, job.finished_at)
        with self.lock:
            if key in self.entries:
                self.entries.move_to_end(key)
                return self.entries[key]
        try:
            index = json.loads(svc.blobs.read_bytes(job.index_key))
            found = (index, placement_of_index(index) if index.get("kind") == PRIMITIVE_INDEX_KIND else PlacementLookup(index))
        except (ValueError, KeyError, TypeError, PlacementError) as error:
            # farfield wrote this index: one that does not read is a bug (500), not bad input
            raise InternalError(f"job {job.id!r}: its placement database index does not read: {error}") from error
        with self.lock:
            self.reads += 1
            self.entries[key] = found
            self.entries.move_to_end(key)
            while len(self.entries) > self.size:
                self.entries.popitem(last=False)
        return found


LOOKUPS = _LookupCache(LOOKUP_CACHE_SIZE)


def _placement_database(svc: Services, tenant_id: str, job_id: str) -> tuple[JobRow, dict, PlacementLookup]:
    """A placement job's (row, index, lookup): 404 for another kind of job, 409 before its index is written."""
    job = get_job_row(svc.db, tenant_id, job_id)
    if job.job_type != PLACEMENT:
        raise NotFoundError(f"job {job_id!r} is a {job.job_type} job, not a placement job: it has no placement (its cells are looked up by position alone)")
    if job.index_key is None:
        raise ConflictError(f"job {job_id!r} is {job.state}; its placement database is written when its impostors are baked")
    index, found = LOOKUPS.get(svc, job)
    return job, index, found


def _cell_records(svc: Services, job_id: str, indices: list[int]) -> list[dict]:
    """The cell records of ``indices`` of a job, in that order."""
    if not indices:
        return []
    with svc.db.session() as s:
        rows = {c.index: c for c in s.scalars(select(CellRow).where(CellRow.job_id == job_id, CellRow.index.in_(indices)))}
    return [cell_record(rows[i]) for i in indices if i in rows]


@router.get("/placement", summary="A placement job's CPVs, impostors, unsolvable regions and totals (the dashboard's map)")
def job_placement(job_id: str, tenant_id: TenantDep, svc: ServicesDep) -> dict:
    job, index, _ = _placement_database(svc, tenant_id, job_id)
    if index.get("kind") == PRIMITIVE_INDEX_KIND:
        return _image_placement(job, index)
    section = index["placement"]
    cells = [
        {k: c.get(k) for k in ("index", "state", "technique", "objects", "viewcell", "cpvs", "figures", "bundle")}
        for c in index.get("cells", [])
    ]  # fmt: skip
    estimated = [(c["figures"] or {}).get("estimated") or {} for c in cells]
    baked = [(c["figures"] or {}).get("baked") or {} for c in cells]
    drawn = [c for c in cells if c.get("cpvs")]
    totals = {
        "impostors": len(drawn),
        "impostors_listed": len(cells),
        "impostors_baked": sum(1 for b in baked if "texture_bytes" in b),
        "memory_bytes_estimated": sum(float(e.get("memory_bytes_estimated", 0.0)) for c, e in zip(cells, estimated) if c.get("cpvs")),
        "memory_bytes_baked": sum(int(b.get("texture_bytes", 0)) for c, b in zip(cells, baked) if c.get("cpvs")),
        "cpvs": len(section["cpvs"]),
        "cpvs_by_status": {s: sum(1 for c in section["cpvs"] if c["status"] == s) for s in ("solved", "unsolved", "unsolvable")},
        "unsolvable_regions": len(section["unsolvable"]),
        "rounds": len(section.get("rounds") or []),
    }
    return {"job": job.id, "state": job.state, **section, "cells": cells, "totals": totals}


@router.get("/lookup", summary="Which impostors serve this view: by position for grid jobs, by position and direction for placement jobs")
def lookup_viewpoint(
    job_id: str, tenant_id: TenantDep, svc: ServicesDep, x: float, y: float, z: float, dx: float | None = None, dy: float | None = None, dz: float | None = None
) -> list[dict] | dict:
    """A grid job's answer is the cells whose view cell holds (x, y, z).  A placement job's is
    :meth:`PlacementLookup.find` for the view (``cpv``, ``status``, ``impostors``, ``replaced``,
    ``time_estimated``) plus ``cells``: the record of each impostor to draw; everything not in
    ``replaced`` is drawn as geometry."""
    job = get_job_row(svc.db, tenant_id, job_id)
    given = (("x", x), ("y", y), ("z", z), ("dx", dx), ("dy", dy), ("dz", dz))
    not_finite = [f"{name}={value!r}" for name, value in given if value is not None and not math.isfinite(value)]
    if not_finite:
        raise ViewCellError(f"the lookup's coordinates must be finite numbers, got {', '.join(not_finite)}")
    if job.job_type != PLACEMENT:
        return [cell_record(cell) for cell in lookup(job_cells(svc.db, job_id), (x, y, z))]
    missing = [name for name, value in (("dx", dx), ("dy", dy), ("dz", dz)) if value is None]
    if missing:
        raise ViewCellError(f"a placement job's lookup needs the view direction dx, dy, dz as well as the position; missing: {', '.join(missing)}")
    _, index, found = _placement_database(svc, tenant_id, job_id)
    if index.get("kind") == PRIMITIVE_INDEX_KIND:
        return _image_lookup(svc, job_id, index, found, (x, y, z), (dx, dy, dz))
    answer = found.find((x, y, z), (dx, dy, dz))
    return {**answer, "cells": _cell_records(svc, job_id, answer["impostors"])}


_CLUSTERS: OrderedDict[tuple, dict] = OrderedDict()  # (index key, end) -> /clusters answer, the last few jobs used
_CLUSTERS_LOCK = threading.Lock()


@router.get("/clusters", summary="A placement job's clusters of split objects: each one's object and face ranges (what a runtime hides when an impostor replaces a cluster)")
def placement_clusters(job_id: str, tenant_id: TenantDep, svc: ServicesDep) -> dict:
    """``{"cluster_triangles": n, "clusters": {name: {"object": name, "faces": [[start, end), ...]}}}``:
    the lookup's ``replaced`` names elements; an element that is not a whole object of the scene is
    one of these clusters (:meth:`farfield.core.placement.hierarchy.Elements.clusters`)."""
    job, index, _ = _placement_database(svc, tenant_id, job_id)
    if index.get("kind") == PRIMITIVE_INDEX_KIND:
        raise NotFoundError(f"job {job_id!r} is a primitive-budget placement: its images replace octree cells, not clusters")
    key = (job.index_key, job.finished_at)
    with _CLUSTERS_LOCK:
        found = _CLUSTERS.get(key)
        if found is not None:
            _CLUSTERS.move_to_end(key)
            return found
    cluster = int(index["placement"]["elements"]["cluster_triangles"])
    scene = load_stored_scene(svc.blobs, get_scene_row(svc.db, tenant_id, job.scene_id))
    found = {"cluster_triangles": cluster, "clusters": Elements.of(scene, cluster).clusters(scene)}
    with _CLUSTERS_LOCK:
        _CLUSTERS[key] = found
        while len(_CLUSTERS) > LOOKUP_CACHE_SIZE:
            _CLUSTERS.popitem(last=False)
    return found


def _image_placement(job: JobRow, index: dict) -> dict:
    """``/placement`` of a primitive-budget job: its parameters, the grid's summary and points with
    their images (each with its cell and bundle), and totals."""
    bundles = index["bundles"]
    baked = {b["image"]: b for b in index.get("cells_baked", [])}
    points = []
    for pi, p in enumerate(index["points"]):
        images = []
        for ii, im in enumerate(p["images"]):
            name = f"{pi}-{ii}"
            cell = baked.get(name) or {}
            images.append({"name": name, "yaw": im["yaw"], "depth": im["depth"], "drawn": im["drawn"], "octree_cells": len(im["cells"]),
                           "cell": cell.get("index"), "bundle": bundles.get(name), "texture_bytes": (cell.get("stats") or {}).get("texture_bytes")})  # fmt: skip
        points.append({"position": p["position"], "level": p["level"], "radius": p["radius"], "failure": p["failure"], "images": images})
    summary = index["summary"]
    sizes = [im["texture_bytes"] or 0 for p in points for im in p["images"]]
    totals = {
        "images": summary["images"], "images_baked": sum(1 for p in points for im in p["images"] if im["bundle"]), "memory_bytes_baked": int(sum(sizes)),
        "grid_points": summary["grid_points"], "unsolved_points": summary["unsolved_points"],
    }  # fmt: skip
    parameters = {"algorithm": "primitive-budget", "technique": "ldi", "primitives": summary["primitives"], "p_opt": summary["p_opt"],
                  "fov_deg": summary["fov_deg"], "octree_depth": summary["octree_depth"], "resolution": index["resolution"],
                  "construction_images": index["construction_images"], "view_space": index["view_space"]}  # fmt: skip
    return {"job": job.id, "state": job.state, "algorithm": "primitive-budget", "parameters": parameters, "summary": summary, "points": points, "totals": totals}


def _image_lookup(svc: Services, job_id: str, index: dict, placement, eye, direction) -> dict:
    """``/lookup`` of a primitive-budget job (:func:`farfield.core.placement.image_database.image_lookup`), with
    the record of the cell that baked the image."""
    answer = image_lookup(index, placement, eye, direction)
    cell = next((b["index"] for b in index.get("cells_baked", []) if b["image"] == answer["image"]), None) if answer["image"] else None
    return {**answer, "cells": _cell_records(svc, job_id, [cell] if cell is not None else [])}
