"""DPRNT lines captured from the machines.

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-23

Generated with Alembic's autogenerate against the models, then checked by hand: the custom
UtcDateTime column is written as the plain timezone-aware DateTime it is in the database, and
the one index serves the API's query (a machine's lines after an id).
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0003"
down_revision = "0002"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "dprnt_lines",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("machine", sa.String(length=64), nullable=False),
        sa.Column("at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("text", sa.Text(), nullable=False),
        sa.Column("fields", sa.JSON(), nullable=False),
        sa.Column("complete", sa.Boolean(), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_dprnt_lines")),
    )
    op.create_index("ix_dprnt_lines_machine_id", "dprnt_lines", ["machine", "id"], unique=False)


def downgrade() -> None:
    op.drop_index("ix_dprnt_lines_machine_id", table_name="dprnt_lines")
    op.drop_table("dprnt_lines")
