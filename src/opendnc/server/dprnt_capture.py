"""DPRNT capture in the server: every line a machine prints is stored and published.

A machine whose configuration names a source (``dprnt = "tcp://HOST:PORT"``, where a Haas NGC
prints with Setting 261 = TCP port and Setting 263 = the port) gets one
:class:`~opendnc.haas.listen.DprntListener` on a thread of its own beside the machine's task:
it reconnects with backoff by itself, keeps a line cut by a broken link (marked incomplete),
and a machine that is away never holds up another. Each line becomes a ``dprnt_lines`` row and
an event of kind ``dprnt`` on the bus; the API serves them (``/api/machines/{name}/dprnt``).
The newest line also goes to ``on_line`` (the supervisor), which puts it into the machine's
status (docs/server.md#dprnt-capture).

A Haas on RS-232 prints on the port its connector owns for XModem and MDC
(``dprnt = "serial"``): :meth:`DprntCapture.attach` gives that connector the same sink, and
the connector picks the lines off the port (:mod:`opendnc.server.machines.dprnt_tap`,
docs/haas.md#dprnt-over-serial).
"""

from __future__ import annotations

import asyncio
import logging
import threading
from collections.abc import Callable, Sequence
from datetime import datetime
from typing import Any

from sqlalchemy.orm import Session, sessionmaker

from opendnc.haas.listen import CapturedLine, DprntListener, open_source
from opendnc.server.config import MachineConfig
from opendnc.server.events import DprntLinePrinted, DprntStatus, EventBus
from opendnc.server.store.models import DprntLine
from opendnc.transport.base import ByteStream

__all__ = ["DprntCapture", "DprntSink", "LineHook", "line_json"]

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
    """One listener thread per machine with a DPRNT source; :meth:`start` / :meth:`stop`."""

    def __init__(
        self,
        machines: Sequence[MachineConfig],
        sessions: sessionmaker[Session],
        bus: EventBus,
        *,
        opener: Callable[[str], ByteStream] = open_source,
        backoff_max: float = 10.0,
        on_line: LineHook | None = None,
    ) -> None:
        self.sessions = sessions
        self.bus = bus
        self.on_line = on_line
        self.status: dict[str, str] = {}  # machine -> the listener's last word
        self.listeners: dict[str, DprntListener] = {}
        for machine in machines:
            if machine.dprnt and machine.dprnt != "serial":
                self.listeners[machine.name] = DprntListener(
                    machine.dprnt,
                    [DprntSink(machine.name, sessions, bus, self._line)],
                    opener=opener,
                    backoff_max=backoff_max,
                    on_status=self._on_status(machine.name),
                )
        self._threads: list[threading.Thread] = []

    def attach(self, machine: MachineConfig, connector: object) -> None:
        """Give a serial connector with ``dprnt = "serial"`` the sink for its printed lines."""
        if machine.dprnt == "serial" and hasattr(connector, "on_dprnt"):
            sink = DprntSink(machine.name, self.sessions, self.bus, self._line)
            connector.on_dprnt = sink.write
            self.status[machine.name] = f"capturing on {machine.serial}"

    def _line(self, machine: str, text: str, at: datetime) -> None:
        # looked up at each line: the hook is set once the supervisor exists
        if self.on_line is not None:
            self.on_line(machine, text, at)

    def _on_status(self, machine: str) -> Callable[[str], None]:
        def report(message: str) -> None:
            self.status[machine] = message
            log.info("%s DPRNT: %s", machine, message)
            self.bus.publish(DprntStatus(machine, message))

        return report

    def start(self) -> None:
        """Start every listener."""
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
        """Stop every listener and wait for its thread (a read ends within its timeout)."""
        for listener in self.listeners.values():
            listener.stop()
        threads, self._threads = self._threads, []
        for thread in threads:
            await asyncio.to_thread(thread.join, 5.0)
