"""Scenes keep their object count and the file name as uploaded; listing scenes is by tenant, newest first.

``object_count`` lets a listing summarise a scene without reading its ``objects`` JSON (megabytes for
10^5 objects); ``original_name`` is the upload's name as sent (bounded), kept as metadata only: the
path-safe ``name`` stays the one blob keys are built from.  Existing rows are filled in: the count
from the JSON (``json_array_length`` on SQLite and PostgreSQL), the original name from ``name``.

Revision ID: 0005
Revises: 0004
"""

import json

import sqlalchemy as sa
from alembic import op

revision = "0005"
down_revision = "0004"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("scenes") as batch:
        batch.add_column(sa.Column("object_count", sa.Integer, nullable=False, server_default="0"))
        batch.add_column(sa.Column("original_name", sa.String(1024), nullable=False, server_default=""))
    connection = op.get_bind()
    if connection.dialect.name in ("sqlite", "postgresql"):
        op.execute("UPDATE scenes SET object_count = json_array_length(objects), original_name = name")
    else:
        for scene_id, objects in connection.execute(sa.text("SELECT id, objects FROM scenes")).all():
            count = len(json.loads(objects) if isinstance(objects, str) else objects or [])
            connection.execute(
                sa.text("UPDATE scenes SET object_count = :n, original_name = name WHERE id = :id"),
                {"n": count, "id": scene_id},
            )
    op.create_index("ix_scenes_tenant_created", "scenes", ["tenant_id", "created_at"])


def downgrade() -> None:
    op.drop_index("ix_scenes_tenant_created", "scenes")
    with op.batch_alter_table("scenes") as batch:
        batch.drop_column("original_name")
        batch.drop_column("object_count")
