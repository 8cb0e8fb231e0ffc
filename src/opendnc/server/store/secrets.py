"""Secrets the servers on one database share, made once (``server_secrets``).

The first server that needs a secret makes it and inserts it; one that finds it there uses
that one. Two servers starting at the same moment both try to insert: the primary key lets one
through, the other reads the winner's. So every server of a cluster, and the same server after
a restart, signs with the same key (docs/server.md#throttling).
"""

from __future__ import annotations

import secrets

from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.core.errors import Unavailable
from opendnc.server.store.models import ServerSecret

__all__ = ["DEVICE_COOKIE_KEY", "SECRET_BYTES", "shared_secret"]

DEVICE_COOKIE_KEY = "device-cookie"  # signs the browsers' device cookies (throttle.py)
SECRET_BYTES = 32


def shared_secret(sessions: sessionmaker[Session], name: str) -> bytes:
    """The secret called ``name``, made now if no server has made it yet."""
    with sessions() as session:
        row = session.get(ServerSecret, name)
        if row is not None:
            return bytes(row.value)
    try:
        with sessions.begin() as session:
            session.add(ServerSecret(name=name, value=secrets.token_bytes(SECRET_BYTES)))
    except IntegrityError:
        pass  # another server made it a moment ago: that one is read below
    with sessions() as session:
        row = session.get(ServerSecret, name)
        if row is None:  # pragma: no cover - inserted or found above
            raise Unavailable(f"the shared secret {name!r} was neither found nor made")
        return bytes(row.value)
