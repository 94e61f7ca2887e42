"""Failure classes of a cell (issue 22): transient, bad input and internal failures.

The cells live in a real SQLite database and a local blob store.  Cells are run the way a worker
runs them: ``farfield.service.jobs.runner.run_cell`` in a loop (as the task does, without its countdowns),
or the Celery task itself executed eagerly (``apply``: each retry runs at once, with the message's
retry count, instead of after its countdown).  Only the bake is replaced where a test needs it to
fail in a given way; the classification, counting and retry limits are the real ones.
"""

from __future__ import annotations

import io
import logging
import os
import sqlite3

import click
import pytest
import trimesh
from celery.exceptions import SoftTimeLimitExceeded
from click.testing import CliRunner
from fastapi.testclient import TestClient
from sqlalchemy import event

import farfield.service.jobs.runner as cell_runner
import farfield.workers.tasks as tasks
from farfield.api.app import create_app
from farfield.cli.main import FarfieldGroup
from farfield.core.errors import ErrorKind, InternalError, LayerPlanError, RenderBackendError
from farfield.service.blobs import LocalBlobStore
from farfield.service.db import CellRow, Database, JobRow
from farfield.service.jobs.admission import create_job
from farfield.service.jobs.admitting import admit_job
from farfield.service.jobs.runner import RetryCell, run_cell
from farfield.service.jobs.schema import JobSpec
from farfield.service.keys import tenant_named
from farfield.service.scenes import ingest_scene
from farfield.service.settings import Settings

MAX_ATTEMPTS = 3
CELL = {"kind": "box", "lo": [-4.0, -0.5, -0.5], "hi": [-3.0, 0.5, 0.5]}


class Stack:
    """A database, blob store and one queued cell of a job over a 1 m box."""

    def __init__(self, root, database_url: str | None = None) -> None:
        self.root = root
        self.settings = Settings.from_env({"FARFIELD_HOME": str(root), "FARFIELD_MAX_ATTEMPTS": str(MAX_ATTEMPTS)})
        self.db = Database(database_url or self.settings.database_url)
        self.db.migrate()
        self.blobs = LocalBlobStore(self.settings.blob_dir)
        tenant = tenant_named(self.db, "failures")
        data = io.BytesIO(trimesh.creation.box(extents=(1.0, 1.0, 1.0)).export(file_type="stl"))
        scene = ingest_scene(self.db, self.blobs, tenant.id, "crate.stl", data, limit=2**20)
        self.job_id = create_job(
            self.db, tenant.id, scene, JobSpec(scene_id=scene.id, viewcells=[CELL], resolution=32)
        ).id
        # Its admission, as a worker runs it: the job is queued with its cell.
        assert admit_job(self.db, self.blobs, self.job_id, "admission@here", MAX_ATTEMPTS)[0] == "queued"
        with self.db.session() as s:
            self.cell_id = s.query(CellRow.id).filter(CellRow.job_id == self.job_id).scalar()

    def cell(self) -> CellRow:
        with self.db.session() as s:
            return s.get(CellRow, self.cell_id)

    def job_state(self) -> str:
        with self.db.session() as s:
            return s.get(JobRow, self.job_id).state


@pytest.fixture
def stack(tmp_path):
    made = Stack(tmp_path)
    yield made
    made.db.dispose()


def bake_raising(error: BaseException):
    calls = []

    def bake(*_args, **_kwargs):
        calls.append(1)
        raise error

    bake.calls = calls
    return bake


def run_like_the_task(stack: Stack, limit: int = 10) -> tuple[str, list[float]]:
    """run_cell again after each RetryCell, as the worker task does (without waiting): its end state and the countdowns."""
    countdowns = []
    for _ in range(limit):
        try:
            return run_cell(stack.db, stack.blobs, stack.cell_id, MAX_ATTEMPTS, worker="test"), countdowns
        except RetryCell as retry:
            countdowns.append(retry.countdown)
    raise AssertionError(f"still retried after {limit} runs: {countdowns}")


# 1. Internal errors: retried up to the attempt limit, traceback logged, then failed as internal.


@pytest.mark.parametrize(
    "error", [ZeroDivisionError("division by zero"), InternalError("7 voxels left uncovered by the simplified mesh")]
)
@pytest.mark.slow
def test_an_internal_error_fails_the_cell_after_the_attempt_limit(stack, monkeypatch, caplog, error):
    bake = bake_raising(error)
    monkeypatch.setattr(cell_runner, "bake_cell", bake)
    with caplog.at_level(logging.ERROR, logger="farfield.cells"):
        state, countdowns = run_like_the_task(stack)
    assert state == "failed" and countdowns == [2.0, 4.0]  # backoff between the 3 attempts
    cell = stack.cell()
    assert cell.state == "failed" and cell.attempts == MAX_ATTEMPTS and len(bake.calls) == MAX_ATTEMPTS
    assert cell.error == f"internal error: {type(error).__name__}: {error}"
    assert stack.job_state() == "failed"
    tracebacks = [r for r in caplog.records if r.exc_info and r.exc_info[1] is error]
    assert len(tracebacks) == MAX_ATTEMPTS and "Traceback" in caplog.text
    # A further delivery of the message changes nothing: the cell is not retried forever.
    assert run_cell(stack.db, stack.blobs, stack.cell_id, MAX_ATTEMPTS) == "skipped"
    assert stack.cell().attempts == MAX_ATTEMPTS and len(bake.calls) == MAX_ATTEMPTS


