"""Servers of a cluster and their machine leases (several servers on one PostgreSQL).

Revision ID: 0009
Revises: 0004
Create Date: 2026-11-27

Written by hand to match the models: who is alive (a heartbeat on the database's clock) and
which server serves which machine until when, with an epoch that grows at every change of owner.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0009"
down_revision = "0004"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "cluster_servers",
        sa.Column("name", sa.String(length=64), nullable=False),
        sa.Column("host", sa.String(length=255), nullable=False),
        sa.Column("pid", sa.Integer(), nullable=False),
        sa.Column("url", sa.String(length=255), nullable=False),
        sa.Column("lease_seconds", sa.Float(), nullable=False),
        sa.Column("started", sa.DateTime(timezone=True), nullable=False),
        sa.Column("heartbeat", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("name", name=op.f("pk_cluster_servers")),
    )
    op.create_table(
        "machine_leases",
        sa.Column("machine", sa.String(length=64), nullable=False),
        sa.Column("owner", sa.String(length=64), nullable=False),
        sa.Column("epoch", sa.BigInteger(), nullable=False),
        sa.Column("acquired", sa.DateTime(timezone=True), nullable=False),
        sa.Column("expires", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("machine", name=op.f("pk_machine_leases")),
    )


def downgrade() -> None:
    op.drop_table("machine_leases")
    op.drop_table("cluster_servers")
