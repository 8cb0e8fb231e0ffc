"""Failed jobs claimed before their alerts go: ``alerted_jobs``.

Revision ID: 0022
Revises: 0021
Create Date: 2026-12-01

Written by hand to match the models. A failed job's alert went from every server that saw the
job end: a job ended by one server and handed over to another could alert twice, and so could
a server restarted after it. Now the row is the claim: the one server whose insert goes
through sends the job's alerts (docs/server.md#alerts).
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0022"
down_revision = "0021"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "alerted_jobs",
        sa.Column("job_id", sa.Integer(), autoincrement=False, nullable=False),
        sa.Column("machine", sa.String(length=64), nullable=False),
        sa.Column("server", sa.String(length=64), nullable=False),
        sa.Column("claimed", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("job_id", name=op.f("pk_alerted_jobs")),
    )


def downgrade() -> None:
    op.drop_table("alerted_jobs")
