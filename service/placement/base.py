"""The placement-algorithm interface (:class:`Algorithm`) and what every algorithm shares.

A placement job (SQL ``job_type`` :data:`PLACEMENT_JOB`; its algorithm in
``params["placement"]["algorithm"]``, absent for a job stored before there were two) is planned,
baked and checked by :mod:`farfield.service.placement.rounds`, which asks the job's algorithm (the registry,
:data:`farfield.service.placement.ALGORITHMS`) for everything that differs between algorithms: the
request fields it reads, its admission (the job's stored params), its plan, the cells it makes and
how one is keyed and baked, its check of a baked round, its database index, and the documents the
API serves of that index (``/placement``, ``/lookup``, ``/clusters``).
"""

from __future__ import annotations

import json
import math
import uuid
from dataclasses import dataclass, field
from typing import Any

from farfield.core.errors import NotFoundError
from farfield.core.placement.hierarchy import PlacementError
from farfield.service.blobs import BlobStore
from farfield.service.db import CellRow, Database, JobRow, now

PLACEMENT_JOB = "placement"  # the job_type column of a placement job


@dataclass(frozen=True)
class Round:
    """What a plan or a check leaves to commit (:func:`farfield.service.placement.rounds._commit_round`): the
    planner state's key, the cells to add (dicts of index, viewcell and params; none: the job ends
    with ``index_key``, its database), how many impostors (or images) the placement holds, its
    summary, the round's number and the check rounds' records so far."""

    state_key: str
    cells: list[dict]
    impostors: int
    summary: dict | None
    round: int
    index_key: str | None
    rounds: list = field(default_factory=list)


class Algorithm:
    """A placement algorithm: subclasses fill in the class attributes and the methods that raise here.

    - request: :attr:`fields` (the ``placement`` object's fields only this algorithm reads, as
      ``name: (annotation, pydantic Field)``; the request schema, :class:`farfield.service.placement.schema.PlacementSpec`,
      is made of every algorithm's) and :attr:`help` (its line in the field ``algorithm``'s description);
    - admission: :meth:`params` (the job's stored params, or a PlacementError naming the problem);
    - planning: :meth:`plan` (on the worker: the planner state, the placement, its cells);
    - cells: :meth:`cell_inputs` (what keys a cell's bundle) and :meth:`bake_cell`;
    - rounds: :meth:`check` (a baked round: repair it, or write the database) and :meth:`too_many_cells`;
    - index: :attr:`index_kind`, :meth:`write_index`, :meth:`bundled_cells`;
    - documents: :meth:`read_index` (what the API keeps parsed), :meth:`placement_document`,
      :meth:`lookup`, :meth:`clusters`.
    """

    name: str
    help: str
    fields: dict[str, tuple[Any, Any]]
    index_kind: str
    noun: str = "impostors"  # what its cells are, in messages
    technique: str | None = None  # the one technique it bakes; None: any placeable (part) technique
    choice: str  # its option's text in the dashboard's algorithm select, after its name
    summary: str  # the sentence a job page shows of a job of it; "{technique}": the job's technique
    images: bool = False  # its placement document lists images on a solution grid (else impostors of CPVs)
    labels: dict[str, str] | None = None  # the dashboard's totals' labels it changes (key -> label)
    offline: str  # how `farfield place` places with it offline: "cost-model" or "solution-grid"

    def describe(self) -> dict:
        """``GET /v1/placement-algorithms``: what a client (the dashboard) knows of the algorithm, JSON-ready."""
        return {
            "name": self.name,
            "help": self.help,
            "technique": self.technique,
            "index_kind": self.index_kind,
            "noun": self.noun,
            "choice": self.choice,
            "summary": self.summary,
            "images": self.images,
            "labels": dict(self.labels) if self.labels else None,
            "fields": list(self.fields),
        }

    # --- admission ------------------------------------------------------------------------------

    def params(
        self, technique_name: str | None, given_options: dict, resolution, fov_deg, spec, model_triangles: int | None
    ) -> dict:
        """Validate a request (``spec``: the request's ``placement``); the job's stored params."""
        raise NotImplementedError

    # --- planning and rounds --------------------------------------------------------------------

    def plan(self, blobs: BlobStore, job: JobRow, scene, progress) -> tuple[str, dict, list[dict]]:
        """Plan the job on ``scene``: (its state's key, the placement document, the cells to bake)."""
        raise NotImplementedError

    def impostors(self, doc: dict) -> int:
        """How many impostors (or images) the placement document ``doc`` holds."""
        raise NotImplementedError

    def check(self, db: Database, blobs: BlobStore, job: JobRow, round_: int, rounds: list) -> Round:
        """Check the job's baked round ``round_ - 1`` (its planner state at ``job.planning["state_key"]``)."""
        raise NotImplementedError

    def too_many_cells(self, cells: int, limit: int) -> str:
        """The job's error when a round would pass ``limit`` cells."""
        raise NotImplementedError

    # --- its cells --------------------------------------------------------------------------------

    def cell_inputs(self, cell: CellRow) -> tuple[str, dict]:
        """(type, params) of :func:`farfield.service.jobs.cells.result_key` for one of its cells: what makes the
        bundle's bytes, so that equal impostors of another job are found, not baked again."""
        return f"placement/{cell.params['technique']}", dict(cell.params)

    def bake_cell(self, scene, cell: CellRow, progress):
        """The impostor of one of its cells (its own technique, objects and options in ``cell.params``)."""
        raise NotImplementedError

    # --- its database index and what the API serves of it ---------------------------------------

    def write_index(self, db: Database, blobs: BlobStore, job: JobRow, doc: dict, rounds: list) -> str:
        """Write the job's database index (``jobs/<id>/index.json``); returns its key."""
        raise NotImplementedError

    def bundled_cells(self, index: dict) -> set[int] | None:
        """The cells its database ships (``database.zip``); None: every baked cell."""
        return None

    def read_index(self, index: dict):
        """The lookup structure of a parsed index (kept parsed by :mod:`farfield.service.placement.documents`)."""
        raise NotImplementedError

    def placement_document(self, job: JobRow, index: dict) -> dict:
        """``GET /v1/jobs/{id}/placement``."""
        raise NotImplementedError

    def lookup(self, index: dict, found, eye, direction) -> tuple[dict, list[int]]:
        """``GET /v1/jobs/{id}/lookup`` of a view (position ``eye``, direction ``direction``; ``found``:
        :meth:`read_index`'s): the answer, and the indices of the cells whose records it lists as ``cells``."""
        raise NotImplementedError

    def clusters(self, db: Database, blobs: BlobStore, job: JobRow, index: dict) -> dict:
        """``GET /v1/jobs/{id}/clusters``: 404 unless the algorithm replaces clusters of objects."""
        raise NotFoundError(f"job {job.id!r} is a {self.name} placement: it has no clusters")


