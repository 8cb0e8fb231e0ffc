"""One server alone: SQLite always, PostgreSQL with ``[server] cluster = false``.

SQLite serves one server: a second server on the same file is refused with one line.

Several servers coordinate through PostgreSQL (:mod:`opendnc.server.leases`); SQLite has no
shared clock, row locks or notifications, and two servers on one file would both serve every
machine. The guard is an operating-system lock on a file beside the database, held for the
server's life: the system drops it when the process ends, however it ends, so a crashed
server never locks the next one out.

On PostgreSQL a server configured as the only one (``cluster = false``) takes no leases and
never fences itself: it drives its machines through a database outage. It refuses to start
while another live server of a cluster holds leases or heartbeats there
(:func:`refuse_beside_a_cluster`), since both would drive the same machines.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import IO

from sqlalchemy.engine import make_url
from sqlalchemy.orm import Session, sessionmaker

from opendnc.errors import DncError
from opendnc.server.leases import cluster_view

__all__ = ["DatabaseInUse", "SingleServerLock", "refuse_beside_a_cluster"]


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
