"""Haas NGC controls over Ethernet: machine data (MDC Q-commands) and the net share.

Programs go through the control's network share (Setting 262 onwards on NGC): the server
writes the file into the share folder and the operator loads it from the control's device
manager. A local (mounted) folder is read back to verify; for an ``smb://`` share the copy's
own checks are all there is.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import tempfile
from pathlib import Path

from opendnc.errors import DncError, InputError, TransportError
from opendnc.haas import share
from opendnc.haas.mdc import Busy, Count, Mode, ProgramStatus, Reply
from opendnc.haas.mdc_client import AsyncMdcClient
from opendnc.server.core.folders import open_folder  # the scan's own folder code
from opendnc.server.core.status import MachineStatus, Progress
from opendnc.server.kinds.connector import NetworkOnly
from opendnc.server.kinds.haas_ngc.schema import HaasNgcMachine
from opendnc.server.store.models import utcnow

__all__ = ["HaasNgcConnector", "controller_mode", "mdc_status"]

DETAIL_EVERY = 30  # polls between reads of what changes rarely

# Q500's status word in MTConnect's EXECUTION vocabulary.
_EXECUTION = {"IDLE": "READY", "BUSY": "ACTIVE", "FEED HOLD": "FEED_HOLD", "ALARM ON": "STOPPED"}
# Q104's mode words (docs/haas.md#q-commands; classic controls say ZERO RET for ZERO) in
# MTConnect's CONTROLLER_MODE vocabulary (docs/server.md#machine-status).
_MODES = {
    "MEM": "AUTOMATIC",
    "DNC": "AUTOMATIC",
    "MDI": "MANUAL_DATA_INPUT",
    "JOG": "MANUAL",
    "HANDLE JOG": "MANUAL",
    "ZERO": "MANUAL",
    "ZERO RET": "MANUAL",
    "EDIT": "EDIT",
    "LIST PROG": "EDIT",
}


def controller_mode(word: str) -> str:
    """MTConnect's CONTROLLER_MODE for a Haas mode word (Q104); ``""`` for a word not known."""
    return _MODES.get(" ".join(word.upper().split()), "")


def mdc_status(q500: Reply, q104: Reply, tool: int | None) -> MachineStatus:
    """The status from Q500 (program, state, parts) and Q104 (mode), NGC or classic: the mode
    in MTConnect's words, the control's own word in ``native_mode``."""
    program, word, parts = "", "", None
    native = " ".join(q104.mode.upper().split()) if isinstance(q104, Mode) else ""
    if isinstance(q500, ProgramStatus):
        program, word, parts = q500.program, q500.status.upper(), q500.parts
    elif isinstance(q500, Busy):
        word = "BUSY"
    return MachineStatus(
        at=utcnow(),
        available=True,
        execution=_EXECUTION.get(word, "READY" if not word else "ACTIVE"),
        mode=controller_mode(native),
        native_mode=native,
        program=program,
        part_count=parts,
        tool=tool,
        errors=("ALARM",) if "ALARM" in word else (),
    )


class HaasNgcConnector(NetworkOnly):
    """MDC for status, the net share for programs."""

    config: HaasNgcMachine

    def __init__(self, config: HaasNgcMachine) -> None:
        self.config = config
        self._mdc: AsyncMdcClient | None = None
        self._polls = 0
        self._tool: int | None = None

    async def connect(self) -> None:
        """Open the MDC connection."""
        if self._mdc is None:
            self._mdc = await AsyncMdcClient.connect(
                self.config.host, self.config.mdc_port, timeout=3.0
            )

    async def close(self) -> None:
        """Close the MDC connection."""
        mdc, self._mdc = self._mdc, None
        if mdc is not None:
            with contextlib.suppress(DncError):  # the link is already gone
                await mdc.close()

    async def status(self) -> MachineStatus:
        """Q500 (program, state, parts) and Q104 (mode) every poll; the tool in spindle (Q201)
        every ``DETAIL_EVERY`` polls, as it changes at tool changes only."""
        if self._mdc is None:
            raise TransportError(f"{self.config.name}: not connected")
        q500 = await self._mdc.query(500)
        q104 = await self._mdc.query(104)
        if self._polls % DETAIL_EVERY == 0:
            q201 = await self._mdc.query(201)
            self._tool = q201.value if isinstance(q201, Count) else None
        self._polls += 1
        return mdc_status(q500, q104, self._tool)

    def _target(self) -> share.ShareTarget:
        if not self.config.share:
            raise InputError(f"{self.config.name}: no share configured for sending programs")
        return share.parse_target(self.config.share)

    async def send(self, name: str, data: bytes, progress: Progress) -> None:
        """Copy the program into the share (whole or not at all)."""
        target = self._target()

        def copy() -> None:
            with tempfile.TemporaryDirectory(prefix="opendnc-send-") as tmp:
                source = Path(tmp) / name
                source.write_bytes(data)
                share.push([source], target)

        await asyncio.to_thread(copy)
        progress(len(data), len(data))

    async def verify(self, name: str, data: bytes) -> bool | None:
        """Read the file back from a local share folder (None for an SMB share)."""
        target = self._target()
        if target.local is None:
            return None
        local = target.local / name
        return await asyncio.to_thread(lambda: local.is_file() and local.read_bytes() == data)

    async def holds(self, name: str, data: bytes) -> bool:
        """Whether the share already holds exactly ``data`` as ``name`` (what a server that
        took the machine over asks before sending a load again): the share's listing for the
        file's size, then the file's SHA-256 against the program's. A local folder or SMB
        alike; a share that cannot be listed is a :class:`TransportError` (the load is then
        retried like one that could not be copied)."""
        target = self._target()

        def look() -> bool:
            folder = open_folder(target)
            entry = folder.entries().get(name)
            if entry is None or entry[0] != len(data):
                return False
            try:
                there = hashlib.sha256(folder.read(name)).digest()
            except OSError:  # gone between the listing and the read: not there
                return False
            return there == hashlib.sha256(data).digest()

        return await asyncio.to_thread(look)

    def _local(self, path: str) -> Path:
        target = self._target()
        if target.local is None:
            raise InputError(f"{self.config.name}: reading and deleting need a local share folder")
        name = path.replace("\\", "/").rsplit("/", 1)[-1]
        if not name or name in (".", ".."):
            raise InputError(f"{path!r} names no file")
        return target.local / name

    async def fetch(self, path: str) -> bytes:
        """Read a program from the share folder."""
        local = self._local(path)
        try:
            return await asyncio.to_thread(local.read_bytes)
        except OSError as exc:
            raise InputError(
                f"{self.config.name}: cannot read {local.name}: {exc.strerror}"
            ) from exc

    async def delete(self, path: str) -> None:
        """Delete a program from the share folder."""
        local = self._local(path)
        try:
            await asyncio.to_thread(local.unlink)
        except OSError as exc:
            raise InputError(
                f"{self.config.name}: cannot delete {local.name}: {exc.strerror}"
            ) from exc

    async def backup(self, path: str, target: Path) -> dict[str, int]:
        """Not offered: a Haas share is a folder a file-level backup copies already."""
        raise InputError(f"{self.config.name}: backup is for LSV2 controls")
