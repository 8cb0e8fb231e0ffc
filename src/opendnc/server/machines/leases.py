"""Machine leases: several servers on one PostgreSQL database, each machine served by one.

A server that shares its database with others serves a machine (status, listening, jobs,
auto-receive, DPRNT) only while it holds that machine's lease: a row with an owner and an
expiry on the database's clock, renewed every few seconds (docs/server.md#several-servers).
A server that dies stops renewing; once its leases expire the others take its machines.

Who should serve what is computed, not negotiated: every server reads the same live servers
and the same machines and computes the same :func:`assign` — rendezvous hashing with a cap,
so machines spread evenly and few move when a server comes or goes. A server never takes a
lease that is still live: the owner hands a machine over (at a safe point, when nothing runs
there) once another live server is assigned it, and the new owner takes the free row. So a
server that starts takes its share without two servers fighting over the same machines.

All times are the database's: ``now()`` read at the start of each renewal's transaction, so
servers whose clocks disagree still agree on who is alive and whose lease ran out. SQLite
serves one server only (:mod:`opendnc.server.cluster.single_server`); this module then runs on the
process's clock with the same code.
"""

from __future__ import annotations

import hashlib
import os
import socket
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

from sqlalchemy import delete, func, select, text, update
from sqlalchemy.dialects.postgresql import insert as pg_insert
from sqlalchemy.dialects.sqlite import insert as sqlite_insert
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.store.models import ClusterServer, Job, JobState, MachineLease, utcnow

__all__ = [
    "LIBRARY",
    "ClusterView",
    "Holding",
    "LeaseRow",
    "Leases",
    "ServerRow",
    "assign",
    "held_elsewhere",
    "holds",
    "view_in",
]

LIBRARY = "@library"  # the lease of the shop-wide duties: the library watcher and the net share

DEFAULT_TTL = (
    10.0  # seconds a lease lasts unrenewed: the failover time is about this plus a renewal
)


def _score(machine: str, server: str) -> bytes:
    # Rendezvous hashing: each (machine, server) pair gets a stable pseudo-random rank.
    return hashlib.sha256(f"{machine}\0{server}".encode()).digest()


def _ranked(machine: str, servers: frozenset[str]) -> list[str]:
    return sorted(servers, key=lambda server: _score(machine, server), reverse=True)


def assign(machines: Mapping[str, frozenset[str]], live: frozenset[str]) -> dict[str, str]:
    """Which live server should serve each machine.

    ``machines`` maps each machine to the servers it is pinned to (empty: any server). A
    machine whose pinned servers are all down is left out. Machines spread within one of
    each other: the most constrained are placed first, each on its best-ranked server that
    is below the even share, else on its least loaded candidate.
    """
    if not live:
        return {}
    # An even share: every server gets `base` machines and `extra` of them one more.
    base, extra = divmod(len(machines), len(live))
    load = dict.fromkeys(live, 0)
    candidates = {m: _ranked(m, pins & live if pins else live) for m, pins in machines.items()}
    out: dict[str, str] = {}
    order = sorted(candidates, key=lambda m: (len(candidates[m]), _score(m, "")))
    for machine in order:
        ranked = candidates[machine]
        if not ranked:
            continue
        below = [s for s in ranked if load[s] < base or (load[s] == base and extra > 0)]
        chosen = below[0] if below else min(ranked, key=lambda s: load[s])
        if load[chosen] == base:
            extra -= 1
        load[chosen] += 1
        out[machine] = chosen
    return out


@dataclass(frozen=True)
class Holding:
    """What one renewal changed: the machines to start and stop serving, and all held now."""

    held: frozenset[str]
    gained: frozenset[str]
    lost: frozenset[str]  # expired and taken by another server, or released by a hand-over
    epochs: Mapping[str, int]  # the epoch of each held lease (fencing)
    valid_until: float  # time.monotonic() after which the leases may be someone else's


@dataclass(frozen=True)
class ServerRow:
    """One server of the cluster, as ``opendnc cluster status`` shows it."""

    name: str
    host: str
    pid: int
    url: str
    started: datetime
    heartbeat_age: float  # seconds since its last heartbeat, on the database's clock
    alive: bool
    machines: int


@dataclass(frozen=True)
class LeaseRow:
    """One machine's lease."""

    machine: str
    owner: str
    epoch: int
    expires_in: float  # seconds; negative when expired
    live: bool


@dataclass(frozen=True)
class ClusterView:
    """The cluster as the database sees it now."""

    now: datetime
    servers: tuple[ServerRow, ...]
    leases: tuple[LeaseRow, ...]


