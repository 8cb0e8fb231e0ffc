"""Heidenhain controls over LSV2 (TCP)."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import TypeVar

from opendnc.errors import ControlRefused, DncError, InputError, TransportError
from opendnc.lsv2 import AsyncClient, Client
from opendnc.lsv2.backup import backup as lsv2_backup
from opendnc.lsv2.constants import ExecutionMode, ProgramState
from opendnc.lsv2.localfiles import is_binary_name
from opendnc.lsv2.serial_stream import SerialLine
from opendnc.server.core.status import MachineStatus, Progress
from opendnc.server.kinds.connector import NetworkOnly
from opendnc.server.kinds.files import RemoteFile
from opendnc.server.kinds.lsv2.schema import Lsv2Machine
from opendnc.server.store.models import utcnow

__all__ = ["Lsv2Connector"]

T = TypeVar("T")
DETAIL_EVERY = 5  # polls between reads of overrides, tool and errors

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

# What the card and the alarm statistics say for a program the control stopped with an NC
# error when its error list cannot be read (TNC 640, 620, 320 and TNC7 answer the error
# list's run information only on an iTNC 530; the program state still says "error").
PROGRAM_ERROR = "Program stopped by an NC error (its text is on the control)"
_MODE = {
    ExecutionMode.MANUAL: "MANUAL",
    ExecutionMode.MDI: "MANUAL_DATA_INPUT",
    ExecutionMode.PASS_REFERENCES: "MANUAL",
    ExecutionMode.SINGLE_STEP: "SEMI_AUTOMATIC",
    ExecutionMode.AUTOMATIC: "AUTOMATIC",
    ExecutionMode.UNDEFINED: "",
}


class Lsv2Connector(NetworkOnly):
    """One LSV2 session per machine, reopened by the machine's task when it drops."""

    config: Lsv2Machine

    def __init__(self, config: Lsv2Machine) -> None:
        self.config = config
        self.folder = config.folder.rstrip("/\\") if config.folder else "TNC:/nc_prog"
        self._client: AsyncClient | None = None
        self._refused: set[str] = set()
        self._polls = 0
        self._overrides: dict[str, float] = {}
        self._errors: tuple[str, ...] = ()
        self._tool: int | None = None

    def _require(self) -> AsyncClient:
        if self._client is None:
            raise TransportError(f"{self.config.name}: not connected")
        return self._client

    async def connect(self) -> None:
        """Open the LSV2 session."""
        if self._client is not None:
            return
        client = self._client_for()
        await client.connect()
        self._client = client

    def _client_for(self) -> AsyncClient:
        # RS-232 (serial = "...") or TCP: the operations are the same, only the link differs.
        config = self.config
        if config.serial:
            profile = config.profile
            line = SerialLine(
                config.serial,
                baud=profile.baud,
                parity=profile.parity,
                bytesize=profile.bytesize,
                stopbits=profile.stopbits,
                flow=profile.flow,
                telegram_size=256,  # as the CLI: uploads adapt below it (docs/lsv2-serial.md)
            )
            return AsyncClient.over_serial(line, timeout=10.0)
        return AsyncClient(config.host, config.port, timeout=10.0)

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
        # a program stopped by an error: its text now, not a few polls later
        in_error = state is ProgramState.ERROR
        if self._polls % DETAIL_EVERY == 0 or (in_error and not self._errors):
            # Overrides, tool and the error list change seldom: read them every few polls.
            overrides = await self._optional("overrides", client.overrides)
            errors = await self._optional("nc_errors", client.nc_errors)
            tool = await self._optional("current_tool", client.current_tool)
            if overrides is not None:
                feed, spindle, rapid = overrides.percent
                self._overrides = {"feed": feed, "spindle": spindle, "rapid": rapid}
            self._errors = tuple(e.text for e in errors or ())
            self._tool = tool.number if tool is not None else None
        self._polls += 1
        alarms = self._errors
        if in_error and not alarms:
            alarms = (PROGRAM_ERROR,)  # an error state is an alarm, with or without its text
        return MachineStatus(
            at=utcnow(),
            available=True,
            execution=_EXECUTION.get(state, "READY"),
            mode=_MODE.get(mode, ""),
            program=program.main,
            line=program.line,
            tool=self._tool,
            overrides=dict(self._overrides),
            errors=alarms,
        )

    async def _optional(self, what: str, read: Callable[[], Awaitable[T]]) -> T | None:
        # Families differ in the run-info selectors they answer (and a TNC with no NC error
        # refuses the error list); a refusal is remembered so it is not asked every poll.
        if what in self._refused:
            return None
        try:
            return await read()
        except ControlRefused:
            self._refused.add(what)
            return None

    def _target(self, name: str) -> str:
        return f"{self.folder}/{name}"

    async def send(self, name: str, data: bytes, progress: Progress) -> None:
        """Write the program into the machine's folder (the control keeps the old file until
        the new one is complete)."""
        client = self._require()
        await client.make_dir(self.folder)
        await client.write_file(self._target(name), data, progress=progress)

    async def verify(self, name: str, data: bytes) -> bool | None:
        """Read the program back and compare.

        A text file travels in LSV2's ASCII mode, in which the control keeps lines in its own
        form; it is read back with the line end the program came with, so a program written
        with LF compares equal to itself.
        """
        line_end = b"\r\n" if b"\r\n" in data or b"\n" not in data else b"\n"
        return await self._require().read_file(self._target(name), line_end=line_end) == data

    async def holds(self, name: str, data: bytes) -> bool | None:
        """Whether the machine's folder already holds exactly ``data`` as ``name`` (what a
        server that took the machine over asks before sending a load again).

        The file's entry first (one telegram): no such file, or a binary file of another size,
        is a plain no. Otherwise the file is read back and compared as :meth:`verify` does: a
        text file's size on the control depends on how the control stores line ends, so only
        its content can say. A control that refuses the read-back cannot say (None): the load
        is then sent again rather than failed for a read it was never asked to allow.
        """
        return await self.holds_file(self._target(name), data)

    async def holds_file(self, path: str, data: bytes) -> bool | None:
        """:meth:`holds` for a file anywhere on the control's drive (a ``put_file`` job)."""
        client = self._require()
        try:
            info = await client.file_info(path)
        except ControlRefused:
            return False  # the folder itself is not there
        if info is None:
            return False
        if is_binary_name(path) and info.size != len(data):
            return False
        # read as written (the mode by the file's type), text with the line end it came with
        line_end = b"\r\n" if b"\r\n" in data or b"\n" not in data else b"\n"
        try:
            return await client.read_file(path, line_end=line_end) == data
        except ControlRefused:
            return None

    async def fetch(self, path: str) -> bytes:
        """Read a file from the control (binary: the bytes as the control holds them)."""
        return await self._require().read_file(path, binary=True)

    async def list_files(self, folder: str) -> list[RemoteFile]:
        """The files and folders in ``folder`` (one directory listing on this session)."""
        base = folder.rstrip("/\\")
        return [
            RemoteFile(e.name, f"{base}/{e.name}", e.size, e.modified, e.is_dir)
            for e in await self._require().list_dir(folder)
            if e.name not in {".", ".."} and not e.hidden and not e.is_drive
        ]

    async def put_file(self, path: str, data: bytes, progress: Progress) -> None:
        """Write a file anywhere on the control's drive (a ``put_file`` job of the browser)."""
        await self._require().write_file(path, data, progress=progress)

    async def delete(self, path: str) -> None:
        """Delete a file on the control."""
        await self._require().delete_file(path)

    async def backup(self, path: str, target: Path) -> dict[str, int]:
        """Back up a folder over a second LSV2 session (the backup walks the whole tree in
        a worker thread; the status polls keep their own session)."""

        if self.config.serial:
            # One RS-232 line carries one session: the backup cannot run beside the polls.
            raise InputError(
                f"{self.config.name}: backup runs over TCP (LSV2 over RS-232 has one session)"
            )

        def run() -> dict[str, int]:
            with Client(self.config.host, self.config.port, timeout=30.0) as client:
                summary = lsv2_backup(client, path, target)
            return {
                "copied": len(summary.copied),
                "unchanged": len(summary.skipped),
                "failed": len(summary.failed),
            }

        return await asyncio.to_thread(run)
