"""A job's time, broken down (``timing`` of its record, :mod:`farfield.service.jobs.timing`), through a
real service: ``farfield submit --wait`` prints it, ``farfield jobs ID`` shows it, ``--json`` carries it,
and its figures are the cells' own, summed."""

from __future__ import annotations

import json

import pytest
from service_harness import BUNNY, assert_timing_adds_up, service_client, service_on_sqlite  # noqa: F401 - the service fixtures

pytestmark = pytest.mark.skipif(not BUNNY.exists(), reason="needs ../shared/scenes")

GRID = "-0.6,0.05,-0.05,-0.4,0.15,0.05,2,1,1"  # two cells of the bunny, at 128 px: a few seconds


def test_submit_wait_prints_the_breakdown_and_the_record_adds_up(service, client):
    auth = ("--url", service.url, "--key", service.env["FARFIELD_ADMIN_KEY"])
    done = service.cli("submit", str(BUNNY), "--grid", GRID, "--resolution", "128", "--wait", *auth)
    assert done.returncode == 0, done.stderr
    job_id = done.stdout.split()[1].rstrip(":")
    job = client.get(f"/v1/jobs/{job_id}").json()
    assert job["state"] == "done" and all(c["stats"]["baked"] for c in job["cells"])
    timing = assert_timing_adds_up(job)
    # A layered bake's stages (core.techniques.layered), each summed over the two cells.
    assert set(timing["stages"]) == {"plan", "record", "cull", "quads", "atlas"} and timing["stages"]["record"] > 0
    assert timing["cells"] == 2 and timing["admission_s"] > 0 and timing["evaluation_s"] > 0
    assert timing["planning_s"] == 0 and timing["checking_s"] == 0  # a grid job is neither planned nor checked
    lines = done.stdout.splitlines()
    table = lines[lines.index(next(line for line in lines if line.startswith("time "))) :]
    labels = [line[2:24].strip() for line in table[1:]]
    stages = [f"bake: {name}" for name in timing["stages"]]
    assert labels == ["wall", "admission", "cells (2, summed)", *stages, "evaluation", "overhead"], table
    shown = {label: float(line[24:34]) for label, line in zip(labels, table[1:], strict=True)}
    assert shown["bake: record"] == pytest.approx(timing["stages"]["record"], abs=5e-4)
    assert shown["cells (2, summed)"] == pytest.approx(timing["cells_s"], abs=5e-4)
    shown_by_jobs = service.cli("jobs", job_id, *auth)
    assert (
        shown_by_jobs.returncode == 0 and "bake: record" in shown_by_jobs.stdout and "overhead" in shown_by_jobs.stdout
    )

    # The same job again finds every bundle: its cells take time but bake nothing, so no stage.
    again = service.cli("submit", job["scene_id"], "--grid", GRID, "--resolution", "128", "--wait", "--json", *auth)
    assert again.returncode == 0, again.stderr
    record = json.loads(again.stdout)
    assert record["timing"]["stages"] == {} and record["timing"]["bake_s"] == 0 and record["timing"]["cells"] == 2
    found = client.get(f"/v1/jobs/{record['id']}").json()
    assert not any(c["stats"]["baked"] for c in found["cells"])
    assert_timing_adds_up(found)
