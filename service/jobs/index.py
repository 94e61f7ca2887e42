"""A job's impostor database index (``jobs/<id>/index.json``) and the lookup from a viewpoint to the cells that serve it.

The worker that ends a job of view cells writes its index (:func:`write_index`): every cell's view
cell, state and bundle key, and its neighbours on the grid (what a runtime prefetches).  A
placement job's index is its algorithm's (:mod:`farfield.service.placement`), and so is its answer to a
lookup (:func:`lookup_view`) and the cells its ``database.zip`` ships (:func:`bundled_cells`).
"""

from __future__ import annotations

import json

import numpy as np

from farfield.core.errors import ViewCellError
from farfield.core.impostor.database import database_index
from farfield.core.viewcells import viewcell_from_dict
from farfield.service.blobs import BlobStore
from farfield.service.db import CellRow, Database, JobRow, job_cells
from farfield.service.jobs.records import CellView, cell_record, cell_records, cell_views
from farfield.service.placement import INDEX_KINDS, job_algorithm
from farfield.service.placement.documents import placement_lookup


def index_document(job: JobRow, cells: list[CellRow] | list[CellView]) -> dict:
    """The impostor database index of a job (:func:`farfield.core.impostor.database.database_index`)."""
    entries = [
        {"index": c.index, "grid": c.grid, "viewcell": c.viewcell, "state": c.state, "bundle": f"cells/{c.index:05d}/" if c.result_key else None}
        for c in cells
    ]  # fmt: skip
    return database_index(job.job_type, job.params, entries, job=job.id, scene=job.scene_id)


def write_index(db: Database, blobs: BlobStore, job_id: str, final_state: str) -> str:
    """Write the job's impostor database index (as it ends in ``final_state``); returns its key."""
    with db.reading() as s:
        job = s.get(JobRow, job_id)
    job.state = final_state  # the state the index describes; the row itself changes after the write
    key = f"jobs/{job_id}/index.json"
    blobs.put_bytes(key, json.dumps(index_document(job, cell_views(db, job_id)), sort_keys=True, indent=1).encode())
    return key


def lookup(cells: list[CellRow], point) -> list[CellRow]:
    """The cells whose view cell contains ``point`` (the impostors that serve that viewpoint)."""
    p = np.asarray(point, dtype=np.float64).reshape(1, 3)
    return [c for c in cells if bool(viewcell_from_dict(c.viewcell).contains(p, tol=1e-9)[0])]


def lookup_view(db: Database, blobs: BlobStore, job: JobRow, point, direction) -> list[dict] | dict:
    """``GET /v1/jobs/{id}/lookup``: a job of view cells answers with the records of the cells whose
    view cell holds ``point``; a placement job with its algorithm's answer for the view (``point``
    and ``direction``, which it needs) plus ``cells``, the records of the cells it names
    (:meth:`~farfield.service.placement.base.Algorithm.lookup`); a frame-time placement planned
    with visibility answers its region's potentially visible set too (``pvs``,
    :meth:`~farfield.core.placement.database.PlacementLookup.pvs_answer`)."""
    algorithm = job_algorithm(job)
    if algorithm is None:
        return [cell_record(cell) for cell in lookup(job_cells(db, job.id), point)]
    missing = [name for name, value in zip(("dx", "dy", "dz"), direction, strict=True) if value is None]
    if missing:
        raise ViewCellError(
            f"a placement job's lookup needs the view direction dx, dy, dz as well as the position; missing: {', '.join(missing)}"
        )
    answer, cells = placement_lookup(blobs, job, tuple(point), tuple(direction))
    return {**answer, "cells": cell_records(db, job.id, cells)}


def bundled_cells(index: bytes) -> set[int] | None:
    """The cells a job's ``database.zip`` ships, by its index: those a placement algorithm's index
    gives a bundle (:meth:`~farfield.service.placement.base.Algorithm.bundled_cells`); None for any
    other database (every baked cell)."""
    doc = json.loads(index)
    algorithm = INDEX_KINDS.get(doc.get("kind"))
    return None if algorithm is None else algorithm.bundled_cells(doc)
