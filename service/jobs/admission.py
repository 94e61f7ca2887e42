"""Admission: a job from a request, or a refusal before anything is stored.

Every cell of a job of view cells is planned by its technique's check when the job is created
(:func:`admit_cells`); a tenant's cells in flight are capped; a placement job is admitted by its
algorithm (:func:`farfield.service.placement.admission.create_placement_job`).
"""

from __future__ import annotations

import uuid

import numpy as np

from farfield.core.errors import JobTooCostlyError, LayerPlanError, NotFoundError, ViewCellError
from farfield.core.options import stored_values
from farfield.core.techniques import get_technique
from farfield.core.viewcells import viewcell_from_dict
from farfield.service.db import CellRow, Database, JobRow, SceneRow, now
from farfield.service.jobs.schema import MAX_CELLS, JobSpec, grid_cells
from farfield.service.placement.admission import create_placement_job
from farfield.service.quotas import check_cells, open_cells, reserve_tenant_work
from farfield.service.settings import AdmissionLimits

__all__ = [
    "PLAN_BEYOND_LIMIT",
    "admit_cells",
    "approx",
    "create_job",
    "create_placement_job",
    "open_tenant_cells",
    "part_bounds",
    "reserve_tenant_work",
]


def part_bounds(scene: SceneRow, objects: list[str] | None) -> np.ndarray:
    """(2, 3) bounds of the represented objects, from the stored object summaries."""
    by_name = {obj["name"]: obj for obj in scene.objects}
    names = objects or list(by_name)
    missing = [name for name in names if name not in by_name]
    if missing:
        known = sorted(by_name)  # a scene may have 10^5 objects: the message names a few
        shown = ", ".join(known[:20]) + (
            f", ... ({len(known)} in all; GET /v1/scenes/{scene.id}/objects)" if len(known) > 20 else ""
        )
        raise NotFoundError(f"scene {scene.id!r} has no objects named {missing[:20]}; it has {shown}")
    bounds = np.array([by_name[name]["bounds"] for name in names], dtype=np.float64)
    return np.array([bounds[:, 0].min(axis=0), bounds[:, 1].max(axis=0)])


def approx(n: float) -> str:
    """A count for a message: exact below 100,000, else two significant digits.

    >>> approx(4096), approx(1_940_520_960), approx(4 * 10**9), approx(6.25e11)
    ('4,096', '1.9e9', '4e9', '6.2e11')
    """
    if n < 100_000:
        return f"{int(n):,}"
    mantissa, exponent = f"{n:.1e}".split("e")
    return f"{mantissa.removesuffix('.0')}e{int(exponent)}"


def open_tenant_cells(db: Database, tenant_id: str) -> int:
    """Cells of the tenant's jobs that are queued or running."""
    with db.session() as s:
        return open_cells(s, tenant_id)


# How far past the limits admission plans a cell before it stops and refuses with a lower bound.
PLAN_BEYOND_LIMIT = 8


def admit_cells(technique, options, cells: list, bounds: np.ndarray | None, limits: AdmissionLimits) -> int:
    """Plan every cell (the technique's check) and refuse the job when a cell's estimated texels
    pass ``limits.max_cell_texels`` or all cells' pass ``limits.max_job_texels``
    (:class:`~farfield.core.errors.JobTooCostlyError`, 413); returns the job's texels.

    Each check is given ``PLAN_BEYOND_LIMIT`` times what is left of the budgets: a job a few times
    over its limits is refused with its full estimate, one far beyond them after planning that many
    layers, not all of its own (a hostile job costs the API a bounded plan), with a lower bound.
    """
    total = 0
    for n, (_, cell) in enumerate(cells):
        budget = PLAN_BEYOND_LIMIT * min(limits.max_cell_texels, limits.max_job_texels - total)
        try:
            cost = technique.check(cell, options, bounds, max_texels=budget)
        except (LayerPlanError, ViewCellError) as error:
            raise type(error)(f"view cell {n} ({cell.to_dict()}): {error}") from None
        about = "about" if cost.complete else "more than"
        if cost.texels > limits.max_cell_texels:
            raise JobTooCostlyError(
                f"view cell {n} needs {about} {approx(cost.texels)} texels ({cost.describe()}) over the limit of "
                f"{approx(limits.max_cell_texels)} per cell (FARFIELD_MAX_CELL_TEXELS): lower the resolution, use smaller "
                "or farther view cells, or raise the limit"
            )
        total += cost.texels
        if total > limits.max_job_texels:
            which = (
                f"its {len(cells)} view cells need"
                if n == len(cells) - 1
                else f"its first {n + 1} of {len(cells)} view cells already need"
            )
            raise JobTooCostlyError(
                f"the job is too large: {which} {about} {approx(total)} texels over the limit of {approx(limits.max_job_texels)} per job "
                f"(FARFIELD_MAX_JOB_TEXELS): split it into smaller jobs, lower the resolution, or raise the limit"
            )
    return total


