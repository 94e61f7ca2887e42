"""The job database's migrations: a database made by an older revision upgrades in place."""

from __future__ import annotations

import os

import pytest
import sqlalchemy as sa
from alembic import command
from alembic.config import Config

from farfield.service.db import MIGRATIONS, Database, JobRow, SceneRow, Tenant
from farfield.service.jobs.cells import has_open_cells


def _config(connection) -> Config:
    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS))
    config.attributes["connection"] = connection
    return config


def test_upgrade_keeps_rows_and_adds_columns(tmp_path):
    db = Database(f"sqlite:///{tmp_path / 'old.db'}")
    with db.engine.begin() as connection:
        command.upgrade(_config(connection), "0001")
        connection.execute(sa.text("INSERT INTO tenants (id, name, created_at) VALUES ('t', 'acme', 1.0)"))
    assert "worker" not in {c["name"] for c in sa.inspect(db.engine).get_columns("cells")}
    db.migrate()
    db.migrate()  # idempotent
    assert "worker" in {c["name"] for c in sa.inspect(db.engine).get_columns("cells")}
    with db.engine.connect() as connection:
        assert connection.execute(sa.text("SELECT name FROM tenants")).scalars().all() == ["acme"]
        assert connection.execute(sa.text("SELECT version_num FROM alembic_version")).scalar() == "0010"


def test_0008_adds_cell_leases_and_the_worker_registry_and_goes_back(tmp_path):
    db = Database(f"sqlite:///{tmp_path / 'old.db'}")
    with db.engine.begin() as connection:
        command.upgrade(_config(connection), "0007")
    db.migrate()
    inspector = sa.inspect(db.engine)
    assert {"lease_token", "lease_until"} <= {c["name"] for c in inspector.get_columns("cells")}
    assert "ix_cells_lease_until" in {i["name"] for i in inspector.get_indexes("cells")}
    assert {c["name"] for c in inspector.get_columns("workers")} >= {
        "name", "host", "pid", "kind", "renderer", "concurrency", "started_at", "heartbeat_at",
    }  # fmt: skip
    with db.engine.begin() as connection:
        command.downgrade(_config(connection), "0007")
    inspector = sa.inspect(db.engine)
    assert "lease_token" not in {c["name"] for c in inspector.get_columns("cells")}
    assert "workers" not in inspector.get_table_names()


@pytest.fixture(params=["sqlite", "postgresql"])
def database_url(request, tmp_path):
    """An empty database's URL: SQLite, and PostgreSQL where ``FARFIELD_TEST_DATABASE_URL`` names a server."""
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'old.db'}"
        return
    from service_harness import fresh_postgres_database

    admin_url = os.environ.get("FARFIELD_TEST_DATABASE_URL")
    if not admin_url:
        pytest.skip("no PostgreSQL server: set FARFIELD_TEST_DATABASE_URL (CI starts one with scripts/postgres-server)")
    url, drop = fresh_postgres_database(admin_url)
    yield url
    drop()


def test_0009_indexes_a_job_s_cells_by_state_and_goes_back(database_url):
    db = Database(database_url)
    with db.engine.begin() as connection:
        command.upgrade(_config(connection), "0008")
    db.migrate()
    assert "ix_cells_job_state" in {i["name"] for i in sa.inspect(db.engine).get_indexes("cells")}
    if db.engine.dialect.name == "sqlite":
        # What finish_job_if_complete asks after each cell: answered from the index alone, every
        # column it needs in it (a "covering" index), never by reading the job's cell rows.
        open_cell = has_open_cells("j").compile(db.engine, compile_kwargs={"literal_binds": True})
        with db.engine.connect() as connection:
            plan = " ".join(row[-1] for row in connection.exec_driver_sql(f"EXPLAIN QUERY PLAN {open_cell}"))
        assert "COVERING INDEX ix_cells_job_state" in plan, plan
    with db.engine.begin() as connection:
        command.downgrade(_config(connection), "0008")
    assert "ix_cells_job_state" not in {i["name"] for i in sa.inspect(db.engine).get_indexes("cells")}
    db.dispose()


def test_0010_adds_cell_texels_and_worker_queues_and_goes_back(database_url):
    db = Database(database_url)
    with db.engine.begin() as connection:
        command.upgrade(_config(connection), "0009")
    db.migrate()
    inspector = sa.inspect(db.engine)
    assert "texels" in {c["name"] for c in inspector.get_columns("cells")}
    assert "queues" in {c["name"] for c in inspector.get_columns("workers")}
    with db.engine.begin() as connection:
        command.downgrade(_config(connection), "0009")
    inspector = sa.inspect(db.engine)
    assert "texels" not in {c["name"] for c in inspector.get_columns("cells")}
    assert "queues" not in {c["name"] for c in inspector.get_columns("workers")}
    db.dispose()