@pytest.mark.slow
def test_a_transient_error_is_retried_with_backoff_then_failed_without_the_internal_label(stack, monkeypatch, caplog):
    monkeypatch.setattr(cell_runner, "bake_cell", bake_raising(ConnectionResetError("blob store went away")))
    with caplog.at_level(logging.WARNING, logger="farfield.cells"):
        state, countdowns = run_like_the_task(stack)
    cell = stack.cell()
    assert state == "failed" and countdowns == [2.0, 4.0] and cell.attempts == MAX_ATTEMPTS
    assert cell.error == "ConnectionResetError: blob store went away"
    assert "transient failure" in caplog.text and not any(r.exc_info for r in caplog.records)


# 3. Bad input fails at once; an internal error is never a 4xx.


def _wrapped_time_limit() -> RenderBackendError:
    """What moderngl's context creation made of the soft time limit striking inside it."""
    try:
        try:
            raise SoftTimeLimitExceeded()
        except SoftTimeLimitExceeded as limit:
            raise RenderBackendError(f"no usable EGL OpenGL 3.3 context: {limit!r}") from limit
    except RenderBackendError as error:
        return error


@pytest.mark.slow
def test_the_time_limit_wrapped_by_a_library_still_fails_the_cell_once(stack, monkeypatch):
    """The soft time limit striking while the GL context is created came back as a RenderBackendError
    (transient): the cell past its limit was attempted three times (tests/test_admission.py's time
    limit test, failed with attempts 3).  An error raised while handling the limit is the limit."""
    monkeypatch.setattr(cell_runner, "bake_cell", bake_raising(_wrapped_time_limit()))
    state, countdowns = run_like_the_task(stack)
    cell = stack.cell()
    assert state == "failed" and countdowns == [] and cell.attempts == 1
    assert cell.error.startswith("CellLimitError: the cell ran past the worker's time limit"), cell.error


@pytest.mark.slow
def test_bad_input_fails_the_cell_at_once(stack, monkeypatch):
    monkeypatch.setattr(
        cell_runner, "bake_cell", bake_raising(LayerPlanError("the part left no visible texel in any layer"))
    )
    state, countdowns = run_like_the_task(stack)
    cell = stack.cell()
    assert state == "failed" and countdowns == [] and cell.attempts == 1
    assert cell.error == "LayerPlanError: the part left no visible texel in any layer"
    assert stack.job_state() == "failed"


def test_the_failure_classes():
    import redis.exceptions
    import sqlalchemy.exc

    assert (
        cell_runner.failure_class(
            sqlalchemy.exc.OperationalError("SELECT 1", {}, sqlite3.OperationalError("unable to open database file"))
        )
        == "transient"
    )
    assert cell_runner.failure_class(redis.exceptions.ConnectionError("refused")) == "transient"
    assert cell_runner.failure_class(IsADirectoryError("scenes/x")) == "transient"
    assert (
        cell_runner.failure_class(
            sqlalchemy.exc.ProgrammingError("SELECT nonsense", {}, sqlite3.ProgrammingError("bad"))
        )
        == "internal"
    )
    assert cell_runner.failure_class(KeyError("objects")) == "internal"
    assert cell_runner.failure_class(InternalError("x")) == "internal"
    assert cell_runner.failure_class(LayerPlanError("x")) == "bad input"


def test_an_internal_error_is_reported_as_500_and_exit_code_1(tmp_path):
    assert ErrorKind.INTERNAL.http_status == 500 and InternalError("x").kind is ErrorKind.INTERNAL
    bad_input_codes = {ErrorKind.BAD_INPUT.exit_code, ErrorKind.MISSING.exit_code}
    assert ErrorKind.INTERNAL.exit_code not in bad_input_codes and ErrorKind.INTERNAL.exit_code != 0
    # The API: the one FarfieldError handler gives the kind's status.
    settings = Settings.from_env({"FARFIELD_HOME": str(tmp_path), "REDIS_URL": "redis://127.0.0.1:1/0"})
    app = create_app(settings)

    def broken():
        raise InternalError("7 voxels left uncovered by the simplified mesh")

    app.add_api_route("/broken", broken)
    response = TestClient(app).get("/broken")
    assert response.status_code == 500 and response.json()["error"] == "InternalError"

    # The CLI: exit code 1 and a line that says internal error (not the bad-input 2).
    @click.group(cls=FarfieldGroup)
    def group() -> None:
        pass

    @group.command()
    def boom() -> None:
        raise InternalError("7 voxels left uncovered by the simplified mesh")

    result = CliRunner().invoke(group, ["boom"])
    assert result.exit_code == 1 and "farfield: internal error" in result.output


