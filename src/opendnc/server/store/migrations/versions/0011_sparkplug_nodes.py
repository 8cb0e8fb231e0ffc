"""The Sparkplug B edge nodes' bdSeq, kept across restarts.

Revision ID: 0011
Revises: 0010 (written on 0007; chained after 0010 when main was merged)
Create Date: 2026-11-27

Written by hand to match the model: one row per (group, edge node) with the bdSeq of the
node's latest MQTT session.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0011"
down_revision = "0010"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "sparkplug_nodes",
        sa.Column("group_id", sa.String(length=64), nullable=False),
        sa.Column("node_id", sa.String(length=64), nullable=False),
        sa.Column("bd_seq", sa.Integer(), nullable=False),
        sa.PrimaryKeyConstraint("group_id", "node_id", name=op.f("pk_sparkplug_nodes")),
    )


def downgrade() -> None:
    op.drop_table("sparkplug_nodes")