def test_jobs_made_before_evaluate_existed_are_evaluated(tmp_path):
    db = Database(f"sqlite:///{tmp_path / 'old.db'}")
    with db.engine.begin() as connection:
        command.upgrade(_config(connection), "0003")
        connection.execute(sa.text("INSERT INTO tenants (id, name, created_at) VALUES ('t', 'acme', 1.0)"))
        connection.execute(sa.text(
            "INSERT INTO scenes (id, tenant_id, name, extension, blob_key, size_bytes, content_hash, triangles, bounds, objects, created_at) "
            "VALUES ('s', 't', 'a.ply', '.ply', 'k', 1, 'h', 1, '[]', '[]', 1.0)"
        ))  # fmt: skip
        connection.execute(sa.text(
            "INSERT INTO jobs (id, tenant_id, scene_id, job_type, params, state, created_at) VALUES ('j', 't', 's', 'layered', '{}', 'done', 1.0)"
        ))  # fmt: skip
    db.migrate()
    with db.session() as s:
        assert s.get(JobRow, "j").evaluate is True


def test_scenes_made_before_0005_get_their_object_count_and_original_name(tmp_path):
    db = Database(f"sqlite:///{tmp_path / 'old.db'}")
    with db.engine.begin() as connection:
        command.upgrade(_config(connection), "0004")
        connection.execute(sa.text("INSERT INTO tenants (id, name, created_at) VALUES ('t', 'acme', 1.0)"))
        for scene_id, objects in (("s", '[{"name": "a"}, {"name": "b"}, {"name": "c"}]'), ("e", "[]")):
            connection.execute(sa.text(
                "INSERT INTO scenes (id, tenant_id, name, extension, blob_key, size_bytes, content_hash, triangles, bounds, objects, created_at) "
                f"VALUES ('{scene_id}', 't', 'my_scene.glb', 'glb', 'k', 1, 'h', 1, '[]', '{objects}', 1.0)"
            ))  # fmt: skip
    db.migrate()
    with db.session() as s:
        rows = {row.id: row for row in s.scalars(sa.select(SceneRow))}
    assert (rows["s"].object_count, rows["e"].object_count) == (3, 0)
    assert rows["s"].original_name == "my_scene.glb"
    assert "ix_scenes_tenant_created" in {i["name"] for i in sa.inspect(db.engine).get_indexes("scenes")}


def test_scenes_made_before_0007_were_read_double_sided_and_keep_it(tmp_path):
    """A stored scene is loaded again with its row's ``sides``; those uploaded before the option
    were read with every object double-sided, which their content hash records."""
    db = Database(f"sqlite:///{tmp_path / 'old.db'}")
    with db.engine.begin() as connection:
        command.upgrade(_config(connection), "0006")
        connection.execute(sa.text("INSERT INTO tenants (id, name, created_at) VALUES ('t', 'acme', 1.0)"))
        connection.execute(sa.text(
            "INSERT INTO scenes (id, tenant_id, name, extension, blob_key, size_bytes, content_hash, triangles, bounds, objects, created_at) "
            "VALUES ('s', 't', 'room.obj', 'obj', 'k', 1, 'h', 1, '[]', '[]', 1.0)"
        ))  # fmt: skip
    db.migrate()
    with db.session() as s:
        assert s.get(SceneRow, "s").sides == "both"
        s.add(SceneRow(id="n", tenant_id="t", name="new.obj", extension="obj", blob_key="k2", size_bytes=1, content_hash="h2",
                       triangles=1, bounds=[], objects=[]))  # fmt: skip
    with db.session() as s:
        assert s.get(SceneRow, "n").sides == "one"


def test_a_reading_session_neither_waits_for_nor_holds_up_a_writer(tmp_path):
    # SQLite: a reading session begins deferred (a snapshot, no write lock).  Were it BEGIN IMMEDIATE,
    # as a writing session is, the write below (another connection, as another process's, with a
    # 0.5 s busy timeout) would fail "database is locked", as the workers' claims waited behind the
    # API's reads of a large job before (benchmarks/bench_orchestration.py).
    path = tmp_path / "read.db"
    db = Database(f"sqlite:///{path}")
    db.migrate()
    with db.session() as s:
        s.add(Tenant(id="t1", name="one", created_at=1.0))
    other = sa.create_engine(f"sqlite:///{path}", connect_args={"timeout": 0.5})
    with db.reading() as reader:
        first = reader.get(Tenant, "t1")
        assert reader.execute(sa.text("SELECT count(*) FROM tenants")).scalar() == 1
        with other.begin() as connection:
            connection.execute(sa.text("INSERT INTO tenants (id, name, created_at) VALUES ('t2', 'two', 2.0)"))
        assert reader.execute(sa.text("SELECT count(*) FROM tenants")).scalar() == 1  # its own snapshot
    assert first.name == "one"  # rows it loaded stay usable after it ends (nothing expired)
    with db.reading() as reader:
        assert reader.execute(sa.text("SELECT count(*) FROM tenants")).scalar() == 2
    other.dispose()
    db.dispose()
