"""Utilization: what the status samples need for it, and its summed hours.

Revision ID: 0007
Revises: 0009 (written on 0004; chained after 0009 when main was merged)
Create Date: 2026-11-27

Written by hand to match the models. ``status_samples`` gains the program, the control's
part counter and the alarm text (the recorder writes a sample when one of them changes);
``utilization_hours`` holds each machine's finished hours summed, ``utilization_stretches``
its finished stops and alarms, ``utilization_marks`` how far that summing has got
(docs/dashboard.md#utilization).
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0007"
down_revision = "0009"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("status_samples") as batch:
        batch.add_column(
            sa.Column("program", sa.String(length=64), nullable=False, server_default="")
        )
        batch.add_column(sa.Column("part_count", sa.Integer(), nullable=True))
        batch.add_column(
            sa.Column("alarm", sa.String(length=200), nullable=False, server_default="")
        )
    op.create_table(
        "utilization_hours",
        sa.Column("machine", sa.String(length=64), nullable=False),
        sa.Column("hour", sa.DateTime(timezone=True), nullable=False),
        *(
            sa.Column(name, sa.Float(), nullable=False)
            for name in ("running", "ready", "stopped", "alarm", "offline", "unknown", "no_record")
        ),
        sa.Column("parts", sa.Integer(), nullable=True),
        sa.Column("runs", sa.Integer(), nullable=False),
        sa.Column("cycles", sa.Integer(), nullable=False),
        sa.Column("cycle_seconds", sa.Float(), nullable=False),
        sa.PrimaryKeyConstraint("machine", "hour", name=op.f("pk_utilization_hours")),
    )
    op.create_table(
        "utilization_stretches",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("machine", sa.String(length=64), nullable=False),
        sa.Column("kind", sa.String(length=8), nullable=False),
        sa.Column("start", sa.DateTime(timezone=True), nullable=False),
        sa.Column("end", sa.DateTime(timezone=True), nullable=False),
        sa.Column("seconds", sa.Float(), nullable=False),
        sa.Column("state", sa.String(length=16), nullable=False),
        sa.Column("text", sa.String(length=200), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_utilization_stretches")),
    )
    op.create_index(
        "ix_utilization_stretches_machine_end",
        "utilization_stretches",
        ["machine", "kind", "end"],
        unique=False,
    )
    op.create_index(
        "ix_utilization_stretches_machine_seconds",
        "utilization_stretches",
        ["machine", "kind", "seconds"],
        unique=False,
    )
    op.create_table(
        "utilization_marks",
        sa.Column("machine", sa.String(length=64), nullable=False),
        sa.Column("until", sa.DateTime(timezone=True), nullable=False),
        sa.Column("last_id", sa.Integer(), nullable=False),
        sa.Column("carry", sa.JSON(), nullable=False),
        sa.PrimaryKeyConstraint("machine", name=op.f("pk_utilization_marks")),
    )


def downgrade() -> None:
    op.drop_table("utilization_marks")
    op.drop_index("ix_utilization_stretches_machine_seconds", table_name="utilization_stretches")
    op.drop_index("ix_utilization_stretches_machine_end", table_name="utilization_stretches")
    op.drop_table("utilization_stretches")
    op.drop_table("utilization_hours")
    with op.batch_alter_table("status_samples") as batch:
        batch.drop_column("alarm")
        batch.drop_column("part_count")
        batch.drop_column("program")
