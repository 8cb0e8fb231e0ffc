"""Utilization per week: each machine's summed days summed once more per week of the calendar.

Revision ID: 0016
Revises: 0015
Create Date: 2026-11-28

Written by hand to match the models. ``utilization_weeks`` holds one row per machine and
week (its Monday): the sum of the week's rows in ``utilization_days``, the seconds in each
state and within shifts. A question over months grouped by week reads these instead of
240 000 day rows a year for 200 machines (docs/dashboard.md#how-it-stays-fast). On
PostgreSQL the index of stretches by machine, kind and end carries the alarm's start,
length, state and text, so a year of alarms per text is read from the index alone.

A week row is written when the week's last day is summed, so the days already summed are
dropped here with their marks: the server sums them again from the hours (in the background
and with each question), the weeks with them. Their calendar is not known here, so which of
them close a week is not either.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0016"
down_revision = "0015"
branch_labels = None
depends_on = None

STATES = ("running", "ready", "stopped", "alarm", "offline", "unknown", "no_record")


def upgrade() -> None:
    op.create_table(
        "utilization_weeks",
        sa.Column("machine", sa.String(length=64), nullable=False),
        sa.Column("week", sa.Date(), nullable=False),
        *(sa.Column(name, sa.Float(), nullable=False) for name in STATES),
        *(sa.Column(f"shift_{name}", sa.Float(), nullable=False) for name in STATES),
        sa.Column("parts", sa.Integer(), nullable=True),
        sa.Column("runs", sa.Integer(), nullable=False),
        sa.Column("cycles", sa.Integer(), nullable=False),
        sa.Column("cycle_seconds", sa.Float(), nullable=False),
        sa.PrimaryKeyConstraint("machine", "week", name=op.f("pk_utilization_weeks")),
    )
    op.execute("DELETE FROM utilization_days")
    op.execute("DELETE FROM utilization_day_marks")
    if op.get_bind().dialect.name == "postgresql":
        _stretches_end_index(["start", "seconds", "state", "text"])


def _stretches_end_index(include: list[str]) -> None:
    """The index of stretches by machine, kind and end, carrying ``include`` (PostgreSQL)."""
    op.drop_index("ix_utilization_stretches_machine_end", table_name="utilization_stretches")
    op.create_index(
        "ix_utilization_stretches_machine_end",
        "utilization_stretches",
        ["machine", "kind", "end"],
        postgresql_include=include,
    )


def downgrade() -> None:
    if op.get_bind().dialect.name == "postgresql":
        _stretches_end_index([])
    op.drop_table("utilization_weeks")
