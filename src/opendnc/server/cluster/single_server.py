"""One server alone: SQLite always, PostgreSQL with ``[server] cluster = false``.

SQLite serves one server: a second server on the same file is refused with one line.

Several servers coordinate through PostgreSQL (:mod:`opendnc.server.machines.leases`); SQLite has no
shared clock, row locks or notifications, and two servers on one file would both serve every
machine. The guard is an operating-system lock on a file beside the database, held for the
server's life: the system drops it when the process ends, however it ends, so a crashed
server never locks the next one out.

On PostgreSQL a server configured as the only one (``cluster = false``) takes no leases and
never fences itself: it drives its machines through a database outage. A lone server writes no
rows another could see, so every server holds one PostgreSQL advisory lock
(:data:`SERVER_LOCK_KEY`, :class:`ServerLock`) on a connection of its own for its life: a lone
server exclusively, a cluster server shared. A second lone server, or a cluster server beside a
lone one (or a lone one beside a cluster), cannot take it and refuses to start in one line,
since both would drive the same machines. A lone server also refuses while an older cluster
server holds leases or heartbeats there (:func:`refuse_beside_a_cluster`).
"""

from __future__ import annotations

import asyncio
import logging
import os
import sys
import threading
from pathlib import Path
from typing import IO

from sqlalchemy import Connection, create_engine, text
from sqlalchemy.engine import make_url
from sqlalchemy.exc import DBAPIError, SQLAlchemyError
from sqlalchemy.orm import Session, sessionmaker
from sqlalchemy.pool import NullPool

from opendnc.errors import DncError
from opendnc.server.core.components import RunsTask
from opendnc.server.machines.leases import cluster_view
from opendnc.server.store.db import pg_connect_args, unreachable
from opendnc.server.store.health import reason

__all__ = [
    "SERVER_LOCK_KEY",
    "DatabaseInUse",
    "ServerLock",
    "SingleServerLock",
    "refuse_beside_a_cluster",
]

log = logging.getLogger("opendnc.server")

# The advisory lock every opendnc server on one PostgreSQL database holds ("odnc" in ASCII):
# exclusive for a lone server, shared for a cluster's.
SERVER_LOCK_KEY = 0x6F646E63


class DatabaseInUse(DncError):
    """Another server already serves from this SQLite database."""


class SingleServerLock:
    """The lock of one SQLite database's server (nothing to lock for other databases)."""

    def __init__(self, database_url: str) -> None:
        url = make_url(database_url)
        name = url.database or ""
        self.path: Path | None = None
        if url.get_backend_name() == "sqlite" and name and name != ":memory:":
            self.path = Path(name).with_name(Path(name).name + ".server-lock")
        self._file: IO[str] | None = None

    def acquire(self) -> None:
        """Take the lock, or raise :class:`DatabaseInUse` naming the other server's process."""
        if self.path is None or self._file is not None:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        handle = open(self.path, "a+", encoding="ascii")  # noqa: SIM115 (held for the server's life)
        if not _try_lock(handle):
            handle.seek(0)
            holder = handle.read().strip() or "another process"
            handle.close()
            database = self.path.with_name(self.path.name.removesuffix(".server-lock"))
            raise DatabaseInUse(
                f"another opendnc server ({holder}) serves from {database}; SQLite serves one "
                "server: use PostgreSQL for several (docs/server.md#several-servers)"
            )
        handle.seek(0)
        handle.truncate()
        handle.write(f"pid {os.getpid()}")
        handle.flush()
        self._file = handle

    def release(self) -> None:
        """Give the lock back (a clean stop; a crash gives it back by itself)."""
        if self._file is not None:
            _unlock(self._file)
            self._file.close()
            self._file = None


def _try_lock(handle: IO[str]) -> bool:
    if sys.platform == "win32":
        import msvcrt

        try:
            msvcrt.locking(handle.fileno(), msvcrt.LK_NBLCK, 1)
        except OSError:
            return False
        return True
    import fcntl

    try:
        fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return False
    return True


def _unlock(handle: IO[str]) -> None:
    if sys.platform == "win32":
        import msvcrt

        handle.seek(0)
        msvcrt.locking(handle.fileno(), msvcrt.LK_UNLCK, 1)
        return
    import fcntl

    fcntl.flock(handle.fileno(), fcntl.LOCK_UN)


def refuse_beside_a_cluster(sessions: sessionmaker[Session], server: str) -> None:
    """Raise :class:`DatabaseInUse` if another live server shares this database (a heartbeat
    younger than its lease, or a live machine lease of its own)."""
    view = cluster_view(sessions)
    others = {s.name for s in view.servers if s.alive and s.name != server}
    others |= {r.owner for r in view.leases if r.live and r.owner != server}
    if others:
        raise DatabaseInUse(
            f"other opendnc servers use this database ({', '.join(sorted(others))}); a server "
            "with [server] cluster = false must be the only one: stop them first, or set "
            "cluster = true (docs/server.md#one-server-alone)"
        )


