"""Health (no key needed), the render workers and Prometheus-style metrics (a key needed).

``/metrics`` answers with the figures of the caller's tenant: a tenant's key sees its own jobs,
cells and scenes, the admin tenant's key the whole service's.  Counts across tenants tell a stranger
how busy the service is and when other tenants work, so a key is needed (a Prometheus scrape job
sets it with ``authorization: {credentials: <key>}``); ``/v1/health`` stays open for load balancers.
"""

from __future__ import annotations

from fastapi import APIRouter, Depends
from fastapi.responses import PlainTextResponse
from sqlalchemy import func, select

from farfield.api.deps import Services, services, tenant
from farfield.service.db import CellRow, JobRow, SceneRow, Tenant
from farfield.service.jobs.leases import worker_records
from farfield.service.keys import ADMIN_TENANT

router = APIRouter(tags=["operations"])


@router.get("/v1/health", summary="Database and broker reachability")
def health(svc: Services = Depends(services)) -> dict:
    try:
        svc.db.ping()  # never behind a writer's lock
        database = True
    except Exception:  # noqa: BLE001
        database = False
    broker = svc.broker.reachable()  # a PING on a kept connection (api/broker_probe.py)
    return {"status": "ok" if database and broker else "degraded", "database": database, "broker": broker}


@router.get("/v1/workers", summary="The render workers: host, kind, renderer, current cells, last heartbeat")
def workers(tenant_id: str = Depends(tenant), svc: Services = Depends(services)) -> dict:
    """Every worker that ever sent a heartbeat, newest first; ``alive`` while its last heartbeat is
    within the lease (``FARFIELD_LEASE_S``).  A worker's cells of other tenants' jobs are only counted
    (``other_cells``); the admin key sees them all."""
    with svc.db.session() as s:
        admin = s.scalar(select(Tenant.id).where(Tenant.name == ADMIN_TENANT)) == tenant_id
    found = worker_records(svc.db, None if admin else tenant_id, svc.settings.lease_s)
    return {"workers": found, "lease_s": svc.settings.lease_s, "heartbeat_s": svc.settings.heartbeat_s}


@router.get(
    "/metrics",
    response_class=PlainTextResponse,
    summary="Prometheus text format: the caller's tenant's figures (the admin key: the service's)",
)
def metrics(tenant_id: str = Depends(tenant), svc: Services = Depends(services)) -> str:
    lines = []
    with svc.db.session() as s:
        admin = s.scalar(select(Tenant.id).where(Tenant.name == ADMIN_TENANT)) == tenant_id
        jobs, cells = select(JobRow.state, func.count()), select(CellRow.state, func.count())
        attempts = select(func.coalesce(func.sum(CellRow.attempts), 0))
        seconds = select(func.coalesce(func.sum(CellRow.seconds), 0.0))
        scenes = select(func.count()).select_from(SceneRow)
        if not admin:
            jobs = jobs.where(JobRow.tenant_id == tenant_id)
            cells, attempts, seconds = (
                q.join(JobRow, CellRow.job_id == JobRow.id).where(JobRow.tenant_id == tenant_id)
                for q in (cells, attempts, seconds)
            )
            scenes = scenes.where(SceneRow.tenant_id == tenant_id)
        lines += ["# HELP farfield_jobs Jobs by state.", "# TYPE farfield_jobs gauge"]
        for state, count in s.execute(jobs.group_by(JobRow.state)):
            lines.append(f'farfield_jobs{{state="{state}"}} {count}')
        lines += ["# HELP farfield_cells Cells by state.", "# TYPE farfield_cells gauge"]
        for state, count in s.execute(cells.group_by(CellRow.state)):
            lines.append(f'farfield_cells{{state="{state}"}} {count}')
        lines += [
            "# HELP farfield_cell_attempts_total Attempts over all cells.",
            "# TYPE farfield_cell_attempts_total counter",
        ]
        lines.append(f"farfield_cell_attempts_total {s.scalar(attempts)}")
        lines += [
            "# HELP farfield_cell_seconds_total Seconds spent in finished cells.",
            "# TYPE farfield_cell_seconds_total counter",
        ]
        lines.append(f"farfield_cell_seconds_total {float(s.scalar(seconds))}")
        lines += ["# HELP farfield_scenes Stored scenes.", "# TYPE farfield_scenes gauge"]
        lines.append(f"farfield_scenes {s.scalar(scenes)}")
    return "\n".join(lines) + "\n"
