"""Refused logins and keys, summed per minute into audit rows (docs/server.md#throttling).

A script with a wrong key, or someone guessing a password, may try hundreds of times a
minute. A row per try fills the audit table and costs a write transaction per try (on the
very path the throttle is meant to keep cheap); dropping the throttled ones, as before, lost
most of them (158 attempts, 38 rows). Each refusal is counted here in memory under its
minute, source (``via`` and address) and actor (the user name tried, or ``api`` for a key);
this component writes one ``login`` row with result ``refused`` per such group, carrying the
``count`` (of which ``throttled`` were answered 429), the first and last time, the last reason
and the ``names`` tried (the keys' prefixes; at most :data:`NAMES`, ``more_names`` counts the
rest), so a script sending a new wrong key each time is still one row a minute. Every
:data:`FLUSH_EVERY` seconds it writes the groups whose minute has ended, and everything at a
stop: a row appears within two minutes of its first refusal.
"""

from __future__ import annotations

import asyncio
import logging
import threading
from dataclasses import dataclass
from datetime import datetime

from sqlalchemy.exc import SQLAlchemyError
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.core.components import RunsTask
from opendnc.server.store import audit
from opendnc.server.store.models import utcnow

__all__ = ["FLUSH_EVERY", "Refusals"]

log = logging.getLogger(__name__)

FLUSH_EVERY = 60.0
_GROUPS = 10_000  # groups held between two writes; beyond, new groups fold into one
NAMES = 10  # names kept per group


@dataclass
class _Group:
    count: int
    throttled: int
    first: datetime
    last: datetime
    error: str
    names: list[str]
    more_names: int = 0

    def add(self, other: _Group) -> None:
        self.count += other.count
        self.throttled += other.throttled
        self.first = min(self.first, other.first)
        self.last = max(self.last, other.last)
        self.error = other.error
        for name in other.names:
            self.name(name)
        self.more_names += other.more_names

    def name(self, name: str) -> None:
        if name in self.names:
            return
        if len(self.names) < NAMES:
            self.names.append(name)
        else:
            self.more_names += 1


_Key = tuple[str, str, str, str]  # minute, actor, via, address


class Refusals(RunsTask):
    """Refusals counted since the last write, and the task that writes them (a component)."""

    name = "refusals"
    needs = ("database",)

    def __init__(self, sessions: sessionmaker[Session], every: float = FLUSH_EVERY) -> None:
        self.sessions = sessions
        self.every = every
        self._groups: dict[_Key, _Group] = {}
        self._lock = threading.Lock()  # requests note from worker threads

    def note(
        self,
        *,
        actor: str,
        via: str,
        address: str,
        name: str,
        error: str,
        throttled: bool = False,
        when: datetime | None = None,
    ) -> None:
        """One refused try by ``actor`` (a user name, or ``api``) at ``name``."""
        at = when or utcnow()
        minute = at.strftime("%Y-%m-%dT%H:%M")
        key = (minute, actor[:64], via, address[:64])
        one = _Group(1, int(throttled), at, at, error, [name[:64]])
        with self._lock:
            if key not in self._groups and len(self._groups) >= _GROUPS:
                key = (minute, "*", via, "*")  # a flood of sources: counted, not itemised
            group = self._groups.get(key)
            if group is None:
                self._groups[key] = one
            else:
                group.add(one)

    def pending(self) -> int:
        """Refusals counted but not yet written."""
        with self._lock:
            return sum(g.count for g in self._groups.values())

    def flush(self, *, everything: bool = False) -> int:
        """Write a row per group whose minute has ended (``everything``: every group) in one
        transaction (blocking); the number of rows.

        What could not be written (the database is away) is kept for the next try."""
        current = utcnow().strftime("%Y-%m-%dT%H:%M")
        with self._lock:
            groups = {k: g for k, g in self._groups.items() if everything or k[0] < current}
            for key in groups:
                del self._groups[key]
        if not groups:
            return 0
        try:
            with self.sessions.begin() as session:
                for (_minute, actor, via, address), g in groups.items():
                    audit.record(
                        session,
                        actor,
                        "login",
                        result="refused",
                        via=via,
                        address=address,
                        names=g.names,
                        more_names=g.more_names,
                        count=g.count,
                        throttled=g.throttled,
                        first=g.first.isoformat(),
                        last=g.last.isoformat(),
                        error=g.error,
                    )
        except SQLAlchemyError:
            with self._lock:
                for key, g in groups.items():
                    now = self._groups.get(key)
                    if now is None:
                        self._groups[key] = g
                    else:
                        now.add(g)
            raise
        return len(groups)

    async def run(self) -> None:
        """Write the counted refusals every :attr:`every` seconds."""
        while True:
            await asyncio.sleep(self.every)
            try:
                await asyncio.to_thread(self.flush)
            except SQLAlchemyError as exc:
                log.warning("could not write the refused logins (kept for the next try): %s", exc)

    async def stop(self) -> None:
        """Stop the task and write what is left."""
        await super().stop()
        try:
            await asyncio.to_thread(lambda: self.flush(everything=True))
        except SQLAlchemyError as exc:
            log.warning("could not write the refused logins at the stop: %s", exc)
