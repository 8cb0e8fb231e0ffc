"""A duty done once across restarts and the servers of a cluster: the row is the claim.

Some duties must be done by one server only, and only once: a failed job's alert
(``alerted_jobs``), an alert episode (``alert_episodes``), a shift's report by e-mail
(``shift_reports``). Each has a table whose primary key names the duty. Before doing it, a
server inserts the duty's row in a transaction of its own; the primary key lets exactly one
insert through, on SQLite and on PostgreSQL alike. The server whose insert went through does
the duty; one that finds the row there (another server of the cluster, or itself before a
restart) does not.

The claim is written before the duty is done, so a server killed in between leaves the row
and the duty is not done again by anyone: at most once. For a message to a person a missing
copy (which the audit trail shows) is the lesser harm than a second one.
"""

from __future__ import annotations

from sqlalchemy import inspect
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.store.models import Base

__all__ = ["claim_once"]


def claim_once(sessions: sessionmaker[Session], row: Base) -> bool:
    """Insert ``row`` (a claim, its primary key set) in a transaction of its own: True if the
    insert went through (this server does the duty), False if a row with that key is there
    already (the duty is another's, or was done before a restart).

    Raises :class:`sqlalchemy.exc.SQLAlchemyError` when the database does not answer, and
    the :class:`IntegrityError` itself when the insert was refused for another reason than an
    existing row (a value the table does not take): that is a bug, not a claim lost.
    """
    model = type(row)
    key = inspect(model).primary_key_from_instance(row)
    try:
        with sessions.begin() as session:
            session.add(row)
    except IntegrityError:
        with sessions() as session:
            if session.get(model, tuple(key)) is None:
                raise
        return False
    return True
