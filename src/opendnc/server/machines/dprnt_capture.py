"""DPRNT capture in the server: every line a machine prints is stored and published.

A machine whose configuration names a source (``dprnt = "tcp://HOST:PORT"``, where a Haas NGC
prints with Setting 261 = TCP port and Setting 263 = the port) gets one
:class:`~opendnc.haas.listen.DprntListener` on a thread of its own beside the machine's task:
it reconnects with backoff by itself, keeps a line cut by a broken link (marked incomplete),
and a machine that is away never holds up another. Each line becomes a ``dprnt_lines`` row and
an event of kind ``dprnt`` on the bus; the API serves them (``/api/machines/{name}/dprnt``).
The newest line also goes into the machine's status (:meth:`Machines.note_dprnt
<opendnc.server.machines.state.Machines.note_dprnt>`, docs/server.md#dprnt-capture).

A Haas on RS-232 prints on the port its connector owns for XModem and MDC
(``dprnt = "serial"``): :meth:`DprntCapture.hooks_for` gives that connector the same sink, and
the connector picks the lines off the port (:mod:`opendnc.server.kinds.dprnt_tap`,
docs/haas.md#dprnt-over-serial).
"""

from __future__ import annotations

import asyncio
import logging
import threading
from collections.abc import Callable
from datetime import datetime
from typing import TYPE_CHECKING, Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session, sessionmaker

from opendnc.haas.listen import CapturedLine, DprntListener, open_source
from opendnc.server.config.shop import MachineConfig
from opendnc.server.core.events import DprntLinePrinted, DprntStatus, EventBus
from opendnc.server.kinds.base import ConnectorHooks
from opendnc.server.kinds.registry import dprnt_of
from opendnc.server.store.models import DprntLine

if TYPE_CHECKING:
    from opendnc.server.machines.state import Machines
from opendnc.transport.base import ByteStream

__all__ = [
    "DprntCapture",
    "DprntSink",
    "LineHook",
    "last_lines",
    "line_json",
    "lines_after",
    "newest_lines",
]

log = logging.getLogger(__name__)

LineHook = Callable[[str, str, datetime], None]
"""Called with (machine, line text, time captured) after each line is stored."""


def line_event(row: DprntLine) -> DprntLinePrinted:
    """A stored line as the event the bus carries."""
    return DprntLinePrinted(
        row.id, row.machine, row.at.isoformat(), row.text, tuple(row.fields), row.complete
    )


def line_json(row: DprntLine) -> dict[str, Any]:
    """A stored line as JSON (``numbers`` in order, ``fields`` with their labels): the same
    as its event's."""
    return line_event(row).as_json()


class DprntSink:
    """A listener sink that stores each line in the database and publishes it."""

    def __init__(
        self,
        machine: str,
        sessions: sessionmaker[Session],
        bus: EventBus,
        on_line: LineHook | None = None,
    ) -> None:
        self.machine = machine
        self.sessions = sessions
        self.bus = bus
        self.on_line = on_line

    def write(self, line: CapturedLine) -> None:
        """Store ``line`` (committed before the next line is read), then publish it."""
        with self.sessions.begin() as session:
            row = DprntLine(
                machine=self.machine,
                at=line.timestamp,
                text=line.text,
                fields=[{"label": f.label, "value": f.value} for f in line.fields],
                complete=line.complete,
            )
            session.add(row)
            session.flush()
            event = line_event(row)
            text, at = row.text, row.at
        self.bus.publish(event)
        if self.on_line is not None:
            self.on_line(self.machine, text, at)

    def close(self) -> None:
        """Nothing to release."""


