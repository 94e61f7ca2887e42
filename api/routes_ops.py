"""Health and Prometheus-style metrics (no key needed)."""

from __future__ import annotations

from fastapi import APIRouter, Depends
from fastapi.responses import PlainTextResponse
from sqlalchemy import func, select, text

from farfield.service.db import CellRow, JobRow, SceneRow

from farfield.api.deps import Services, services

router = APIRouter(tags=["operations"])


def _broker_ok(svc: Services) -> bool:
    try:
        with svc.celery.connection_for_write() as connection:
            connection.ensure_connection(max_retries=1, timeout=1)
        return True
    except Exception:  # noqa: BLE001 - any failure means "not reachable"
        return False


@router.get("/v1/health", summary="Database and broker reachability")
def health(svc: Services = Depends(services)) -> dict:
    try:
        with svc.db.session() as s:
            s.execute(text("SELECT 1"))
        database = True
    except Exception:  # noqa: BLE001
        database = False
    broker = _broker_ok(svc)
    return {"status": "ok" if database and broker else "degraded", "database": database, "broker": broker}


@router.get("/metrics", response_class=PlainTextResponse, summary="Prometheus text format")
def metrics(svc: Services = Depends(services)) -> str:
    lines = []
    with svc.db.session() as s:
        lines += ["# HELP farfield_jobs Jobs by state.", "# TYPE farfield_jobs gauge"]
        for state, count in s.execute(select(JobRow.state, func.count()).group_by(JobRow.state)):
            lines.append(f'farfield_jobs{{state="{state}"}} {count}')
        lines += ["# HELP farfield_cells Cells by state.", "# TYPE farfield_cells gauge"]
        for state, count in s.execute(select(CellRow.state, func.count()).group_by(CellRow.state)):
            lines.append(f'farfield_cells{{state="{state}"}} {count}')
        lines += ["# HELP farfield_cell_attempts_total Attempts over all cells.", "# TYPE farfield_cell_attempts_total counter"]
        lines.append(f"farfield_cell_attempts_total {s.scalar(select(func.coalesce(func.sum(CellRow.attempts), 0)))}")
        lines += ["# HELP farfield_cell_seconds_total Seconds spent in finished cells.", "# TYPE farfield_cell_seconds_total counter"]
        lines.append(f"farfield_cell_seconds_total {float(s.scalar(select(func.coalesce(func.sum(CellRow.seconds), 0.0))))}")
        lines += ["# HELP farfield_scenes Stored scenes.", "# TYPE farfield_scenes gauge"]
        lines.append(f"farfield_scenes {s.scalar(select(func.count()).select_from(SceneRow))}")
    return "\n".join(lines) + "\n"
