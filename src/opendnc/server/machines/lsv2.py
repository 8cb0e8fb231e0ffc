"""Heidenhain controls over LSV2 (TCP)."""

from __future__ import annotations

import contextlib

from opendnc.errors import DncError, TransportError
from opendnc.lsv2 import AsyncClient
from opendnc.lsv2.constants import ExecutionMode, ProgramState
from opendnc.server.config import MachineConfig
from opendnc.server.machines.base import MachineStatus, Progress
from opendnc.server.store.models import utcnow

__all__ = ["Lsv2Connector"]

# LSV2 program states in MTConnect's EXECUTION vocabulary.
_EXECUTION = {
    ProgramState.STARTED: "ACTIVE",
    ProgramState.STOPPED: "STOPPED",
    ProgramState.FINISHED: "PROGRAM_COMPLETED",
    ProgramState.CANCELLED: "STOPPED",
    ProgramState.INTERRUPTED: "INTERRUPTED",
    ProgramState.ERROR: "STOPPED",
    ProgramState.ERROR_CLEARED: "READY",
    ProgramState.IDLE: "READY",
    ProgramState.UNDEFINED: "READY",
}
_MODE = {
    ExecutionMode.MANUAL: "MANUAL",
    ExecutionMode.MDI: "MANUAL_DATA_INPUT",
    ExecutionMode.PASS_REFERENCES: "MANUAL",
    ExecutionMode.SINGLE_STEP: "SEMI_AUTOMATIC",
    ExecutionMode.AUTOMATIC: "AUTOMATIC",
    ExecutionMode.UNDEFINED: "",
}


class Lsv2Connector:
    """One LSV2 session per machine, reopened by the supervisor when it drops."""

    def __init__(self, config: MachineConfig) -> None:
        self.config = config
        self.folder = config.folder.rstrip("/\\") if config.folder else "TNC:/nc_prog"
        self._client: AsyncClient | None = None

    def _require(self) -> AsyncClient:
        if self._client is None:
            raise TransportError(f"{self.config.name}: not connected")
        return self._client

    async def connect(self) -> None:
        """Open the LSV2 session."""
        if self._client is not None:
            return
        client = AsyncClient(self.config.host, int(self.config.port), timeout=10.0)
        await client.connect()
        self._client = client

    async def close(self) -> None:
        """Close the session."""
        client, self._client = self._client, None
        if client is not None:
            with contextlib.suppress(DncError):  # the link is already gone
                await client.close()

    async def status(self) -> MachineStatus:
        """Mode, program state, selected program, overrides and NC errors."""
        client = self._require()
        mode = await client.execution_mode()
        state = await client.program_state()
        program = await client.selected_program()
        overrides = await client.overrides()
        errors = await client.nc_errors()
        feed, spindle, rapid = overrides.percent
        return MachineStatus(
            at=utcnow(),
            available=True,
            execution=_EXECUTION.get(state, "READY"),
            mode=_MODE.get(mode, ""),
            program=program.main,
            line=program.line,
            overrides={"feed": feed, "spindle": spindle, "rapid": rapid},
            errors=tuple(e.text for e in errors),
        )

    def _target(self, name: str) -> str:
        return f"{self.folder}/{name}"

    async def send(self, name: str, data: bytes, progress: Progress) -> None:
        """Write the program into the machine's folder (the control keeps the old file until
        the new one is complete)."""
        client = self._require()
        await client.make_dir(self.folder)
        await client.write_file(self._target(name), data, progress=progress)

    async def verify(self, name: str, data: bytes) -> bool | None:
        """Read the program back and compare."""
        return await self._require().read_file(self._target(name)) == data
