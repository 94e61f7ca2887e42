"""Admission: a job from a request, or a refusal before anything is stored.

The request costs O(cells) and plans nothing (issue 58, item 3): a job of view cells is refused
(413) where a cheap lower bound of its cost (the technique's ``bound``, :func:`bound_cells`)
already passes the limits, and otherwise stored in the state ``admitting`` with its cells, counted
against the tenant's quota; a worker then runs every cell's full check (:func:`check_cell`,
:mod:`farfield.service.jobs.admitting`) before any is baked.  A placement job is admitted by its
algorithm (:func:`farfield.service.placement.admission.create_placement_job`).
"""

from __future__ import annotations

import json
import secrets
import uuid

import numpy as np
from sqlalchemy.orm import Session

from farfield.core.errors import JobTooCostlyError, LayerPlanError, NotFoundError, ViewCellError
from farfield.core.options import stored_values
from farfield.core.techniques import get_technique
from farfield.core.viewcells import viewcell_from_dict
from farfield.service.db import CellRow, Database, JobRow, SceneRow, now
from farfield.service.jobs.schema import MAX_CELLS, JobSpec, grid_cell_arrays
from farfield.service.placement.admission import create_placement_job
from farfield.service.quotas import check_cells, open_cells, reserve_tenant_work
from farfield.service.settings import AdmissionLimits

