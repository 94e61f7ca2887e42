"""An index on ``cells (job_id, state)`` (issue 58, item 5).

After each cell a worker counts its job's open cells (``state`` queued or running,
``service.jobs.cells.finish_job_if_complete``), and admission counts a tenant's open cells
(``service.quotas.open_cells``).  With ``job_id`` alone indexed, that read visits every cell row of
the job, 10,000 of them for a 10,000-cell job after every one of its cells; with ``(job_id,
state)`` it reads only the open cells' index entries, without the rows.

Revision ID: 0009
Revises: 0008
"""

from alembic import op

revision = "0009"
down_revision = "0008"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_index("ix_cells_job_state", "cells", ["job_id", "state"])


def downgrade() -> None:
    op.drop_index("ix_cells_job_state", "cells")
