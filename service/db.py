"""The job database: tenants, API keys, scenes, jobs and cells (SQLAlchemy; SQLite or PostgreSQL).

The job state machine lives here, not in Celery results (see :mod:`farfield.service.jobs`).  The schema is
made by Alembic migrations (``service/migrations``), run by :func:`migrate`; tables are never
created behind Alembic's back.  Times are float seconds since the epoch.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from pathlib import Path

from sqlalchemy import (
    JSON,
    Boolean,
    Float,
    ForeignKey,
    Index,
    Integer,
    String,
    Text,
    create_engine,
    event,
    select,
    true,
)
from sqlalchemy.engine import Engine
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column, sessionmaker

MIGRATIONS = Path(__file__).resolve().parent / "migrations"

CELL_STATES = ("queued", "running", "done", "failed", "cancelled")
CELL_FINAL = ("done", "failed", "cancelled")
JOB_STATES = ("admitting", "queued", "placing", "running", "done", "failed", "cancelled")
# A job of view cells is ``admitting`` while a worker checks its cells' full plans before any is
# baked (service.jobs.admitting).  A placement job is ``placing`` while a worker plans it and while
# it checks (and repairs) the baked impostors; its other states are a grid job's (service.placement).
OPEN_JOB_STATES = ("admitting", "queued", "placing", "running")


def now() -> float:
    return time.time()


class Base(DeclarativeBase):
    pass


class Tenant(Base):
    __tablename__ = "tenants"
    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    name: Mapped[str] = mapped_column(String(200), unique=True)
    created_at: Mapped[float] = mapped_column(Float, default=now)


class ApiKey(Base):
    __tablename__ = "api_keys"
    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    tenant_id: Mapped[str] = mapped_column(ForeignKey("tenants.id", ondelete="CASCADE"), index=True)
    prefix: Mapped[str] = mapped_column(String(32), unique=True)  # shown in listings; looks the key up
    digest: Mapped[str] = mapped_column(String(64))  # sha256 of the whole key; the key itself is never stored
    created_at: Mapped[float] = mapped_column(Float, default=now)
    revoked_at: Mapped[float | None] = mapped_column(Float, nullable=True)


class SceneRow(Base):
    __tablename__ = "scenes"
    __table_args__ = (Index("ix_scenes_tenant_created", "tenant_id", "created_at"),)  # listings: newest first
    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    tenant_id: Mapped[str] = mapped_column(ForeignKey("tenants.id", ondelete="CASCADE"), index=True)
    name: Mapped[str] = mapped_column(
        String(500)
    )  # path-safe (service.scenes.safe_file_name): the blob key's last part
    original_name: Mapped[str] = mapped_column(
        String(1024), default=""
    )  # as uploaded, bounded; metadata only, never in a path
    extension: Mapped[str] = mapped_column(String(16))
    blob_key: Mapped[str] = mapped_column(String(500))
    size_bytes: Mapped[int] = mapped_column(Integer)
    content_hash: Mapped[str] = mapped_column(String(64))
    triangles: Mapped[int] = mapped_column(Integer)
    bounds: Mapped[list] = mapped_column(JSON)
    object_count: Mapped[int] = mapped_column(Integer, default=0)
    # core Scene.summary()["objects"]: megabytes for a scene of 10^5 objects, so deferred (never loaded
    # by a listing or a worker's row; service.scenes.scene_objects pages it in SQL).
    objects: Mapped[list] = mapped_column(JSON, deferred=True)
    created_at: Mapped[float] = mapped_column(Float, default=now)
    # The loader's ``sides`` option (farfield.core.sidedness): "one" or "both", the sidedness of the
    # objects of a format that states none (OBJ, PLY, STL); a worker loads the file with it again.
    sides: Mapped[str] = mapped_column(String(8), default="one")


class JobRow(Base):
    __tablename__ = "jobs"
    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    tenant_id: Mapped[str] = mapped_column(ForeignKey("tenants.id", ondelete="CASCADE"), index=True)
    scene_id: Mapped[str] = mapped_column(ForeignKey("scenes.id"), index=True)
    job_type: Mapped[str] = mapped_column(String(32))
    params: Mapped[dict] = mapped_column(JSON)  # resolution, fov_deg, objects, options
    state: Mapped[str] = mapped_column(String(16), default="queued", index=True)
    error: Mapped[str | None] = mapped_column(Text, nullable=True)
    index_key: Mapped[str | None] = mapped_column(String(500), nullable=True)  # the impostor database index
    # Evaluate each baked cell against the real geometry (part-scope techniques; service.jobs.runner).
    evaluate: Mapped[bool] = mapped_column(Boolean, default=True, server_default=true())
    created_at: Mapped[float] = mapped_column(Float, default=now)
    started_at: Mapped[float | None] = mapped_column(Float, nullable=True)
    finished_at: Mapped[float | None] = mapped_column(Float, nullable=True)
    # A placement job's planning (service.placement): its progress record (phase, step, done,
    # total, round, rounds), which worker holds it and until when (a lease its heartbeat renews; the
    # API's sweeper sends an expired one's task again), and the attempts of the current phase.
    planning: Mapped[dict | None] = mapped_column(JSON, nullable=True)
    plan_worker: Mapped[str | None] = mapped_column(String(200), nullable=True)
    lease_until: Mapped[float | None] = mapped_column(Float, nullable=True, index=True)
    plan_attempts: Mapped[int] = mapped_column(Integer, default=0, server_default="0")


class CellRow(Base):
    __tablename__ = "cells"
    # A job's open cells (queued or running) counted after each cell: the index entries alone
    # (migration 0009), not every row of the job.
    __table_args__ = (Index("ix_cells_job_state", "job_id", "state"),)
    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    job_id: Mapped[str] = mapped_column(ForeignKey("jobs.id", ondelete="CASCADE"), index=True)
    index: Mapped[int] = mapped_column(Integer)
    grid: Mapped[list | None] = mapped_column(JSON, nullable=True)  # (i, j, k) in a grid job
    viewcell: Mapped[dict] = mapped_column(JSON)  # core BoxCell/ShaftCell.to_dict()
    # A placement job's cell carries its own impostor: technique, objects, resolution, fov_deg,
    # options, cluster_triangles (None: the job's params, one technique for every cell).
    params: Mapped[dict | None] = mapped_column(JSON, nullable=True)
    state: Mapped[str] = mapped_column(String(16), default="queued", index=True)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    worker: Mapped[str | None] = mapped_column(String(200), nullable=True)  # who ran the last attempt
    error: Mapped[str | None] = mapped_column(Text, nullable=True)
    result_key: Mapped[str | None] = mapped_column(String(500), nullable=True)
    stats: Mapped[dict | None] = mapped_column(JSON, nullable=True)
    progress: Mapped[float] = mapped_column(Float, default=0.0)  # 0..1 within the running attempt
    queued_at: Mapped[float | None] = mapped_column(Float, nullable=True)  # last sent to the queue
    started_at: Mapped[float | None] = mapped_column(Float, nullable=True)
    finished_at: Mapped[float | None] = mapped_column(Float, nullable=True)
    seconds: Mapped[float | None] = mapped_column(Float, nullable=True)
    # The running attempt's lease (service.jobs.leases): its token, checked by every write of the
    # attempt (a result under a lost lease is discarded), and until when its worker's heartbeat holds it.
    lease_token: Mapped[str | None] = mapped_column(String(32), nullable=True)
    lease_until: Mapped[float | None] = mapped_column(Float, nullable=True, index=True)
    # Texels its admission's full check planned (migration 0010); the queue it is sent to is chosen
    # from it (service.pools). None: not planned before it was sent (a placement job's cell).
    texels: Mapped[float | None] = mapped_column(Float, nullable=True)


class WorkerRow(Base):
    """A Celery worker node (``name@host``) as its heartbeat last reported it (service.jobs.leases)."""

    __tablename__ = "workers"
    name: Mapped[str] = mapped_column(String(200), primary_key=True)
    host: Mapped[str] = mapped_column(String(200))
    pid: Mapped[int] = mapped_column(Integer)
    kind: Mapped[str] = mapped_column(String(8))  # "gpu" or "cpu" (a software renderer such as llvmpipe)
    renderer: Mapped[str | None] = mapped_column(String(500), nullable=True)  # GL_RENDERER; None until known
    concurrency: Mapped[int] = mapped_column(Integer)
    started_at: Mapped[float] = mapped_column(Float)
    heartbeat_at: Mapped[float] = mapped_column(Float)
    queues: Mapped[str | None] = mapped_column(
        String(200), nullable=True
    )  # consumed now, comma-separated (service.pools)


def _sqlite_pragmas(dbapi_connection, _record) -> None:
    # pysqlite's own transaction handling is switched off (it begins lazily, before the first
    # write): every transaction begins with BEGIN IMMEDIATE instead (_sqlite_begin), so a
    # read-then-write such as claiming a cell is atomic, as SELECT ... FOR UPDATE makes it on
    # PostgreSQL.  SQLAlchemy's documented recipe for serializable SQLite transactions.
    dbapi_connection.isolation_level = None
    cursor = dbapi_connection.cursor()
    cursor.execute("PRAGMA journal_mode=WAL")  # readers (the API) never block the writer (a worker)
    # WAL's NORMAL syncs at checkpoints, not at every commit: a commit survives a crash of any
    # process, and the database is never corrupted, but a power loss may take back the last commits
    # (as the embedded Redis's append-only file, synced every second, may lose its last second).
    # What that can take back the service already recovers from: a cell shown running again has its
    # lease expire and runs again (its bundle's key is its inputs'), a queued one is sent again.
    # FULL's fsync at every commit was a third of a trivial cell's time (bench_orchestration.py).
    cursor.execute("PRAGMA synchronous=NORMAL")
    cursor.execute("PRAGMA busy_timeout=30000")
    cursor.execute("PRAGMA foreign_keys=ON")
    cursor.close()


def _sqlite_begin(connection) -> None:
    # A reading session (Database.reading) begins deferred: in WAL mode it reads a snapshot and
    # never takes the write lock, so a long read (a 10,000-cell job's record) does not hold up the
    # workers' claims and commits, nor wait for them.
    deferred = connection.get_execution_options().get(_READING, False)
    connection.exec_driver_sql("BEGIN" if deferred else "BEGIN IMMEDIATE")


_READING = "farfield_reading"


class Database:
    """An engine and session factory for one URL."""

    def __init__(self, url: str) -> None:
        self.url = url
        if url.startswith("sqlite:///"):
            Path(url.removeprefix("sqlite:///")).parent.mkdir(parents=True, exist_ok=True)
        self.engine: Engine = create_engine(url, pool_pre_ping=True)
        if self.engine.dialect.name == "sqlite":
            event.listen(self.engine, "connect", _sqlite_pragmas)
            event.listen(self.engine, "begin", _sqlite_begin)
        self.sessions = sessionmaker(self.engine, expire_on_commit=False)
        # The same pool, its transactions marked as reading (SQLite: a deferred BEGIN, _sqlite_begin).
        self.readers = sessionmaker(self.engine.execution_options(**{_READING: True}), expire_on_commit=False)

    @contextmanager
    def session(self):
        """A session that commits on success and rolls back on error."""
        with self.sessions() as session:
            try:
                yield session
                session.commit()
            except BaseException:
                session.rollback()
                raise

    @contextmanager
    def reading(self):
        """A session for reads alone: on SQLite its transaction begins deferred (a snapshot, no write
        lock: it neither waits for a writer nor holds one up), on PostgreSQL it is a :meth:`session`.
        What it reads may be stale by the time it is used: a decision to write is taken again in the
        write's own conditional ``UPDATE`` or locked :meth:`session`, never on this read alone."""
        with self.readers() as session:  # closing it ends the transaction; its rows stay loaded
            yield session

    def ping(self) -> None:
        """``SELECT 1`` on a pooled connection, outside the sessions' transactions: a health check
        that never waits for a writer (a session on SQLite begins ``BEGIN IMMEDIATE``, which queues
        behind the transaction storing a 10,000-cell job).  Raises when the database is unreachable."""
        connection = self.engine.raw_connection()
        try:
            cursor = connection.cursor()
            cursor.execute("SELECT 1")
            cursor.fetchone()
            cursor.close()
        finally:
            connection.close()

    def migrate(self) -> None:
        """Bring the schema to the newest migration."""
        migrate(self.engine)

    def dispose(self) -> None:
        self.engine.dispose()