__all__ = [
    "PLAN_BEYOND_LIMIT",
    "approx",
    "bound_cells",
    "check_cell",
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


# How far past the limits a cell's full check plans before it stops and fails the cell with a lower bound.
PLAN_BEYOND_LIMIT = 8


def cell_too_costly(n: int, texels: int, about: str, described: str, limits: AdmissionLimits) -> str:
    """The refusal of view cell ``n`` over ``limits.max_cell_texels``: the 413's detail in the
    request (by the bound), a cell's error on a worker (by its full check)."""
    return (
        f"view cell {n} needs {about} {approx(texels)} texels ({described}) over the limit of "
        f"{approx(limits.max_cell_texels)} per cell (FARFIELD_MAX_CELL_TEXELS): lower the resolution, use smaller "
        "or farther view cells, or raise the limit"
    )


def job_too_costly(n: int, cells: int, texels: int, about: str, limits: AdmissionLimits) -> str:
    """The refusal of a job whose first ``n + 1`` of ``cells`` view cells pass ``limits.max_job_texels``."""
    which = (
        f"its {cells} view cells need" if n == cells - 1 else f"its first {n + 1} of {cells} view cells already need"
    )
    return (
        f"the job is too large: {which} {about} {approx(texels)} texels over the limit of {approx(limits.max_job_texels)} per job "
        f"(FARFIELD_MAX_JOB_TEXELS): split it into smaller jobs, lower the resolution, or raise the limit"
    )


def bound_cells(technique, options, cells, bounds: np.ndarray | None, limits: AdmissionLimits) -> int:
    """The request's admission, O(cells) and without a plan: refuse the job
    (:class:`~farfield.core.errors.JobTooCostlyError`, 413) when a lower bound of its cells' texels
    (the technique's ``bound``: for a part technique one layer of each cell's exact texture,
    vectorised) already passes ``limits.max_cell_texels`` for a cell or ``limits.max_job_texels``
    for all; returns the bound of the job's texels (0 for a technique without one).

    A bound, never an estimate: what it refuses, the full plans would refuse too, so the request
    never turns away a job that its workers' checks (:mod:`farfield.service.jobs.admitting`) would take."""
    bound = getattr(technique, "bound", None)
    if bound is None or not cells:
        return 0
    texels = np.asarray(bound(cells, options, bounds), dtype=np.int64)
    over = np.flatnonzero(texels > limits.max_cell_texels)
    if over.size:
        n = int(over[0])
        raise JobTooCostlyError(cell_too_costly(n, int(texels[n]), "at least", "one layer at least", limits))
    running = np.cumsum(texels)
    past = np.flatnonzero(running > limits.max_job_texels)
    if past.size:
        n = int(past[0])
        raise JobTooCostlyError(job_too_costly(n, len(cells), int(running[n]), "at least", limits))
    return int(running[-1])


def check_cell(technique, options, n: int, cell, bounds: np.ndarray | None, limits: AdmissionLimits, total: int):
    """The full check of view cell ``n`` (its technique's ``check``: for a part technique the layer
    plan the bake will use), after ``total`` texels of the job's earlier cells: (its texels, and
    whether they are complete), or the error that fails the cell: its plan has no answer
    (LayerPlanError, ViewCellError) or its texels pass ``limits.max_cell_texels`` (the message the
    request's 413 gave before issue 58).

    The check is given ``PLAN_BEYOND_LIMIT`` times what is left of the budgets: a cell a few times
    over its limits fails with its full estimate, one far beyond them after planning that many
    layers, not all of its own (a hostile cell costs a worker a bounded plan), with a lower bound."""
    budget = PLAN_BEYOND_LIMIT * max(min(limits.max_cell_texels, limits.max_job_texels - total), 1)
    try:
        cost = technique.check(cell, options, bounds, max_texels=budget)
    except (LayerPlanError, ViewCellError) as error:
        return None, f"{type(error).__name__}: view cell {n} ({cell.to_dict()}): {error}"
    if cost.texels > limits.max_cell_texels:
        about = "about" if cost.complete else "more than"
        return None, f"{JobTooCostlyError.__name__}: " + cell_too_costly(n, cost.texels, about, cost.describe(), limits)
    return cost, None


def admission_record(cells: int, bound: int) -> dict:
    """A job's ``planning`` record while it is admitted: its cells' full checks done of ``total``,
    the texels they found (``texels``), the next cell index to check (``next``), and the request's
    lower bound of the job's texels (``bound_texels``).  ``GET /v1/jobs/{id}`` shows it as ``admission``."""
    return {"phase": "admit", "done": 0, "total": cells, "next": 0, "texels": 0, "failed": 0, "bound_texels": bound}


def create_job(
    db: Database,
    tenant_id: str,
    scene: SceneRow,
    spec: JobSpec,
    limits: AdmissionLimits | None = None,
    requeue_after: float = 3600.0,
) -> JobRow:
    """Validate ``spec`` against ``scene`` and store the job and its cells, in O(cells) and without
    a plan.  Stored parameters hold every option as validated (the technique's defaults filled in,
    numbers and lists normalised), so equal requests store equal parameters (and share their
    bundles, :func:`farfield.service.jobs.cells.result_key`) and a job means the same thing if a default changes.

    A placement job (``spec.placement``) is stored by
    :func:`~farfield.service.placement.admission.create_placement_job` (``requeue_after``: its
    planning lease), within the tenant's quota of open placement jobs.

    Cost admission (``limits``; None: :meth:`AdmissionLimits.from_env`): a tenant whose queued and
    running cells would pass ``max_tenant_cells`` with this job's is refused with
    :class:`~farfield.core.errors.QuotaError` (429); a job whose cells' lower bound of texels
    passes the texel limits with :class:`~farfield.core.errors.JobTooCostlyError` (413,
    :func:`bound_cells`).  Nothing is stored for a refused job.  The count is read once before
    the bound (a cheap early refusal) and again, authoritatively, in the transaction that stores the
    cells, with the tenant's admissions serialised (:func:`reserve_tenant_work`), so two requests of
    one tenant at the same moment cannot both pass it.

    A job that passes is stored ``admitting`` (its ``planning`` record: :func:`admission_record`,
    its lease ``requeue_after`` seconds, after which the API's sweeper sends its admission again)
    with every cell ``queued``; the caller sends its admission task
    (:func:`farfield.service.jobs.admitting.admit_job` on a worker), which checks every cell and
    then sends the cells that passed."""
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
    if spec.grid is not None:  # arrays, not 10,000 objects
        ijk, cells = grid_cell_arrays(spec.grid)
        grids, stored = ijk.tolist(), cells.to_dicts()
    else:
        if not spec.viewcells:
            raise ViewCellError("'viewcells' is empty")
        if len(spec.viewcells) > MAX_CELLS:
            raise ViewCellError(f"{len(spec.viewcells)} view cells is over the limit of {MAX_CELLS}")
        cells = [viewcell_from_dict(cell) for cell in spec.viewcells]
        grids, stored = [None] * len(cells), [cell.to_dict() for cell in cells]
    bounds = part_bounds(scene, spec.objects) if technique.scope == "part" else None
    if len(cells) > limits.max_tenant_cells:  # it could never pass: not a 429 to retry
        raise JobTooCostlyError(
            f"the job's {len(cells):,} view cells are more than a tenant may have queued or running, {limits.max_tenant_cells:,} "
            "(FARFIELD_MAX_TENANT_CELLS): split it into smaller jobs, or raise the limit"
        )
    check_cells(open_tenant_cells(db, tenant_id), len(cells), limits)
    bound = bound_cells(technique, options, cells, bounds, limits)
    created = now()
    job = JobRow(
        id=uuid.uuid4().hex, tenant_id=tenant_id, scene_id=scene.id, job_type=technique.name, params=params,
        evaluate=spec.evaluate, state="admitting", created_at=created, planning=admission_record(len(cells), bound),
        lease_until=created + requeue_after, plan_attempts=0,
    )  # fmt: skip
    rows = new_cell_rows(job.id, grids, stored, created)
    with db.session() as s:
        # The quota counts cells, which are known exactly here: the reservation is the job's cells,
        # and it shrinks by itself as a worker's full check fails some (they leave "queued").
        reserve_tenant_work(s, tenant_id, len(cells), limits)
        s.add(job)
        s.flush()
        insert_cell_rows(s, rows)
    return job


# The columns new_cell_rows fills, in its tuples' order (the others take their defaults: NULL).
NEW_CELL_COLUMNS = ("id", "job_id", "index", "grid", "viewcell", "state", "attempts", "progress", "queued_at")


def new_cell_rows(job_id: str, grids: list, viewcells: list[dict], created: float) -> list[tuple]:
    """The rows of a new job's queued cells as tuples of :data:`NEW_CELL_COLUMNS`, their JSON
    columns encoded here as SQLAlchemy's ``JSON`` type writes them (``json.dumps``; None as ``null``)."""
    encode = json.JSONEncoder().encode
    ids = secrets.token_hex(16 * len(viewcells))  # 128 random bits a cell, as uuid4().hex has (122), in one call
    return [
        (ids[32 * n : 32 * n + 32], job_id, n, encode(grid), encode(cell), "queued", 0, 0.0, created)
        for n, (grid, cell) in enumerate(zip(grids, viewcells, strict=True))
    ]


def insert_cell_rows(session: Session, rows: list[tuple]) -> None:
    """Insert :func:`new_cell_rows` in one ``executemany`` of the driver, in the session's
    transaction.  SQLAlchemy's own insert (even Core's) processed each of 10,000 rows' parameters
    (JSON encoding, binding) for about two thirds of a 10,000-cell request; here the driver gets
    the values as they are stored (PostgreSQL casts the JSON text to the column's type)."""
    connection = session.connection()
    quote = connection.dialect.identifier_preparer.quote
    mark = "?" if connection.dialect.paramstyle == "qmark" else "%s"
    columns = ", ".join(quote(c) for c in NEW_CELL_COLUMNS)
    marks = ", ".join([mark] * len(NEW_CELL_COLUMNS))
    connection.exec_driver_sql(f"INSERT INTO {quote(CellRow.__tablename__)} ({columns}) VALUES ({marks})", rows)
