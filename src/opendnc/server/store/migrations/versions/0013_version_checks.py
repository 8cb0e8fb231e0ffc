"""The dry run of each program version (the library's program check).

Revision ID: 0013
Revises: 0012
Create Date: 2026-11-27

Written by hand to match the models: one row per version and machine limits (``""`` for the
text alone) with the problems the checker found (docs/server.md#program-checks).
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0013"
down_revision = "0012"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "version_checks",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("version_id", sa.Integer(), nullable=False),
        sa.Column("limits", sa.String(length=64), nullable=False),
        sa.Column("control", sa.String(length=16), nullable=False),
        sa.Column("errors", sa.Integer(), nullable=False),
        sa.Column("warnings", sa.Integer(), nullable=False),
        sa.Column("summary", sa.Text(), nullable=False),
        sa.Column("problems", sa.JSON(), nullable=False),
        sa.Column("facts", sa.JSON(), nullable=False),
        sa.Column("checked", sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(
            ["version_id"],
            ["program_versions.id"],
            name=op.f("fk_version_checks_version_id_program_versions"),
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_version_checks")),
        sa.UniqueConstraint("version_id", "limits", name="uq_version_checks_version_limits"),
    )


def downgrade() -> None:
    op.drop_table("version_checks")