def create_job(
    db: Database,
    tenant_id: str,
    scene: SceneRow,
    spec: JobSpec,
    limits: AdmissionLimits | None = None,
    requeue_after: float = 3600.0,
) -> JobRow:
    """Validate ``spec`` against ``scene`` (every cell is planned by its technique's check) and store
    the job and its cells.  Stored parameters hold every option as validated (the technique's
    defaults filled in, numbers and lists normalised), so equal requests store equal parameters (and
    share their bundles, :func:`farfield.service.jobs.cells.result_key`) and a job means the same thing if a default changes.

    A placement job (``spec.placement``) is stored by
    :func:`~farfield.service.placement.admission.create_placement_job` (``requeue_after``: its
    planning lease), within the tenant's quota of open placement jobs.

    Cost admission (``limits``; None: :meth:`AdmissionLimits.from_env`): a tenant whose queued and
    running cells would pass ``max_tenant_cells`` with this job's is refused with
    :class:`~farfield.core.errors.QuotaError` (429) before anything is planned; a job whose cells'
    plans pass the texel limits with :class:`~farfield.core.errors.JobTooCostlyError` (413,
    :func:`admit_cells`).  Nothing is stored for a refused job.  The count is read once before
    planning (a cheap early refusal) and again, authoritatively, in the transaction that stores the
    cells, with the tenant's admissions serialised (:func:`reserve_tenant_work`), so two requests of
    one tenant at the same moment cannot both pass it."""
    limits = AdmissionLimits.from_env() if limits is None else limits
    if spec.placement is not None:
        reserve = lambda s: reserve_tenant_work(s, tenant_id, 0, limits, placement=True)  # noqa: E731
        return create_placement_job(db, tenant_id, scene, spec, requeue_after, reserve)
    technique = get_technique(spec.technique_name)
    options = technique.options(spec.options, spec.resolution, spec.fov_deg)
    params = {
        "resolution": options.resolution,
        "fov_deg": options.fov_deg,
        "objects": spec.objects,
        "options": stored_values(options),
    }
    if technique.scope == "scene" and spec.objects is not None:
        raise LayerPlanError(
            f"a {technique.name} job represents the whole scene: leave out 'objects' (it is for techniques of one part)"
        )
    if spec.grid is not None:
        cells = [(list(ijk), box) for ijk, box in grid_cells(spec.grid)]
    else:
        if not spec.viewcells:
            raise ViewCellError("'viewcells' is empty")
        if len(spec.viewcells) > MAX_CELLS:
            raise ViewCellError(f"{len(spec.viewcells)} view cells is over the limit of {MAX_CELLS}")
        cells = [(None, viewcell_from_dict(cell)) for cell in spec.viewcells]
    bounds = part_bounds(scene, spec.objects) if technique.scope == "part" else None
    if len(cells) > limits.max_tenant_cells:  # it could never pass: not a 429 to retry
        raise JobTooCostlyError(
            f"the job's {len(cells):,} view cells are more than a tenant may have queued or running, {limits.max_tenant_cells:,} "
            "(FARFIELD_MAX_TENANT_CELLS): split it into smaller jobs, or raise the limit"
        )
    check_cells(open_tenant_cells(db, tenant_id), len(cells), limits)
    admit_cells(technique, options, cells, bounds, limits)
    job = JobRow(
        id=uuid.uuid4().hex, tenant_id=tenant_id, scene_id=scene.id, job_type=technique.name, params=params,
        evaluate=spec.evaluate, state="queued", created_at=now(),
    )  # fmt: skip
    with db.session() as s:
        reserve_tenant_work(s, tenant_id, len(cells), limits)
        s.add(job)
        s.flush()
        for n, (grid, cell) in enumerate(cells):
            s.add(
                CellRow(
                    id=uuid.uuid4().hex,
                    job_id=job.id,
                    index=n,
                    grid=grid,
                    viewcell=cell.to_dict(),
                    state="queued",
                    attempts=0,
                    progress=0.0,
                    queued_at=now(),
                )
            )
    return job
