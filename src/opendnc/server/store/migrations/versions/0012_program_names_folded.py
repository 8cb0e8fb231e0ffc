"""A unique index on the folded (lower-case) program name.

Revision ID: 0012
Revises: 0011 (written on 0007; chained after 0011 when main was merged)
Create Date: 2026-11-27

Names that differ only in case are one file on Windows and SMB shares. The library refuses
such a name when the other exists, but on PostgreSQL two uploads of ``a.nc`` and ``A.nc`` at
the same moment could both pass that check; the index refuses the second. A database that
already holds such a pair keeps it (nothing is renamed behind the shop's back): the index is
left out with a warning naming them, and the library's own check still refuses new ones.
"""

from __future__ import annotations

import logging

import sqlalchemy as sa
from alembic import op

revision = "0012"
down_revision = "0011"
branch_labels = None
depends_on = None

log = logging.getLogger("alembic.runtime.migration")


def upgrade() -> None:
    twins = (
        op.get_bind()
        .execute(
            sa.text(
                "SELECT lower(name), count(*) FROM programs GROUP BY lower(name) "
                "HAVING count(*) > 1"
            )
        )
        .all()
    )
    if twins:
        log.warning(
            "programs whose names differ only in case (%s): the unique index on the folded "
            "name is left out until one of each is renamed",
            ", ".join(str(row[0]) for row in twins),
        )
        return
    op.create_index("uq_programs_name_folded", "programs", [sa.text("lower(name)")], unique=True)


def downgrade() -> None:
    op.execute("DROP INDEX IF EXISTS uq_programs_name_folded")
