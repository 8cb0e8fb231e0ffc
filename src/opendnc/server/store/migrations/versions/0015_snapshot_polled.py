"""A machine's shared status is rewritten only when it changed: ``changed`` and ``polled``.

Revision ID: 0015
Revises: 0014
Create Date: 2026-11-28

Written by hand to match the models. The serving server used to rewrite each machine's whole
status row on every poll; now ``data`` is written when something but the status's time changed
(at ``changed``), and an unchanged poll moves only ``polled``, the time of the status the row
stands for (docs/server.md#several-servers). Rows of an older server have neither: a reader
then takes ``data`` as it is.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0015"
down_revision = "0014"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("machine_snapshots") as batch:
        batch.add_column(sa.Column("changed", sa.DateTime(timezone=True), nullable=True))
        batch.add_column(sa.Column("polled", sa.DateTime(timezone=True), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("machine_snapshots") as batch:
        batch.drop_column("polled")
        batch.drop_column("changed")
