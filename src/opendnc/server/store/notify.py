"""Wake-ups between servers sharing one PostgreSQL database: LISTEN/NOTIFY.

A server that queues a job, cancels or reorders one, or changes the library tells the others
through the database itself (``pg_notify`` inside the same transaction), so the server that
serves the machine acts at once instead of at its next sweep (docs/server.md#several-servers).
PostgreSQL delivers a notification only when its transaction commits, and never one whose
transaction rolled back, so a woken server always finds the row it was woken for.

Notifications are hints, not the truth: a listener that was disconnected may have missed
some, so it reports every reconnect and the server then re-reads what it serves. On SQLite
(one server) :func:`notify` does nothing and nothing listens.
"""

from __future__ import annotations

import asyncio
import enum
import logging
from collections.abc import Callable
from dataclasses import dataclass

from sqlalchemy import text
from sqlalchemy.engine import make_url
from sqlalchemy.orm import Session

from opendnc.server.store.db import pg_connect_args
from opendnc.server.store.health import reason

__all__ = ["CHANNEL", "Listener", "Notice", "Topic", "notify"]

CHANNEL = "opendnc"
_log = logging.getLogger(__name__)


class Topic(enum.StrEnum):
    """What a notice is about; its key says which one."""

    JOB = "job"  # a machine's queue changed: its server claims at once (key: the machine)
    CANCEL = "cancel"  # a cancel was asked: the server running it stops it (key: the job id)
    LIBRARY = "library"  # a program has a new version or state (key: "number:name")
    STATUS = "status"  # a server wrote its machines' status rows (key: that server)


@dataclass(frozen=True)
class Notice:
    """One wake-up: what changed and its key; ``topic`` is None for a payload this server
    does not know (a bare key, or a newer server's topic): read and ignored."""

    topic: Topic | None
    key: str

    def encode(self) -> str:
        """The notification's payload."""
        return f"{self.topic.value if self.topic is not None else ''}:{self.key}"

    @classmethod
    def decode(cls, payload: str) -> Notice:
        """A payload back into a notice (one without a topic is a bare key)."""
        word, _, key = payload.partition(":")
        if not key:
            return cls(None, word)
        try:
            return cls(Topic(word), key)
        except ValueError:
            return cls(None, key)


def notify(session: Session, topic: Topic, key: str) -> None:
    """Wake the other servers when ``session``'s transaction commits (nothing on SQLite)."""
    if session.get_bind().dialect.name != "postgresql":
        return
    session.execute(
        text("SELECT pg_notify(:channel, :payload)"),
        {"channel": CHANNEL, "payload": Notice(topic, key).encode()},
    )


class Listener:
    """Listens on the channel and hands each notice to ``on_notice``; reconnects with backoff.

    ``on_reconnect`` is called after every (re)connection: notices sent while the listener
    was away are lost, so the server re-reads the state it serves.
    """

    def __init__(
        self,
        database_url: str,
        on_notice: Callable[[Notice], None],
        *,
        on_reconnect: Callable[[], None] = lambda: None,
    ) -> None:
        url = make_url(database_url)
        # psycopg takes a libpq URL: the SQLAlchemy driver suffix goes
        self.conninfo = url.set(drivername="postgresql").render_as_string(hide_password=False)
        self.on_notice = on_notice
        self.on_reconnect = on_reconnect
        self.connected = asyncio.Event()
        self.connections = 0

    async def run(self) -> None:
        """Listen until cancelled."""
        import psycopg

        delay = 0.5
        failed = 0  # tries that failed since the last connection: the first one is told
        while True:
            try:
                # the engine's deadlines: a silent network breaks the listener too
                async with await psycopg.AsyncConnection.connect(
                    self.conninfo, autocommit=True, **pg_connect_args()
                ) as conn:
                    await conn.execute(f"LISTEN {CHANNEL}")
                    self.connections += 1
                    self.connected.set()
                    if failed:
                        _log.info("database notifications back (after %d tries)", failed)
                    delay, failed = 0.5, 0
                    self.on_reconnect()
                    async for message in conn.notifies():
                        self.on_notice(Notice.decode(message.payload))
            except psycopg.Error as exc:
                self.connected.clear()
                # one line, once an outage: the listener tries again every few seconds while
                # the database is away, and health and the other writers say so already
                _log.log(
                    logging.WARNING if not failed else logging.DEBUG,
                    "database notifications lost (%s); trying again every few seconds",
                    reason(exc),
                )
                failed += 1
            await asyncio.sleep(delay)
            delay = min(delay * 2, 10.0)
