"""Each machine's status as its serving server last saw it (several servers on one PostgreSQL).

Revision ID: 0010
Revises: 0007
Create Date: 2026-11-27

Written by hand to match the models: the server holding a machine's lease writes the machine's
status here and the other servers read it, so every server shows every machine.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0010"
down_revision = "0007"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "machine_snapshots",
        sa.Column("machine", sa.String(length=64), nullable=False),
        sa.Column("server", sa.String(length=64), nullable=False),
        sa.Column("updated", sa.DateTime(timezone=True), nullable=False),
        sa.Column("data", sa.JSON(), nullable=False),
        sa.PrimaryKeyConstraint("machine", name=op.f("pk_machine_snapshots")),
    )
    op.create_index(
        op.f("ix_machine_snapshots_updated"), "machine_snapshots", ["updated"], unique=False
    )


def downgrade() -> None:
    op.drop_index(op.f("ix_machine_snapshots_updated"), table_name="machine_snapshots")
    op.drop_table("machine_snapshots")