class Leases:
    """One server's side of the machine leases (blocking: call it from a worker thread)."""

    def __init__(
        self,
        sessions: sessionmaker[Session],
        server: str,
        machines: Mapping[str, frozenset[str]],
        *,
        ttl: float = DEFAULT_TTL,
        url: str = "",
    ) -> None:
        self.sessions = sessions
        self.server = server
        # only the machines this server may serve; the others never concern it
        self.machines = {m: pins for m, pins in machines.items() if not pins or server in pins}
        self.all_machines = dict(machines)
        self.ttl = timedelta(seconds=ttl)
        self.url = url
        self.held: frozenset[str] = frozenset()
        self.valid_until = 0.0
        self._started: datetime | None = None

    def _now(self, session: Session, lock_limit: float | None = None) -> datetime:
        if session.get_bind().dialect.name == "postgresql":
            if lock_limit is not None:
                # In the same round trip: this transaction's statements, and its silences
                # between them, end after lock_limit (the leases' rows it locks are free
                # again soon after a network cut, however the cut looks from here).
                limit = str(max(100, int(lock_limit * 1000)))
                value = (
                    session.execute(
                        text(
                            "SELECT now(), set_config('statement_timeout', :limit, true),"
                            " set_config('idle_in_transaction_session_timeout', :limit, true)"
                        ),
                        {"limit": limit},
                    )
                    .scalars()
                    .first()
                )
                assert isinstance(value, datetime)
                return value
            value = session.execute(text("SELECT now()")).scalar_one()
            assert isinstance(value, datetime)
            return value
        return utcnow()

    def _insert(self, session: Session) -> Callable[..., object]:
        return pg_insert if session.get_bind().dialect.name == "postgresql" else sqlite_insert

    def _heartbeat(self, session: Session, now: datetime) -> None:
        if self._started is None:
            self._started = now
        values = {
            "name": self.server,
            "host": socket.gethostname()[:255],
            "pid": os.getpid(),
            "url": self.url[:255],
            "lease_seconds": self.ttl.total_seconds(),
            "started": self._started,
            "heartbeat": now,
        }
        insert = self._insert(session)
        statement = insert(ClusterServer).values(**values)  # type: ignore[attr-defined]
        session.execute(
            statement.on_conflict_do_update(
                index_elements=[ClusterServer.name],
                set_={k: statement.excluded[k] for k in values if k != "name"},
            )
        )

    def live_servers(self, session: Session, now: datetime) -> frozenset[str]:
        """The servers whose heartbeat is younger than a lease."""
        rows = session.scalars(
            select(ClusterServer.name).where(ClusterServer.heartbeat > now - self.ttl)
        )
        return frozenset(rows) | {self.server}

    def renew(
        self,
        *,
        can_hand_over: Callable[[str], bool] = lambda _m: True,
        lock_limit: float | None = None,
    ) -> Holding:
        """Heartbeat, renew what this server holds, hand over and take what is due.

        ``can_hand_over(machine)`` says whether a machine is at a safe point (no job running):
        a machine assigned to another live server is released only then. ``lock_limit``
        (seconds, PostgreSQL): the transaction ends after a statement or a silence this long.
        """
        # The leases run from before the transaction began: however long it takes, this
        # server stops trusting them no later than the database lets another take them.
        began = time.monotonic()
        with self.sessions.begin() as session:
            now = self._now(session, lock_limit)
            self._heartbeat(session, now)
            wanted = self._wanted(self.live_servers(session, now))
            leases = self._lease_rows(session)
            mine = {
                m for m, row in leases.items() if row.owner == self.server and m in self.machines
            }
            hand_over = {
                m for m in mine if wanted.get(m, self.server) != self.server and can_hand_over(m)
            }
            hand_over = self._hand_over(session, hand_over, now)
            renewed = self._extend(session, mine - hand_over, now)
            free, new = self._due(leases, wanted, renewed | hand_over, now)
            renewed |= self._take(session, free, new, now)
            epochs = self._epochs(session)
        return self._hold(frozenset(renewed), epochs, began)

    def _wanted(self, live: frozenset[str]) -> dict[str, str]:
        """Which live server each machine and duty is assigned to."""
        # The duties (names with "@", never a machine's) are placed apart from the
        # machines, so they do not skew the machines' even share.
        duties = {m: p for m, p in self.all_machines.items() if m.startswith("@")}
        wanted = assign({m: p for m, p in self.all_machines.items() if m not in duties}, live)
        wanted.update(assign(duties, live))
        return wanted

    @staticmethod
    def _lease_rows(session: Session) -> dict[str, Any]:
        """Every lease row (machine, owner, expires), by machine."""
        # plain rows, not ORM objects: an ORM object per machine would also make each
        # UPDATE below evaluate its condition on all of them (a thousand machines: most
        # of a renewal's CPU)
        return {
            row.machine: row
            for row in session.execute(
                select(MachineLease.machine, MachineLease.owner, MachineLease.expires)
            )
        }

    def _hand_over(self, session: Session, hand_over: set[str], now: datetime) -> set[str]:
        """Release those of ``hand_over`` that run no job; which were released."""
        if not hand_over:
            return hand_over
        # Never hand over a machine with a job running: lock the rows first (a claim
        # under way holds its lease row and commits before), then look for running
        # jobs in a statement of its own, which sees that claim.
        locked = set(
            session.scalars(
                select(MachineLease.machine)
                .where(MachineLease.machine.in_(hand_over), MachineLease.owner == self.server)
                .with_for_update()
            )
        )
        busy = set(
            session.scalars(
                select(Job.machine).where(Job.machine.in_(locked), Job.state == JobState.RUNNING)
            )
        )
        hand_over = locked - busy
        if hand_over:
            session.execute(
                update(MachineLease)
                .where(MachineLease.machine.in_(hand_over), MachineLease.owner == self.server)
                .values(owner="", expires=now)
            )
        return hand_over

    def _extend(self, session: Session, keep: set[str], now: datetime) -> set[str]:
        """Renew this server's leases of ``keep``; which it still held."""
        if not keep:
            return set()
        return set(
            session.scalars(
                update(MachineLease)
                .where(MachineLease.machine.in_(keep), MachineLease.owner == self.server)
                .values(expires=now + self.ttl)
                .returning(MachineLease.machine)
            )
        )

    def _due(
        self, leases: dict[str, Any], wanted: dict[str, str], settled: set[str], now: datetime
    ) -> tuple[list[str], list[str]]:
        """The machines to take, besides ``settled`` (renewed or handed over just now): those
        whose row is free (expired or released), and those without a row yet."""
        grace = self.ttl / 2  # a free machine waits this long for the server assigned it
        free: list[str] = []  # rows there but expired or released
        new: list[str] = []  # no row yet
        for machine in sorted(self.machines):
            if machine in settled:
                continue
            row = leases.get(machine)
            free_since = None if row is None else row.expires
            if row is not None and row.owner and row.expires > now:
                continue  # live elsewhere: never taken
            due = wanted.get(machine) == self.server
            if not due and free_since is not None and free_since > now - grace:
                continue
            (new if row is None else free).append(machine)
        return free, new

    def _epochs(self, session: Session) -> dict[str, int]:
        """The epoch of each lease this server holds."""
        return {
            machine: epoch
            for machine, epoch in session.execute(
                select(MachineLease.machine, MachineLease.epoch).where(
                    MachineLease.owner == self.server
                )
            )
        }

    def _hold(self, held: frozenset[str], epochs: dict[str, int], began: float) -> Holding:
        """Note ``held`` as what this server holds now; what changed since the last time."""
        holding = Holding(
            held=held,
            gained=held - self.held,
            lost=self.held - held,
            epochs={m: e for m, e in epochs.items() if m in held},
            valid_until=began + self.ttl.total_seconds(),
        )
        self.held = held
        self.valid_until = holding.valid_until
        return holding

    def serving(self) -> frozenset[str]:
        """The machines this server may act on now: held, and not past the lease."""
        return self.held if time.monotonic() < self.valid_until else frozenset()

    def _take(self, session: Session, free: list[str], new: list[str], now: datetime) -> set[str]:
        """Take the ``free`` rows (expired or released) and insert the ``new`` ones, in two
        statements however many: a server taking hundreds of machines must not spend its
        lease on round trips. A row another server is taking right now is skipped (``SKIP
        LOCKED``), a row that turned live meanwhile is not taken (the condition is checked
        again under the lock), and a row another server just inserted is left to it: a live
        lease is never taken, and two servers' renewals never wait on each other."""
        taken: set[str] = set()
        if free:
            lockable = (
                select(MachineLease.machine)
                .where(
                    MachineLease.machine.in_(free),
                    (MachineLease.expires <= now) | (MachineLease.owner == ""),
                )
                .order_by(MachineLease.machine)
                .with_for_update(skip_locked=True)
            )
            taken |= set(
                session.scalars(
                    update(MachineLease)
                    .where(
                        MachineLease.machine.in_(lockable.scalar_subquery()),
                        (MachineLease.expires <= now) | (MachineLease.owner == ""),
                    )
                    .values(
                        owner=self.server,
                        epoch=MachineLease.epoch + 1,
                        acquired=now,
                        expires=now + self.ttl,
                    )
                    .returning(MachineLease.machine)
                )
            )
        if new:
            insert = self._insert(session)
            statement = insert(MachineLease).values(  # type: ignore[attr-defined]
                [
                    {
                        "machine": machine,
                        "owner": self.server,
                        "epoch": 1,
                        "acquired": now,
                        "expires": now + self.ttl,
                    }
                    for machine in sorted(new)
                ]
            )
            taken |= set(
                session.scalars(
                    statement.on_conflict_do_nothing(
                        index_elements=[MachineLease.machine]
                    ).returning(MachineLease.machine)
                )
            )
        return taken

    def release_all(self) -> None:
        """A clean stop: free every lease at once and leave the cluster."""
        with self.sessions.begin() as session:
            now = self._now(session)
            session.execute(
                update(MachineLease)
                .where(MachineLease.owner == self.server)
                .values(owner="", expires=now)
            )
            session.execute(delete(ClusterServer).where(ClusterServer.name == self.server))
        self.held = frozenset()

    def view(self) -> ClusterView:
        """Servers, heartbeats and leases as the database sees them now."""
        return cluster_view(self.sessions)


