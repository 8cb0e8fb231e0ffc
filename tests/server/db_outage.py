"""Cutting the server's database for the runner's robustness tests: PostgreSQL refuses new
connections to the test's own database and drops its sessions; SQLite is locked by another
connection holding an exclusive transaction."""

from __future__ import annotations

import sqlite3
from pathlib import Path
from typing import Any

from sqlalchemy import create_engine, event, text
from sqlalchemy.engine import Engine, make_url

from tests.server.conftest import PG_ADMIN


class Outage:
    """``cut()`` and ``restore()`` the database at ``url`` (only that one database)."""

    def __init__(self, url: str) -> None:
        self.url = make_url(url)
        self._lock: sqlite3.Connection | None = None
        self._admin: Engine | None = None
        if self.url.get_backend_name() == "postgresql":
            self._admin = create_engine(PG_ADMIN, isolation_level="AUTOCOMMIT")

    @property
    def sqlite(self) -> bool:
        return self._admin is None

    def quicken(self, engine: Engine) -> None:
        """SQLite waits 30 s for a lock by default; a test wants "locked" within 1 s, so the
        server's connections are made again with a short busy timeout."""
        if not self.sqlite:
            return

        def short(dbapi: Any, _record: Any) -> None:
            dbapi.execute("PRAGMA busy_timeout=1000")

        event.listen(engine, "connect", short)
        engine.dispose()

    def cut(self) -> None:
        if self._admin is None:
            path = Path(str(self.url.database))
            self._lock = sqlite3.connect(path, isolation_level=None, timeout=30)
            self._lock.execute("BEGIN EXCLUSIVE")
            return
        name = self.url.database
        with self._admin.connect() as conn:
            conn.execute(text(f'ALTER DATABASE "{name}" ALLOW_CONNECTIONS false'))
            conn.execute(
                text(
                    "SELECT pg_terminate_backend(pid) FROM pg_stat_activity "
                    "WHERE datname = :name AND pid <> pg_backend_pid()"
                ),
                {"name": name},
            )

    def restore(self) -> None:
        if self._admin is None:
            if self._lock is not None:
                self._lock.execute("ROLLBACK")
                self._lock.close()
                self._lock = None
            return
        with self._admin.connect() as conn:
            conn.execute(text(f'ALTER DATABASE "{self.url.database}" ALLOW_CONNECTIONS true'))

    def close(self) -> None:
        self.restore()
        if self._admin is not None:
            self._admin.dispose()