# --- what the algorithms share ---------------------------------------------------------------------


def finite(value, what: str) -> float:
    value = float(value)
    if not math.isfinite(value):
        raise PlacementError(f"{what} must be a finite number, got {value!r}")
    return value


def view_space(spec) -> tuple[list[float], list[float], list[float]]:
    """The view space's (lo, hi, span), checked."""
    lo = [finite(v, "view_space.lo") for v in spec.view_space.lo]
    hi = [finite(v, "view_space.hi") for v in spec.view_space.hi]
    inverted = [axis for axis, a, b in zip("xyz", lo, hi, strict=True) if b < a]
    if inverted:
        raise PlacementError(f"the view space is empty: hi < lo on axis {', '.join(inverted)} (lo {lo}, hi {hi})")
    span = [b - a for a, b in zip(lo, hi, strict=True)]
    if not all(math.isfinite(s) for s in span):
        raise PlacementError(f"the view space's size is not finite: lo {lo}, hi {hi}")
    return lo, hi, span


def state_key(job_id: str, round_: int) -> str:
    """Where a job keeps its planner state of round ``round_`` (a pickle)."""
    return f"jobs/{job_id}/planner-{round_}.pickle"


def index_key(job_id: str) -> str:
    return f"jobs/{job_id}/index.json"


def put_index(blobs: BlobStore, job_id: str, index: dict) -> str:
    """Store a placement's database index; strict JSON (engines read it)."""
    key = index_key(job_id)
    blobs.put_bytes(key, json.dumps(index, sort_keys=True, indent=1, allow_nan=False).encode())
    return key


def add_cells(session, job: JobRow, cells: list[dict]) -> list[str]:
    """Add ``cells`` (index, viewcell, params) to the job, queued; their ids."""
    made = []
    for entry in cells:
        cell = CellRow(
            id=uuid.uuid4().hex, job_id=job.id, index=int(entry["index"]), grid=None, viewcell=entry["viewcell"], params=entry["params"],
            state="queued", attempts=0, progress=0.0, queued_at=now(),
        )  # fmt: skip
        session.add(cell)
        made.append(cell.id)
    return made
