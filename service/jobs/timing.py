"""A job's time, broken down: admission, planning, the bake's stages summed over cells, checking, and the rest.

Nothing here is timed anew: every figure is one the service already records.

- ``admission_s``: the seconds the workers spent checking the cells of a job of view cells
  (:mod:`farfield.service.jobs.admitting` adds each delivery's to the job's ``planning`` record as
  ``seconds``);
- ``planning_s`` and ``checking_s``: a placement job's plan and check deliveries that committed a
  round (:mod:`farfield.service.placement.rounds` adds each one's seconds, claim to commit, to the
  ``planning`` record with the round it stores: ``PHASE_SECONDS``);
- ``cells_s``: the cells' wall seconds (``cells.seconds``: the last attempt, claim to outcome:
  loading the scene, baking, writing and publishing the bundle, evaluating it), summed;
- ``stages``: the bake's seconds per stage (each cell's ``stats.seconds``, from
  :class:`~farfield.core.stage_clock.StageClock`), summed over the cells that baked their bundle
  (a cell that found its bundle baked nothing); ``bake_s`` their total, ``evaluation_s`` the
  evaluations' (``stats.evaluation.seconds``);
- ``cells_busy_s``: how long at least one cell of the job was running (the union of the cells'
  ``[started_at, finished_at]`` of their last attempt, a running one's to now): ``cells_s /
  cells_busy_s`` is how many cells ran at once on average;
- ``wall_s``: from the request (``created_at``) to the job's end (or now, while it is open);
- ``overhead_s`` = ``wall_s`` − ``admission_s`` − ``planning_s`` − ``checking_s`` − ``cells_busy_s``
  (at least 0): the time nothing of the job was being worked on: messages waiting in the queues,
  the sweeper, the database writes between phases, earlier attempts of retried cells.
"""

from __future__ import annotations

import numpy as np

from farfield.service.db import CellRow, JobRow, now


def busy_seconds(intervals: list[tuple[float, float]]) -> float:
    """The length of the union of ``(start, end)`` intervals.

    >>> busy_seconds([(0.0, 2.0), (1.0, 3.0), (5.0, 6.0)])
    4.0
    """
    if not intervals:
        return 0.0
    spans = np.asarray(sorted(intervals), dtype=np.float64)
    # An interval (by start) adds what it reaches past every earlier one's end.
    before = np.concatenate(([-np.inf], np.maximum.accumulate(spans[:-1, 1])))
    return float(np.sum(np.maximum(spans[:, 1] - np.maximum(spans[:, 0], before), 0.0)))


def job_timing(job: JobRow, cells: list[CellRow], placement: bool) -> dict:
    """The breakdown of ``job``'s time (see the module docstring) from its row and its cells."""
    record = job.planning or {}
    stages: dict[str, float] = {}
    evaluation = 0.0
    for cell in cells:
        stats = cell.stats or {}
        for name, seconds in (stats.get("seconds") or {}).items():
            if name != "total":
                stages[name] = stages.get(name, 0.0) + float(seconds)
        evaluation += float((stats.get("evaluation") or {}).get("seconds", 0.0))
    at = now()
    # A running cell's span reaches now; a cell that never ran (or was queued again) has none.
    spans = [
        (c.started_at, c.finished_at or at)
        for c in cells
        if c.started_at is not None and (c.finished_at or c.state == "running")
    ]
    busy = busy_seconds(spans)
    admission = 0.0 if placement else float(record.get("seconds", 0.0))
    planning = float(record.get("planning_s", 0.0)) if placement else 0.0
    checking = float(record.get("checking_s", 0.0)) if placement else 0.0
    wall = (job.finished_at or at) - job.created_at
    return {
        "wall_s": wall,
        "admission_s": admission,
        "planning_s": planning,
        "checking_s": checking,
        "cells": len([c for c in cells if c.seconds is not None]),
        "cells_s": float(sum(c.seconds for c in cells if c.seconds is not None)),
        "cells_busy_s": busy,
        "stages": stages,
        "bake_s": float(sum(stages.values())),
        "evaluation_s": evaluation,
        "overhead_s": max(wall - admission - planning - checking - busy, 0.0),
    }