class ServerLock(RunsTask):
    """This server's hold of :data:`SERVER_LOCK_KEY` on PostgreSQL (see the module): exclusive
    when ``alone``, else shared. :meth:`acquire` takes it at build or raises
    :class:`DatabaseInUse`; the component then checks its connection every ``every`` seconds
    and, if the connection was lost (a database blip ends the session and so the lock), logs it
    and takes the lock again once the database answers. A lone server keeps driving meanwhile:
    it is configured as the only one, and fencing it on a blip is what it is for not to do."""

    name = "server-lock"

    def __init__(self, database_url: str, *, alone: bool, every: float = 2.0) -> None:
        url = make_url(database_url)
        self.alone = alone
        self.every = every
        # a connection of its own, never pooled: the lock lives exactly as long as it does
        self._engine = create_engine(
            url,
            poolclass=NullPool,
            isolation_level="AUTOCOMMIT",
            connect_args=pg_connect_args(dict(url.query)),
        )
        self._connection: Connection | None = None
        self._guard = threading.Lock()  # the check runs in a thread, the stop in another
        self._stopped = False
        self._refused = False  # a re-take refused: said once until it is taken again

    @property
    def held(self) -> bool:
        """Whether this server holds the lock now (as far as its connection last told)."""
        return self._connection is not None

    def acquire(self) -> None:
        """Take the lock, or raise :class:`DatabaseInUse` (one line); a database that refuses
        the lock's connection (one with no connection left, say) is
        :class:`~opendnc.server.store.db.DatabaseUnreachable`, one line too."""
        try:
            taken = self._take()
        except DBAPIError as exc:
            raise unreachable(self._engine, exc) from None
        if taken:
            return
        if self.alone:
            raise DatabaseInUse(
                "another opendnc server uses this database (a server with [server] cluster = "
                "false, or one of a cluster); a server with cluster = false must be the only "
                "one: stop the other first, or set cluster = true (docs/server.md#one-server-alone)"
            )
        raise DatabaseInUse(
            "an opendnc server with [server] cluster = false uses this database and must be the "
            "only one: stop it first, or set cluster = true on it (docs/server.md#one-server-alone)"
        )

    def _take(self) -> bool:
        # no lock held across the network: a stop must not wait for a silent database
        if self._connection is not None:
            return True
        how = "pg_try_advisory_lock" if self.alone else "pg_try_advisory_lock_shared"
        connection = self._engine.connect()
        try:
            got = connection.execute(text(f"SELECT {how}(:key)"), {"key": SERVER_LOCK_KEY})
            taken = bool(got.scalar())
        except BaseException:
            connection.close()
            raise
        with self._guard:
            if taken and not self._stopped:
                self._connection = connection
                return True
        connection.close()
        return False

    def check(self) -> None:
        """Ask the lock's connection; take the lock again if it was lost (blocking)."""
        connection = self._connection
        if connection is not None:
            try:
                connection.execute(text("SELECT 1"))
                return
            except SQLAlchemyError as exc:
                with self._guard:
                    if self._connection is not connection:
                        return  # released meanwhile (a stop)
                    self._connection = None
                connection.invalidate()
                log.warning(
                    "lost the database connection holding this server's lock (%s); %s",
                    reason(exc),
                    "still driving every machine (cluster = false: the only server), taking "
                    "it again once the database answers"
                    if self.alone
                    else "taking it again once the database answers",
                )
                return
        try:
            taken = self._take()
        except SQLAlchemyError:
            return  # still away: said when it was lost
        if taken:
            self._refused = False
            log.warning("this server holds its lock on the database again")
        elif not self._stopped and not self._refused:
            self._refused = True
            log.error(
                "could not take this server's lock on the database again: another server took "
                "it meanwhile (%s)",
                "two servers may now drive the same machines"
                if self.alone
                else "a server with cluster = false",
            )

    async def run(self) -> None:
        while True:
            await asyncio.sleep(self.every)
            await asyncio.to_thread(self.check)

    def release(self) -> None:
        """Give the lock back (closing its connection ends its session)."""
        with self._guard:
            self._stopped = True
            connection, self._connection = self._connection, None
        if connection is not None:
            try:
                connection.close()
            except SQLAlchemyError:
                connection.invalidate()
        self._engine.dispose()

    async def stop(self) -> None:
        await super().stop()
        await asyncio.to_thread(self.release)
