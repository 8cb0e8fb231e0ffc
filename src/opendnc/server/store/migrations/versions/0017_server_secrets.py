"""Secrets the servers on one database share: ``server_secrets``.

Revision ID: 0017
Revises: 0016
Create Date: 2026-11-29

Written by hand to match the models. One row per secret, made once by the first server that
needs it and read by every other: the key that signs the browsers' device cookies used to be
made in memory by each process, so a cookie was good on one server of a cluster only, and
until it restarted (docs/server.md#throttling).
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0017"
down_revision = "0016"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "server_secrets",
        sa.Column("name", sa.String(length=64), nullable=False),
        sa.Column("value", sa.LargeBinary(), nullable=False),
        sa.Column("created", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("name", name=op.f("pk_server_secrets")),
    )


def downgrade() -> None:
    op.drop_table("server_secrets")
