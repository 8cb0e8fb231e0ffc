"""OEE and downtime reasons: standard cycle times per program version, parts reported good
and scrapped, and the reason picked for each stop.

Revision ID: 0019
Revises: 0018
Create Date: 2026-11-29

Written by hand to match the models (server/utilization/oee.py and downtime.py,
docs/dashboard.md#oee). Three new tables; nothing existing changes.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0019"
down_revision = "0018"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "standard_times",
        sa.Column("version_id", sa.Integer(), nullable=False),
        sa.Column("seconds", sa.Float(), nullable=False),
        sa.Column("set_by", sa.String(length=64), nullable=False),
        sa.Column("set_at", sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(
            ["version_id"],
            ["program_versions.id"],
            name=op.f("fk_standard_times_version_id_program_versions"),
        ),
        sa.PrimaryKeyConstraint("version_id", name=op.f("pk_standard_times")),
    )
    op.create_table(
        "part_reports",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("machine", sa.String(length=64), nullable=False),
        sa.Column("at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("good", sa.Integer(), nullable=False),
        sa.Column("scrap", sa.Integer(), nullable=False),
        sa.Column("by", sa.String(length=64), nullable=False),
        sa.Column("note", sa.String(length=200), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_part_reports")),
    )
    op.create_index("ix_part_reports_machine_at", "part_reports", ["machine", "at"])
    op.create_table(
        "downtime_reasons",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("machine", sa.String(length=64), nullable=False),
        sa.Column("start", sa.DateTime(timezone=True), nullable=False),
        sa.Column("reason", sa.String(length=64), nullable=False),
        sa.Column("note", sa.String(length=200), nullable=False),
        sa.Column("by", sa.String(length=64), nullable=False),
        sa.Column("at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_downtime_reasons")),
        sa.UniqueConstraint("machine", "start", name="uq_downtime_reasons_machine_start"),
    )


def downgrade() -> None:
    op.drop_table("downtime_reasons")
    op.drop_index("ix_part_reports_machine_at", table_name="part_reports")
    op.drop_table("part_reports")
    op.drop_table("standard_times")
