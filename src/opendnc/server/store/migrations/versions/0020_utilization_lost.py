"""Lost time per downtime reason summed per machine and local day (and week), as the time
in each state is.

Revision ID: 0020
Revises: 0019
Create Date: 2026-11-30

Written by hand to match the models (server/utilization/lost.py,
docs/dashboard.md#how-it-stays-fast). A year of 200 machines holds about 1.5 million stops:
a question summed their lost time per reason from every one of them. ``utilization_lost_days``
and ``utilization_lost_weeks`` hold those sums per machine, slot of the day (or week) and
reason; ``utilization_day_marks.lost_until`` says how far they go (empty here: the server
sums them from the stops already summed, in the background and with each question). The
index of stretches by machine, kind and start finds the stop a reason is picked for.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0020"
down_revision = "0019"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "utilization_lost_days",
        sa.Column("machine", sa.String(length=64), nullable=False),
        sa.Column("day", sa.Date(), nullable=False),
        sa.Column("shift", sa.String(length=32), nullable=False),
        sa.Column("shift_day", sa.Date(), nullable=False),
        sa.Column("reason", sa.String(length=64), nullable=False),
        sa.Column("week", sa.Date(), nullable=False),
        sa.Column("stops", sa.Integer(), nullable=False),
        sa.Column("seconds", sa.Float(), nullable=False),
        sa.PrimaryKeyConstraint(
            "machine", "day", "shift", "shift_day", "reason", name=op.f("pk_utilization_lost_days")
        ),
    )
    op.create_table(
        "utilization_lost_weeks",
        sa.Column("machine", sa.String(length=64), nullable=False),
        sa.Column("week", sa.Date(), nullable=False),
        sa.Column("reason", sa.String(length=64), nullable=False),
        sa.Column("stops", sa.Integer(), nullable=False),
        sa.Column("seconds", sa.Float(), nullable=False),
        sa.PrimaryKeyConstraint(
            "machine", "week", "reason", name=op.f("pk_utilization_lost_weeks")
        ),
    )
    with op.batch_alter_table("utilization_day_marks") as batch:
        batch.add_column(sa.Column("lost_until", sa.DateTime(timezone=True), nullable=True))
    op.create_index(
        "ix_utilization_stretches_machine_start",
        "utilization_stretches",
        ["machine", "kind", "start"],
    )


def downgrade() -> None:
    op.drop_index("ix_utilization_stretches_machine_start", table_name="utilization_stretches")
    with op.batch_alter_table("utilization_day_marks") as batch:
        batch.drop_column("lost_until")
    op.drop_table("utilization_lost_weeks")
    op.drop_table("utilization_lost_days")