def holds(
    session: Session, machine: str, server: str, epoch: int, lock_limit: float | None = None
) -> bool:
    """True while ``server`` holds ``machine``'s lease at ``epoch`` (fencing).

    The row stays locked (``FOR SHARE``) until ``session``'s transaction ends, so no other
    server can take the lease between this check and the commit of what it guards: a job's
    claim, its end, its progress. A lease that ran out but was not taken yet still holds: no
    other server has acted on the machine, since taking it raises the epoch. ``lock_limit``
    (seconds, PostgreSQL): the transaction ends when it stays silent this long, so a server
    cut off in the middle of it does not keep the row locked.
    """
    columns: list[Any] = [MachineLease.epoch]
    if lock_limit is not None and session.get_bind().dialect.name == "postgresql":
        limit = str(max(100, int(lock_limit * 1000)))
        columns.append(func.set_config("idle_in_transaction_session_timeout", limit, True))
    found = session.execute(
        select(*columns)
        .where(MachineLease.machine == machine, MachineLease.owner == server)
        .with_for_update(read=True)
    ).first()
    return found is not None and int(found[0]) == epoch


def held_elsewhere(sessions: sessionmaker[Session], server: str) -> set[str]:
    """The machines whose live lease another server than ``server`` holds now."""
    view = cluster_view(sessions)
    return {row.machine for row in view.leases if row.live and row.owner != server}


