"""Machines read through an MTConnect agent: the agent's words put into the status model.

The reader (:mod:`opendnc.mtconnect.reader`) follows the agent's sample stream in a task of
its own; a status poll takes the latest values it holds, so a poll costs no request. What an
agent says maps one to one where our model already speaks MTConnect (execution, controller
mode, program, line, part count); an E-stop pressed and every active Fault condition become
the status's errors, with the condition's text, so the one classifier
(:func:`opendnc.server.core.state.classify`) files the machine as in alarm
(docs/mtconnect-input.md#mapping).
"""

from __future__ import annotations

import asyncio
import contextlib

from opendnc.errors import DncError, TransportError
from opendnc.mtconnect.device_state import Snapshot
from opendnc.mtconnect.reader import AgentReader
from opendnc.server.core.status import MachineStatus
from opendnc.server.kinds.connector import StatusOnly
from opendnc.server.kinds.mtconnect.schema import MtconnectMachine
from opendnc.server.store.models import utcnow

__all__ = ["EMERGENCY_STOP", "MtconnectConnector", "agent_status"]

EMERGENCY_STOP = "EMERGENCY STOP"
"""The error a TRIGGERED EmergencyStop puts into the status."""

STREAM_INTERVAL = 0.1  # seconds: the agent sends what changed at most this often
HEARTBEAT = 1.0  # seconds: a quiet stream still sends an empty document this often

_EXECUTION = frozenset(
    {
        "READY", "ACTIVE", "INTERRUPTED", "FEED_HOLD", "STOPPED", "OPTIONAL_STOP",
        "PROGRAM_STOPPED", "PROGRAM_COMPLETED", "WAIT",
    }
)  # fmt: skip
# Later versions of the standard name the M01 stop PROGRAM_OPTIONAL_STOP: our model's word is
# the older OPTIONAL_STOP (the classifier and the outputs know that one).
_ALIASES = {"PROGRAM_OPTIONAL_STOP": "OPTIONAL_STOP"}
_MODES = frozenset({"AUTOMATIC", "MANUAL", "MANUAL_DATA_INPUT", "SEMI_AUTOMATIC", "EDIT"})


def agent_status(snapshot: Snapshot) -> MachineStatus:
    """The status for what the agent reports; a word outside MTConnect's is UNAVAILABLE."""
    errors = list(snapshot.faults)
    if snapshot.emergency_stop == "TRIGGERED":
        errors.insert(0, EMERGENCY_STOP)
    execution = snapshot.execution or "UNAVAILABLE"
    execution = _ALIASES.get(execution, execution)
    mode = snapshot.controller_mode or ""
    available = snapshot.availability == "AVAILABLE"
    return MachineStatus(
        at=utcnow(),
        available=available,
        # the agent answers, but not for the machine: say whose word "offline" is
        message="" if available else "the agent reports the machine UNAVAILABLE",
        execution=execution if execution in _EXECUTION else "UNAVAILABLE",
        mode=mode if mode in _MODES else "",
        # the agent's word beside ours only where it is not already MTConnect's own
        native_mode="" if mode in _MODES else mode,
        program=snapshot.program or "",
        line=snapshot.line or 0,
        part_count=snapshot.part_count,
        tool=snapshot.tool,
        errors=tuple(errors),
    )


class MtconnectConnector(StatusOnly):
    """One device of an agent, followed in a task while the link is up."""

    through = "an MTConnect agent (read-only)"

    config: MtconnectMachine

    def __init__(self, config: MtconnectMachine) -> None:
        self.config = config
        self._reader: AgentReader | None = None
        self._follow: asyncio.Task[None] | None = None

    async def connect(self) -> None:
        """Probe the agent, read current, start following its stream."""
        if self._reader is None:
            self._reader = AgentReader(
                self.config.url,
                self.config.device,
                interval=STREAM_INTERVAL,
                heartbeat=HEARTBEAT,
                poll=self.config.poll_interval,
                streaming=self.config.streaming,
            )
        await self._reader.open()
        self._follow = asyncio.create_task(
            self._reader.follow(), name=f"mtconnect-{self.config.name}"
        )

    async def close(self) -> None:
        """Stop following and close the HTTP client."""
        follow, self._follow = self._follow, None
        if follow is not None:
            follow.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await follow
        reader, self._reader = self._reader, None
        if reader is not None:
            await reader.close()

    @property
    def reader(self) -> AgentReader | None:
        """The agent reader while connected (its counts say what the link went through)."""
        return self._reader

    async def status(self) -> MachineStatus:
        """The latest values the stream brought; raises what ended the stream."""
        if self._reader is None or self._follow is None:
            raise TransportError(f"{self.config.name}: not connected")
        if self._follow.done():
            error = self._follow.exception()
            if isinstance(error, DncError):
                raise error
            raise TransportError(f"{self.config.name}: the agent reader stopped: {error!r}")
        return agent_status(self._reader.snapshot())
