"""A cell's planned texels and a worker's queues: GPU and CPU pools (issue 58, item 4).

``cells.texels`` is what the admission's full check planned for the cell (its cost: layers x texture
texels); the queue a cell is sent to is chosen from it each time it is sent
(:mod:`farfield.service.pools`: ``render.heavy`` past ``FARFIELD_HEAVY_TEXELS``, else ``render``),
so the sweeper's and a lease's re-sends keep the queue.  ``workers.queues`` is the queues a worker
consumes now, as its heartbeat last set them (``GET /v1/workers``).

Revision ID: 0010
Revises: 0009
"""

import sqlalchemy as sa
from alembic import op

revision = "0010"
down_revision = "0009"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("cells") as batch:
        batch.add_column(sa.Column("texels", sa.Float, nullable=True))
    with op.batch_alter_table("workers") as batch:
        batch.add_column(sa.Column("queues", sa.String(200), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("workers") as batch:
        batch.drop_column("queues")
    with op.batch_alter_table("cells") as batch:
        batch.drop_column("texels")
