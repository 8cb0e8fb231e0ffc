"""Status samples of the machines, for the dashboard's status timeline.

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-23

Written by hand to match the models (as 0003 was checked): the custom UtcDateTime column is
the plain timezone-aware DateTime it is in the database. One index serves the machine page's
read (a machine's samples since a time), the other the pruning (every sample before a time).
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0004"
down_revision = "0003"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "status_samples",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("machine", sa.String(length=64), nullable=False),
        sa.Column("at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("state", sa.String(length=16), nullable=False),
        sa.Column("mode", sa.String(length=64), nullable=False),
        sa.Column("execution", sa.String(length=32), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_status_samples")),
    )
    op.create_index(
        "ix_status_samples_machine_at", "status_samples", ["machine", "at"], unique=False
    )
    op.create_index("ix_status_samples_at", "status_samples", ["at"], unique=False)


def downgrade() -> None:
    op.drop_index("ix_status_samples_at", table_name="status_samples")
    op.drop_index("ix_status_samples_machine_at", table_name="status_samples")
    op.drop_table("status_samples")