# 2. Failures in claim_cell's database call: retried with backoff, counted in the message's retries, bounded.


def _task_stack(tmp_path, fail_connects: int | None):
    """A stack whose task process reaches the database through a link that is missing (sqlite cannot
    open the file: OperationalError) until ``fail_connects`` connections have failed (None: never back)."""
    real = tmp_path / "real"
    real.mkdir()
    stack = Stack(real)
    link = tmp_path / "link"
    task_db = Database(f"sqlite:///{link / 'farfield.db'}")
    link.rmdir()  # Database made the folder; without it sqlite cannot open the file
    failed = []

    @event.listens_for(task_db.engine, "do_connect")
    def _connect(*_args):
        if not link.exists():
            if fail_connects is not None and len(failed) >= fail_connects:
                link.symlink_to(real, target_is_directory=True)  # the database is back
            else:
                failed.append(1)

    tasks._STATE.update(pid=os.getpid(), settings=stack.settings, db=task_db, blobs=stack.blobs)
    return stack, failed


@pytest.fixture
def task_state():
    saved = dict(tasks._STATE)
    yield
    tasks._STATE.clear()
    tasks._STATE.update(saved)


def test_the_task_has_a_finite_retry_limit_from_the_attempt_limit():
    assert tasks.bake_cell.max_retries is not None
    assert tasks.bake_cell.max_retries == tasks.max_retries(Settings.from_env().max_attempts)
    assert tasks.max_retries(MAX_ATTEMPTS) == 10 * MAX_ATTEMPTS


@pytest.mark.slow
def test_a_claim_that_cannot_reach_the_database_is_retried_with_backoff_and_counted(
    tmp_path, monkeypatch, caplog, task_state
):
    stack, failed = _task_stack(tmp_path, fail_connects=2)
    seen_retries = []

    def bake(*_args, **_kwargs):
        seen_retries.append(tasks.bake_cell.request.retries)
        raise LayerPlanError("no texel")  # fails the cell at once: shows the claim went through

    monkeypatch.setattr(cell_runner, "bake_cell", bake)
    with caplog.at_level(logging.WARNING, logger="farfield.worker"):
        result = tasks.bake_cell.apply(args=[stack.cell_id])
    assert result.get() == "failed" and len(failed) == 2
    assert seen_retries == [2]  # the third delivery, after two that could not claim
    waits = [r.getMessage() for r in caplog.records if " delivery " in r.getMessage()]
    assert (
        len(waits) == 2
        and "unable to open database file" in waits[0]
        and "retried in 2 s" in waits[0]
        and "retried in 4 s" in waits[1]
    )
    cell = stack.cell()
    assert cell.state == "failed" and cell.attempts == 1 and cell.error == "LayerPlanError: no texel"


@pytest.mark.slow
def test_a_task_never_retries_past_its_limit(tmp_path, caplog, task_state):
    stack, failed = _task_stack(tmp_path, fail_connects=None)  # the database never comes back
    with caplog.at_level(logging.WARNING, logger="farfield.worker"):
        result = tasks.bake_cell.apply(args=[stack.cell_id])
    limit = tasks.max_retries(MAX_ATTEMPTS)
    assert result.get() == "unrecorded"
    deliveries = [r for r in caplog.records if " delivery " in r.getMessage()]
    assert len(deliveries) == limit + 1 and "giving up" in deliveries[-1].getMessage()
    assert "retried in 60 s" in deliveries[-2].getMessage()  # the backoff's cap
    assert stack.cell().state == "queued" and stack.cell().attempts == 0  # the database never saw it


@pytest.mark.slow
def test_a_bug_in_claim_cell_fails_the_cell_after_the_attempt_limit(tmp_path, caplog, task_state):
    """A cell whose job row is gone (a broken invariant) makes claim_cell raise AttributeError."""
    stack, _ = _task_stack(tmp_path, fail_connects=0)
    stack.db.dispose()
    connection = sqlite3.connect(tmp_path / "real" / "farfield.db")  # foreign keys are off by default
    with connection:
        connection.execute("DELETE FROM jobs WHERE id = ?", (stack.job_id,))
    connection.close()
    with caplog.at_level(logging.WARNING, logger="farfield.worker"):
        result = tasks.bake_cell.apply(args=[stack.cell_id])
    assert result.get() == "failed"
    deliveries = [r for r in caplog.records if " delivery " in r.getMessage()]
    assert len(deliveries) == MAX_ATTEMPTS and all(r.exc_info for r in deliveries)
    cell = stack.cell()
    assert cell.state == "failed" and cell.error.startswith("internal error: AttributeError: ")
    assert f"after {MAX_ATTEMPTS} deliveries" in cell.error
