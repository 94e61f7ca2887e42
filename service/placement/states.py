"""The planner states a placement job keeps between its rounds (blobs under ``jobs/<id>/``), and their deletion.

Only the state the next check needs is kept: a committed round deletes the older rounds' states, and
a job that ends deletes them all (:func:`drop_ended_planning`; a job failed while baking keeps its
current one, which ``retry`` needs to check the round again).
"""

from __future__ import annotations

from farfield.service.blobs import BlobStore
from farfield.service.db import Database, JobRow
from farfield.service.placement.base import PLACEMENT_JOB


def planner_state_keys(blobs: BlobStore, job_id: str) -> list[str]:
    """The keys of the job's stored planner states (``jobs/<id>/planner-<round>.pickle``, a primitive-budget
    job's ``planner-grid.json``)."""
    return [
        f"jobs/{job_id}/{name}"
        for name in blobs.list_files(f"jobs/{job_id}")
        if name.startswith("planner-") and name.endswith((".pickle", ".json"))
    ]


def drop_planner_states(blobs: BlobStore, job_id: str, keep: str | None = None) -> list[str]:
    """Delete the job's planner states but ``keep``; returns the keys deleted."""
    dropped = [key for key in planner_state_keys(blobs, job_id) if key != keep]
    for key in dropped:
        blobs.delete_prefix(key)
    return dropped


def drop_ended_planning(db: Database, blobs: BlobStore, job_id: str) -> list[str]:
    """When the placement job has ended (done, failed, cancelled), delete its planner states: all of
    them, except that a job that failed while baking keeps its current one (``retry`` bakes the
    failed cells again, and the check that follows loads it).  Returns the keys deleted."""
    with db.session() as s:
        job = s.get(JobRow, job_id)
    if job is None or job.job_type != PLACEMENT_JOB or job.state not in ("done", "failed", "cancelled"):
        return []
    planning = job.planning or {}
    keep = planning.get("state_key") if job.state == "failed" and planning.get("phase") == "bake" else None
    return drop_planner_states(blobs, job_id, keep)
