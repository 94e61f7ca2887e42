"""Cell leases and the worker registry (issue 58, item 2).

``cells.lease_token`` names the attempt that holds a running cell and ``cells.lease_until`` until when
(renewed by its worker's heartbeat; the API's sweeper queues again a cell whose lease ran out, and a
result whose token no longer matches is discarded).  ``workers`` is one row per Celery worker node:
its host, kind and renderer, and its last heartbeat (``GET /v1/workers``).

Revision ID: 0008
Revises: 0007
"""

import sqlalchemy as sa
from alembic import op

revision = "0008"
down_revision = "0007"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("cells") as batch:
        batch.add_column(sa.Column("lease_token", sa.String(32), nullable=True))
        batch.add_column(sa.Column("lease_until", sa.Float, nullable=True))
    op.create_index("ix_cells_lease_until", "cells", ["lease_until"])
    op.create_table(
        "workers",
        sa.Column("name", sa.String(200), primary_key=True),
        sa.Column("host", sa.String(200), nullable=False),
        sa.Column("pid", sa.Integer, nullable=False),
        sa.Column("kind", sa.String(8), nullable=False),
        sa.Column("renderer", sa.String(500), nullable=True),
        sa.Column("concurrency", sa.Integer, nullable=False),
        sa.Column("started_at", sa.Float, nullable=False),
        sa.Column("heartbeat_at", sa.Float, nullable=False),
    )


def downgrade() -> None:
    op.drop_table("workers")
    op.drop_index("ix_cells_lease_until", "cells")
    with op.batch_alter_table("cells") as batch:
        batch.drop_column("lease_until")
        batch.drop_column("lease_token")
