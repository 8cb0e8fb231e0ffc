"""When each API key was last used: noted in memory per request, written once a minute.

A request that checks a key only notes the key's id and the time (a dict under a lock). This
component writes what was noted every :data:`FLUSH_EVERY` seconds, all keys in one short
transaction, and once more when the server stops. Before, a request whose key's ``last_used``
was a minute old wrote it in a transaction of its own; under load each such write waited for
SQLite's write lock behind the uploads and job claims, on the request's path
(docs/server.md#users-keys-and-the-audit-trail). A server that crashes loses at most the last
minute of these times; nothing else depends on them.
"""

from __future__ import annotations

import asyncio
import logging
import threading
from datetime import datetime
from typing import cast

from sqlalchemy import Table, bindparam, or_, update
from sqlalchemy.exc import SQLAlchemyError
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.core.components import RunsTask
from opendnc.server.store.health import reason
from opendnc.server.store.models import ApiKey, utcnow

__all__ = ["FLUSH_EVERY", "KeyUse"]

log = logging.getLogger(__name__)

FLUSH_EVERY = 60.0  # seconds between two writes of the keys' last use

_KEYS = cast(Table, ApiKey.__table__)
# One statement for every key noted; it never moves a time backwards (another server sharing
# the database may have written a later one).
_WRITE = (
    update(_KEYS)
    .where(_KEYS.c.id == bindparam("key_id"))
    .where(or_(_KEYS.c.last_used.is_(None), _KEYS.c.last_used < bindparam("used")))
    .values(last_used=bindparam("used"))
)


class KeyUse(RunsTask):
    """The keys used since the last write, and the task that writes them (a component)."""

    name = "key-use"
    needs = ("database",)

    def __init__(self, sessions: sessionmaker[Session], every: float = FLUSH_EVERY) -> None:
        self.sessions = sessions
        self.every = every
        self._used: dict[int, datetime] = {}
        self._lock = threading.Lock()  # requests note from worker threads

    def note(self, key_id: int | None, when: datetime | None = None) -> None:
        """Key ``key_id`` was used (now, or at ``when``)."""
        if key_id is None:
            return
        moment = when or utcnow()
        with self._lock:
            known = self._used.get(key_id)
            if known is None or known < moment:
                self._used[key_id] = moment

    def pending(self) -> dict[int, datetime]:
        """What would be written now (a copy)."""
        with self._lock:
            return dict(self._used)

    def flush(self) -> int:
        """Write every noted use in one transaction (blocking); the number of keys written.

        What could not be written (the database is away) is kept for the next try."""
        with self._lock:
            used, self._used = self._used, {}
        if not used:
            return 0
        try:
            with self.sessions.begin() as session:
                session.execute(_WRITE, [{"key_id": k, "used": t} for k, t in used.items()])
        except SQLAlchemyError:
            for key_id, moment in used.items():
                self.note(key_id, moment)
            raise
        return len(used)

    async def run(self) -> None:
        """Write the noted uses every :attr:`every` seconds."""
        while True:
            await asyncio.sleep(self.every)
            try:
                await asyncio.to_thread(self.flush)
            except SQLAlchemyError as exc:
                log.warning(
                    "could not write the keys' last use (kept for the next try): %s", reason(exc)
                )

    async def stop(self) -> None:
        """Stop the task and write what is left."""
        await super().stop()
        try:
            await asyncio.to_thread(self.flush)
        except SQLAlchemyError as exc:
            log.warning("could not write the keys' last use at the stop: %s", exc)