class DprntCapture:
    """One listener thread per machine with a TCP DPRNT source, and the sink a serial
    connector taps its own port into; a component (``start`` / ``stop``)."""

    name = "dprnt"
    needs = ("machines", "database")

    def __init__(
        self,
        machines: Machines,
        sessions: sessionmaker[Session],
        *,
        opener: Callable[[str], ByteStream] = open_source,
        backoff_max: float = 10.0,
    ) -> None:
        self.machines = machines
        self.sessions = sessions
        self.bus = machines.bus
        self.status: dict[str, str] = {}  # machine -> the listener's last word
        self.listeners: dict[str, DprntListener] = {}
        self._serial: dict[str, DprntSink] = {}
        for machine in machines.config.machines:
            source = dprnt_of(machine)
            if source is None:
                continue
            if source.own_port:
                # A control that prints on the port its connector owns (a serial Haas): the
                # connector gets this sink when it is made (hooks_for) and taps the port.
                self._serial[machine.name] = DprntSink(
                    machine.name, sessions, self.bus, machines.note_dprnt
                )
                self.status[machine.name] = f"capturing on {source.own_port}"
            elif source.url:
                self.listeners[machine.name] = DprntListener(
                    source.url,
                    [DprntSink(machine.name, sessions, self.bus, machines.note_dprnt)],
                    opener=opener,
                    backoff_max=backoff_max,
                    on_status=self._on_status(machine.name),
                )
        self._threads: list[threading.Thread] = []

    def hooks_for(self, machine: MachineConfig) -> ConnectorHooks:
        """What ``machine``'s connector is made with: where the lines it taps go."""
        sink = self._serial.get(machine.name)
        return ConnectorHooks(on_dprnt=sink.write if sink is not None else None)

    def _on_status(self, machine: str) -> Callable[[str], None]:
        def report(message: str) -> None:
            self.status[machine] = message
            log.info("%s DPRNT: %s", machine, message)
            self.bus.publish(DprntStatus(machine, message))

        return report

    async def start(self) -> None:
        """Show each machine's newest stored line again, then start every listener."""

        def newest() -> dict[str, tuple[str, datetime]]:
            with self.sessions() as session:
                return last_lines(session)

        for name, (text, at) in (await asyncio.to_thread(newest)).items():
            if name in self.machines.machines:  # the status keeps showing it after a restart
                self.machines.machines[name].dprnt = (text, at)
        for name, listener in self.listeners.items():
            thread = threading.Thread(
                target=self._run, args=(name, listener), name=f"dprnt-{name}", daemon=True
            )
            thread.start()
            self._threads.append(thread)

    def _run(self, name: str, listener: DprntListener) -> None:
        try:
            listener.run()
        except Exception:  # a bug must not pass silently, nor take the server down
            log.exception("%s: DPRNT capture stopped", name)
            self.status[name] = "capture stopped by an error (see the server log)"

    async def stop(self) -> None:
        """Stop every listener and wait for its thread (a read ends within its timeout; the
        threads are daemons, so one that hangs cannot keep the process alive)."""
        for listener in self.listeners.values():
            listener.stop()
        threads, self._threads = self._threads, []
        await asyncio.gather(*(asyncio.to_thread(t.join, 5.0) for t in threads))


def lines_after(session: Session, machine: str, since: int, limit: int) -> list[dict[str, Any]]:
    """``machine``'s stored lines after id ``since``, oldest first, at most ``limit``."""
    rows = session.scalars(
        select(DprntLine)
        .where(DprntLine.machine == machine, DprntLine.id > since)
        .order_by(DprntLine.id)
        .limit(limit)
    ).all()
    return [line_json(row) for row in rows]


def newest_lines(session: Session, machine: str, limit: int) -> list[dict[str, Any]]:
    """``machine``'s newest ``limit`` stored lines, oldest first (what a console shows)."""
    rows = session.scalars(
        select(DprntLine)
        .where(DprntLine.machine == machine)
        .order_by(DprntLine.id.desc())
        .limit(limit)
    ).all()
    return [line_json(row) for row in reversed(rows)]


def last_lines(session: Session) -> dict[str, tuple[str, datetime]]:
    """Each machine's newest stored DPRNT line (one query; the (machine, id) index serves it)."""
    newest = select(func.max(DprntLine.id)).group_by(DprntLine.machine)
    rows = session.scalars(select(DprntLine).where(DprntLine.id.in_(newest)))
    return {row.machine: (row.text, row.at) for row in rows}
