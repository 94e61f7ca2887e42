"""``/v1/jobs``: create, list, get, cancel, retry."""

from __future__ import annotations

from typing import Literal

from fastapi import APIRouter, Depends, Query, Request, Response
from fastapi.responses import JSONResponse

from farfield.api.deps import Services, services, tenant
from farfield.api.paging import DEFAULT_PAGE, PAGED, Limit, Offset, set_page_headers
from farfield.service.jobs.admission import create_job
from farfield.service.jobs.cells import cancel_job, retry_job
from farfield.service.jobs.records import (
    cell_page,
    count_cells,
    count_job_rows,
    full_job_record,
    get_job_row,
    job_record,
    job_summaries,
    list_job_rows,
)
from farfield.service.jobs.schema import JobSpec
from farfield.service.scenes import get_scene_row

router = APIRouter(prefix="/v1/jobs", tags=["jobs"])


def _full_record(svc: Services, job) -> JSONResponse:
    """A job's record with all its cells, encoded straight to JSON: it holds nothing but JSON's own
    types (its columns are JSON or plain), and FastAPI's ``jsonable_encoder``, which walks every value
    first, took 2.7 s of the API's only core for a 10,000-cell job (bench_orchestration.py)."""
    return JSONResponse(full_job_record(svc.db, job))


@router.post(
    "",
    status_code=201,
    summary="Create a job: one impostor per view cell (its cells checked on a worker first: state 'admitting'; "
    "answers the job's record without its cells), or a placement job (planned on a worker: state 'placing')",
)
def submit_job(spec: JobSpec, tenant_id: str = Depends(tenant), svc: Services = Depends(services)) -> dict:
    if spec.placement is not None:
        scene = get_scene_row(svc.db, tenant_id, spec.scene_id)
        job = create_job(svc.db, tenant_id, scene, spec, svc.settings.admission, svc.settings.requeue_after)
        svc.send_planning(job.id)  # Redis away past the send's retries: the job is stored, the next sweep sends it
        return full_job_record(svc.db, job)
    scene = get_scene_row(svc.db, tenant_id, spec.scene_id, with_objects=True)  # a part's bounds are its objects'
    # O(cells), no plan: the job is stored "admitting" and a worker checks its cells, then sends them.
    job = create_job(svc.db, tenant_id, scene, spec, svc.settings.admission, svc.settings.requeue_after)
    svc.send_admission(job.id)  # Redis away past the send's retries: the job is stored, the next sweep sends it
    # The record without its cells (GET /v1/jobs/{id} has them): 10,000 cells would be megabytes.
    return job_record(job, job_summaries(svc.db, [job.id])[job.id])


@router.get(
    "", summary="List jobs, newest first (filter by state or scene); paged (X-Total-Count, Link)", responses=PAGED
)
def list_jobs(
    request: Request,
    response: Response,
    state: str | None = None,
    scene_id: str | None = None,
    limit: Limit = DEFAULT_PAGE,
    offset: Offset = 0,
    tenant_id: str = Depends(tenant),
    svc: Services = Depends(services),
) -> list[dict]:
    jobs = list_job_rows(svc.db, tenant_id, state, scene_id, limit, offset)
    set_page_headers(request, response, count_job_rows(svc.db, tenant_id, state, scene_id), limit, offset)
    summaries = job_summaries(svc.db, [job.id for job in jobs])
    return [job_record(job, summaries[job.id]) for job in jobs]


CELLS = Query(
    "all",
    description="all: the record with every cell, its evaluation and timing; none: without them (counts, progress, "
    "errors and ETA come from SQL, no cell row is read: what a poller of a large job asks for; the cells are "
    "paged at /v1/jobs/{id}/cells)",
)


@router.get("/{job_id}", response_model=dict, summary="One job: state, per-cell progress, counts, timings, errors, ETA")
def get_job(
    job_id: str,
    cells: Literal["all", "none"] = CELLS,
    tenant_id: str = Depends(tenant),
    svc: Services = Depends(services),
) -> JSONResponse:
    job = get_job_row(svc.db, tenant_id, job_id)
    if cells == "none":
        return JSONResponse(job_record(job, job_summaries(svc.db, [job.id])[job.id]))
    return _full_record(svc, job)


@router.get(
    "/{job_id}/cells",
    response_model=list[dict],
    summary="A job's cells by index: state, progress, attempts, errors, statistics; paged (X-Total-Count, Link)",
    responses=PAGED,
)
def list_cells(
    request: Request,
    job_id: str,
    limit: Limit = DEFAULT_PAGE,
    offset: Offset = 0,
    tenant_id: str = Depends(tenant),
    svc: Services = Depends(services),
) -> JSONResponse:
    get_job_row(svc.db, tenant_id, job_id)
    # Encoded straight to JSON, as the job's record is (_full_record): the records hold JSON's own types.
    response = JSONResponse(cell_page(svc.db, job_id, limit, offset))
    set_page_headers(request, response, count_cells(svc.db, job_id), limit, offset)
    return response


@router.post("/{job_id}/cancel", summary="Cancel: queued cells never run, running cells stop at the next layer")
def cancel(job_id: str, tenant_id: str = Depends(tenant), svc: Services = Depends(services)) -> dict:
    job = cancel_job(svc.db, svc.blobs, tenant_id, job_id)
    return full_job_record(svc.db, job)


@router.post("/{job_id}/retry", summary="Queue a failed job's failed cells again")
def retry(job_id: str, tenant_id: str = Depends(tenant), svc: Services = Depends(services)) -> dict:
    ids = retry_job(svc.db, tenant_id, job_id, svc.settings.admission)
    job = get_job_row(svc.db, tenant_id, job_id)
    if job.state == "admitting":  # a cell had failed its full check: the retried cells are checked again
        svc.send_admission(job.id)
    else:
        svc.enqueue(ids)
    return full_job_record(svc.db, job)