def cluster_view(sessions: sessionmaker[Session]) -> ClusterView:
    """Servers, heartbeats and leases of the database behind ``sessions``."""
    with sessions() as session:
        return view_in(session)


def view_in(session: Session) -> ClusterView:
    """Servers, heartbeats and leases as ``session``'s database sees them now."""
    if session.get_bind().dialect.name == "postgresql":
        now = session.execute(text("SELECT now()")).scalar_one()
    else:
        now = utcnow()
    leases = list(session.scalars(select(MachineLease).order_by(MachineLease.machine)))
    servers = list(session.scalars(select(ClusterServer).order_by(ClusterServer.name)))
    counts: dict[str, int] = {}
    for row in leases:
        if row.owner and row.expires > now and not row.machine.startswith("@"):
            counts[row.owner] = counts.get(row.owner, 0) + 1
    return ClusterView(
        now=now,
        servers=tuple(
            ServerRow(
                name=s.name,
                host=s.host,
                pid=s.pid,
                url=s.url,
                started=s.started,
                heartbeat_age=(now - s.heartbeat).total_seconds(),
                alive=(now - s.heartbeat).total_seconds() < s.lease_seconds,
                machines=counts.get(s.name, 0),
            )
            for s in servers
        ),
        leases=tuple(
            LeaseRow(
                machine=row.machine,
                owner=row.owner,
                epoch=row.epoch,
                expires_in=(row.expires - now).total_seconds(),
                live=bool(row.owner) and row.expires > now,
            )
            for row in leases
        ),
    )
