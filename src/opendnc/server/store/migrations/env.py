"""Alembic environment: runs on the connection that :func:`opendnc.server.store.db.migrate` passes.

There is no ``alembic.ini``: the server migrates its own database at start, and the scripts ship
inside the package so an installed server can do that without a source checkout.
"""

from __future__ import annotations

from alembic import context

from opendnc.server.store.models import Base

connection = context.config.attributes["connection"]
context.configure(
    connection=connection,
    target_metadata=Base.metadata,
    # SQLite cannot ALTER most things; batch mode copies the table instead.
    render_as_batch=True,
)
with context.begin_transaction():
    context.run_migrations()