def storable(text: str) -> bool:
    """Whether ``text`` can be stored and looked up in every backend: PostgreSQL's text holds no NUL
    (psycopg raises DataError, a 500 where SQLite answers "not found": issue 59, item 2), so an id
    with one names no row anywhere and is not sent to the database."""
    return isinstance(text, str) and "\x00" not in text


def owned_row(db: Database, model: type, tenant_id: str, row_id: str, what: str):
    """The ``model`` row ``row_id`` of tenant ``tenant_id``.  Another tenant's row is "not found"
    (404, never 403), so ids do not leak across tenants; so is an id no backend can hold
    (:func:`storable`)."""
    from farfield.core.errors import NotFoundError

    if not storable(row_id):
        raise NotFoundError(f"{what} {row_id!r} not found")
    with db.reading() as s:
        row = s.get(model, row_id)
    if row is None or row.tenant_id != tenant_id:
        raise NotFoundError(f"{what} {row_id!r} not found")
    return row


def job_cells(db: Database, job_id: str) -> list[CellRow]:
    """The job's cells, by index."""
    with db.reading() as s:
        return list(s.scalars(select(CellRow).where(CellRow.job_id == job_id).order_by(CellRow.index)))


def migrate(engine: Engine) -> None:
    """Run Alembic's upgrade to head on ``engine``."""
    from alembic import command
    from alembic.config import Config

    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS))
    with engine.begin() as connection:
        config.attributes["connection"] = connection
        command.upgrade(config, "head")
