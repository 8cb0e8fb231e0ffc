"""Utilization per local day: each machine's finished hours summed per day and shift.

Revision ID: 0014
Revises: 0013 (written on 0007; chained after 0013 when main was merged)
Create Date: 2026-11-27

Written by hand to match the models. ``utilization_days`` holds one row per machine, local
day of the shop's calendar and slot (a shift's part of the day, or the time outside shifts),
summed from ``utilization_hours``; ``utilization_day_marks`` how far that has got and for
which calendar. A question over months reads these instead of every hour
(docs/dashboard.md#how-it-stays-fast). Nothing to fill here: the server builds the days from
the hours as it sums them.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0014"
down_revision = "0013"
branch_labels = None
depends_on = None

STATES = ("running", "ready", "stopped", "alarm", "offline", "unknown", "no_record")


def upgrade() -> None:
    op.create_table(
        "utilization_days",
        sa.Column("machine", sa.String(length=64), nullable=False),
        sa.Column("day", sa.Date(), nullable=False),
        sa.Column("shift", sa.String(length=32), nullable=False),
        sa.Column("shift_day", sa.Date(), nullable=False),
        sa.Column("week", sa.Date(), nullable=False),
        *(sa.Column(name, sa.Float(), nullable=False) for name in STATES),
        sa.Column("parts", sa.Integer(), nullable=True),
        sa.Column("runs", sa.Integer(), nullable=False),
        sa.Column("cycles", sa.Integer(), nullable=False),
        sa.Column("cycle_seconds", sa.Float(), nullable=False),
        sa.PrimaryKeyConstraint(
            "machine", "day", "shift", "shift_day", name=op.f("pk_utilization_days")
        ),
    )
    op.create_table(
        "utilization_day_marks",
        sa.Column("machine", sa.String(length=64), nullable=False),
        sa.Column("calendar", sa.String(length=64), nullable=False),
        sa.Column("until", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("machine", name=op.f("pk_utilization_day_marks")),
    )


def downgrade() -> None:
    op.drop_table("utilization_day_marks")
    op.drop_table("utilization_days")
