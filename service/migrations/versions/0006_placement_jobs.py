"""Placement jobs: a job's planning record, lease and attempts; a cell's own impostor parameters.

``jobs.planning`` (JSON) is a placement job's progress while it is ``placing``; ``plan_worker`` and
``lease_until`` say which worker holds its planning and until when (renewed by a heartbeat, checked
by the API's sweeper); ``plan_attempts`` counts the attempts of the current phase.  ``cells.params``
(JSON) holds a placement cell's technique, objects and options (NULL: the job's).  The new job state
``placing`` needs no schema change (the state column is a string).

Revision ID: 0006
Revises: 0005
"""

import sqlalchemy as sa
from alembic import op

revision = "0006"
down_revision = "0005"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("jobs") as batch:
        batch.add_column(sa.Column("planning", sa.JSON, nullable=True))
        batch.add_column(sa.Column("plan_worker", sa.String(200), nullable=True))
        batch.add_column(sa.Column("lease_until", sa.Float, nullable=True))
        batch.add_column(sa.Column("plan_attempts", sa.Integer, nullable=False, server_default="0"))
    op.create_index("ix_jobs_lease_until", "jobs", ["lease_until"])
    with op.batch_alter_table("cells") as batch:
        batch.add_column(sa.Column("params", sa.JSON, nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("cells") as batch:
        batch.drop_column("params")
    op.drop_index("ix_jobs_lease_until", "jobs")
    with op.batch_alter_table("jobs") as batch:
        batch.drop_column("plan_attempts")
        batch.drop_column("lease_until")
        batch.drop_column("plan_worker")
        batch.drop_column("planning")
