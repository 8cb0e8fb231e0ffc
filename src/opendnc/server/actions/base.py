"""What every action shares: the services it works with, the caller's role check, and the
transaction helpers that commit before anyone is told (a wake-up, an event)."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar, Protocol, TypeVar

from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.access.auth import KeyCache, Principal
from opendnc.server.access.throttle import Throttle
from opendnc.server.config.shop import ShopConfig
from opendnc.server.core.errors import Forbidden, NotFound
from opendnc.server.core.events import EventBus, InboxChanged, ProgramChanged, publish_job_queued
from opendnc.server.machines.state import MachineState
from opendnc.server.store.models import Role

if TYPE_CHECKING:
    from opendnc.server.actions.models import JobOut

__all__ = ["Caller", "Runner", "Services", "require"]

T = TypeVar("T")

Caller = Principal
"""Who asks: a user's name and role (from an API key or a web session alike)."""


class Runner(Protocol):
    """What the actions need of the machines' runner (the supervisor)."""

    @property
    def config(self) -> ShopConfig: ...

    @property
    def machines(self) -> Mapping[str, MachineState]: ...

    @property
    def bus(self) -> EventBus: ...

    def wake(self, machine: str) -> None: ...


def require(who: Caller, role: Role) -> None:
    """Refuse ``who`` with :class:`Forbidden` unless it has at least ``role``."""
    if not who.can(role):
        raise Forbidden(f"{who.name} is {who.role.name.lower()}; this needs {role.name.lower()}")


@dataclass(frozen=True)
class Services:
    """The database and the machines, as the actions use them (a component of the server's
    core, which the API and the pages get it from).

    ``sessions`` write (each action is one transaction, committed before it wakes a machine
    or tells the event stream); ``reads`` never take SQLite's write lock; ``guard`` slows
    down repeated failed logins and keys, ``keys`` keeps keys checked a moment ago (both per
    process)."""

    sessions: sessionmaker[Session]
    reads: sessionmaker[Session]
    runner: Runner
    guard: Throttle = field(default_factory=Throttle)
    keys: KeyCache = field(default_factory=KeyCache)
    name: ClassVar[str] = "actions"
    needs: ClassVar[tuple[str, ...]] = ("database", "machines")

    async def start(self) -> None:
        """Nothing to start: every action runs in its caller's request."""

    async def stop(self) -> None:
        """Nothing to stop."""

    def write(self, work: Callable[[Session], T]) -> T:
        """Run ``work`` in one write transaction (committed when it returns)."""
        with self.sessions.begin() as session:
            return work(session)

    def read(self, work: Callable[[Session], T]) -> T:
        """Run ``work`` in a read-only transaction."""
        with self.reads() as session:
            return work(session)

    def machine(self, name: str) -> MachineState:
        """The configured machine ``name``; :class:`NotFound` otherwise."""
        state = self.runner.machines.get(name)
        if state is None:
            raise NotFound(f"no machine named {name!r}")
        return state

    def changed(self, news: ProgramChanged | InboxChanged) -> None:
        """Tell the event stream that a program of the library or a reception of the inbox
        changed (after the commit: a page that reloads its list must see the change)."""
        self.runner.bus.publish(news)

    def queued(self, queued: Sequence[JobOut]) -> None:
        """Announce jobs just committed to the queue (a ``queued`` job event each, with
        program and version) and wake their machines."""
        for job in queued:
            publish_job_queued(
                self.runner.bus,
                job_id=job.id,
                machine=job.machine,
                job_kind=job.kind,
                program=job.program,
                version=job.version,
                by=job.created_by,
            )
        self.wake([job.machine for job in queued])

    def wake(self, machines: list[str]) -> None:
        """Tell the machines' tasks that a job may be waiting (after the commit)."""
        for name in dict.fromkeys(machines):
            self.runner.wake(name)
