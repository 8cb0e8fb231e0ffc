"""Runs and running time per program summed per hour, so OEE's performance reads sums.

Revision ID: 0023
Revises: 0022
Create Date: 2026-12-01

Written by hand to match the models (server/utilization/collect.py, docs/dashboard.md#oee).
Performance followed 7 days of samples to count each program's runs; the hours summed from
now on hold them in ``utilization_program_hours`` (machine, hour, program, runs, seconds).
The hours summed before hold none: every mark's ``last_id`` goes back to 0, so the next
summing takes every kept sample for a late one and sums each machine again from its oldest
kept sample (its hours, stops, days and lost time; hours whose samples were pruned stay as
they were).
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0023"
down_revision = "0022"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "utilization_program_hours",
        sa.Column("machine", sa.String(length=64), nullable=False),
        sa.Column("hour", sa.DateTime(timezone=True), nullable=False),
        sa.Column("program", sa.String(length=64), nullable=False),
        sa.Column("runs", sa.Integer(), nullable=False),
        sa.Column("seconds", sa.Float(), nullable=False),
        sa.PrimaryKeyConstraint(
            "machine", "hour", "program", name=op.f("pk_utilization_program_hours")
        ),
    )
    op.execute("UPDATE utilization_marks SET last_id = 0")


def downgrade() -> None:
    op.drop_table("utilization_program_hours")
