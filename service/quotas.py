"""Tenant quotas, enforced in the transaction that stores the work (issue 59, item 6): the cells a
tenant has queued or running (``FARFIELD_MAX_TENANT_CELLS``) and its open placement jobs
(``FARFIELD_MAX_TENANT_PLACEMENTS``), for a new job (:mod:`farfield.service.jobs.admission`), a
retry (:func:`farfield.service.jobs.cells.retry_job`) and a placement's planned cells
(:mod:`farfield.service.placement.rounds`)."""

from __future__ import annotations

from sqlalchemy import func, select

from farfield.core.errors import QuotaError
from farfield.service.db import OPEN_JOB_STATES, CellRow, JobRow, Tenant
from farfield.service.placement.base import PLACEMENT_JOB
from farfield.service.settings import AdmissionLimits


def open_cells(s, tenant_id: str) -> int:
    """Cells of the tenant's jobs that are queued or running, in the session ``s``."""
    return s.scalar(
        select(func.count()).select_from(CellRow).join(JobRow, CellRow.job_id == JobRow.id)
        .where(JobRow.tenant_id == tenant_id, CellRow.state.in_(("queued", "running")))
    )  # fmt: skip


def check_cells(open_now: int, cells: int, limits: AdmissionLimits) -> None:
    """Refuse (:class:`QuotaError`) ``cells`` more when ``open_now`` are open and they would pass the quota."""
    if open_now + cells > limits.max_tenant_cells:
        raise QuotaError(
            f"tenant has {open_now:,} cells queued or running; this job's {cells:,} would pass the limit of "
            f"{limits.max_tenant_cells:,} (FARFIELD_MAX_TENANT_CELLS): wait for some to end, or cancel a job"
        )


def reserve_tenant_work(s, tenant_id: str, cells: int, limits: AdmissionLimits, placement: bool = False) -> None:
    """In the session ``s`` that stores a new job: serialise the tenant's admissions and refuse
    (:class:`~farfield.core.errors.QuotaError`, 429; the session rolls back, nothing is stored) when
    its open cells with this job's ``cells`` pass ``max_tenant_cells``, or, for a ``placement``
    job, when it has ``max_tenant_placements`` placement jobs open already.

    On PostgreSQL the tenant's row is locked (``SELECT ... FOR NO KEY UPDATE``) until the session commits,
    so a second admission of the same tenant waits for the first to be stored and counts its cells;
    SQLite begins every transaction with ``BEGIN IMMEDIATE`` (:mod:`farfield.service.db`), which
    serialises all writers already."""
    # FOR NO KEY UPDATE: serialises admissions without blocking the tenant's other inserts (their
    # foreign keys take FOR KEY SHARE on the row, which FOR UPDATE would block).
    s.execute(select(Tenant.id).where(Tenant.id == tenant_id).with_for_update(key_share=True))
    check_cells(open_cells(s, tenant_id), cells, limits)
    if placement:
        placing = s.scalar(
            select(func.count()).select_from(JobRow)
            .where(JobRow.tenant_id == tenant_id, JobRow.job_type == PLACEMENT_JOB, JobRow.state.in_(OPEN_JOB_STATES))
        )  # fmt: skip
        if placing >= limits.max_tenant_placements:
            raise QuotaError(
                f"tenant has {placing:,} placement jobs open, the limit (FARFIELD_MAX_TENANT_PLACEMENTS="
                f"{limits.max_tenant_placements}): wait for one to end, or cancel one"
            )
