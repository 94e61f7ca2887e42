"""Scenes keep the ``sides`` option they were loaded with ("one" or "both": the sidedness of the
objects of a format that states none, OBJ, PLY and STL; farfield.core.sidedness).

A worker loads a stored scene file again with it, so the scene it bakes is the one whose content
hash the upload recorded.  Scenes uploaded before this revision were read with every object
double-sided, so existing rows get "both"; new uploads default to "one".

Revision ID: 0007
Revises: 0006
"""

import sqlalchemy as sa
from alembic import op

revision = "0007"
down_revision = "0006"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("scenes") as batch:
        batch.add_column(sa.Column("sides", sa.String(8), nullable=False, server_default="both"))


def downgrade() -> None:
    with op.batch_alter_table("scenes") as batch:
        batch.drop_column("sides")
