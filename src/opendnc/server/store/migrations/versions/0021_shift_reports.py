"""Shift reports claimed before they are mailed: ``shift_reports``.

Revision ID: 0021
Revises: 0020
Create Date: 2026-11-30

Written by hand to match the models. Every server mailed each shift's report at the shift's
end: a cluster of two sent it twice, and a server restarted in the minute after a shift's end
could send it again. Now the row is the claim: the one server whose insert goes through sends
the report (docs/dashboard.md#shift-report).
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0021"
down_revision = "0020"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "shift_reports",
        sa.Column("shift", sa.String(length=64), nullable=False),
        sa.Column("state", sa.String(length=16), nullable=False),
        sa.Column("server", sa.String(length=64), nullable=False),
        sa.Column("claimed", sa.DateTime(timezone=True), nullable=False),
        sa.Column("finished", sa.DateTime(timezone=True), nullable=True),
        sa.Column("error", sa.Text(), nullable=False),
        sa.PrimaryKeyConstraint("shift", name=op.f("pk_shift_reports")),
    )


def downgrade() -> None:
    op.drop_table("shift_reports")
