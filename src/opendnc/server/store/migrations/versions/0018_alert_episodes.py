"""Alert episodes that fired and have not ended: ``alert_episodes``.

Revision ID: 0018
Revises: 0017
Create Date: 2026-11-29

Written by hand to match the models. An episode (a machine in alarm, stopped or offline for
a rule's minutes) was kept in each server's memory only: a restarted server sent the alert of
an episode again, and after a hand-over the next server of a cluster did too. Now the row is
the claim on the alert: inserted by the one server that sends it, deleted by the one that
sends the episode's end (docs/server.md#alerts).
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0018"
down_revision = "0017"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "alert_episodes",
        sa.Column("rule", sa.String(length=128), nullable=False),
        sa.Column("machine", sa.String(length=64), nullable=False),
        sa.Column("since", sa.DateTime(timezone=True), nullable=False),
        sa.Column("fired", sa.DateTime(timezone=True), nullable=False),
        sa.Column("server", sa.String(length=64), nullable=False),
        sa.Column("detail", sa.Text(), nullable=False),
        sa.PrimaryKeyConstraint("rule", "machine", name=op.f("pk_alert_episodes")),
    )


def downgrade() -> None:
    op.drop_table("alert_episodes")
