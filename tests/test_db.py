"""The job database's migrations: a database made by an older revision upgrades in place."""

from __future__ import annotations

import sqlalchemy as sa
from alembic import command
from alembic.config import Config

from farfield.service.db import MIGRATIONS, Database, JobRow


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
        assert connection.execute(sa.text("SELECT version_num FROM alembic_version")).scalar() == "0004"


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
