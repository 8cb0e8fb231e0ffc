"""The ``files`` capability: programs as files in a folder, for a machine of any kind
(docs/files.md).

A machine whose configuration has a ``[machines.files]`` table keeps its own kind's connector
for everything else (status, punches, drip-feed) and gets its program transfer from the
folder: :class:`FilesConnector` wraps the kind's connector and answers ``send``, ``verify``,
``holds``, ``fetch``, ``delete`` and ``list_files`` from the folder. So a machine read through
an MTConnect agent or an OPC UA server, status-only by itself, takes programs too. The
registry wraps every such machine's connector (:func:`with_files`); a send stays an ordinary
job, queued through the actions' one policy decision.

The folder is one of three (:mod:`.filedrop_config`): an FTP folder on the control
(:mod:`.filedrop_ftp`), a local or SMB share, or this server's FTP account of the machine
(both :mod:`.filedrop_folder`; the FTP server itself is
:mod:`opendnc.server.netshare.ftpserver`). Files the control writes come to the inbox by the
server's auto-receive (:func:`receive_of`), which skips the server's own sends.
"""

from __future__ import annotations

import asyncio
from dataclasses import replace
from pathlib import Path
from typing import Protocol

from opendnc.errors import InputError
from opendnc.server.core.status import DripProgress, MachineStatus, Progress
from opendnc.server.kinds.base import Capabilities, MachineBase, ReceiveFolder
from opendnc.server.kinds.connector import Connector, Reception
from opendnc.server.kinds.filedrop_config import FilesConfig
from opendnc.server.kinds.filedrop_folder import FolderDrop
from opendnc.server.kinds.filedrop_ftp import FtpDrop
from opendnc.server.kinds.files import RemoteFile

__all__ = ["Drop", "FilesConnector", "capabilities_with", "drop_for", "receive_of", "with_files"]


class Drop(Protocol):
    """A folder of programs (blocking calls; paths relative to the folder)."""

    where: str

    def put(self, name: str, data: bytes) -> None:
        """Store ``data`` as ``name``, whole or not at all, read back before it counts."""
        ...

    def read(self, path: str) -> bytes:
        """The bytes of ``path`` (:class:`~opendnc.errors.ControlRefused` if absent)."""
        ...

    def holds(self, name: str, data: bytes) -> bool:
        """Whether ``name`` holds exactly ``data``."""
        ...

    def remove(self, path: str) -> None:
        """Delete ``path``."""
        ...

    def listing(self, folder: str) -> list[RemoteFile]:
        """The files of ``folder``."""
        ...


def drop_for(files: FilesConfig, machine: str) -> Drop:
    """The folder ``files`` names, for ``machine``."""
    if files.mode == "ftp":
        return FtpDrop(files, machine)
    if files.mode == "ftp-server":
        if not files.folder:
            raise InputError(f"{machine}: no folder set for its FTP account (an [ftp_server])")
        return FolderDrop(files.folder, machine)
    return FolderDrop(files.path, machine)


class FilesConnector:
    """A machine's own connector, with its programs going to and from ``drop``."""

    def __init__(self, inner: Connector, drop: Drop, config: MachineBase) -> None:
        self.inner = inner
        self.drop = drop
        self.config = config
        self.listens = inner.listens

    async def connect(self) -> None:
        """The kind's link (the folder is reached call by call)."""
        await self.inner.connect()

    async def close(self) -> None:
        """The kind's link."""
        await self.inner.close()

    async def status(self) -> MachineStatus:
        """From the kind's link."""
        return await self.inner.status()

    async def listen(self, seconds: float) -> Reception | None:
        """From the kind's link (a serial control's punch)."""
        return await self.inner.listen(seconds)

    async def dripfeed(
        self, name: str, data: bytes, from_line: int, progress: DripProgress
    ) -> dict[str, int]:
        """From the kind's link."""
        return await self.inner.dripfeed(name, data, from_line, progress)

    async def send(self, name: str, data: bytes, progress: Progress) -> None:
        """Put the program into the folder (temporary name, read-back, rename)."""
        progress(0, len(data))
        await asyncio.to_thread(self.drop.put, name, data)
        progress(len(data), len(data))

    async def verify(self, name: str, data: bytes) -> bool | None:
        """Read the program back under its real name."""
        return await asyncio.to_thread(self.drop.holds, name, data)

    async def holds(self, name: str, data: bytes) -> bool:
        """Whether the folder already holds exactly ``data`` as ``name`` (a take-over)."""
        return await asyncio.to_thread(self.drop.holds, name, data)

    async def fetch(self, path: str) -> bytes:
        """A file of the folder."""
        return await asyncio.to_thread(self.drop.read, path)

    async def delete(self, path: str) -> None:
        """Delete a file of the folder."""
        await asyncio.to_thread(self.drop.remove, path)

    async def list_files(self, folder: str) -> list[RemoteFile]:
        """The files of a folder below the folder (auto-receive)."""
        return await asyncio.to_thread(self.drop.listing, folder)

    async def backup(self, path: str, target: Path) -> dict[str, int]:
        """Not offered: the folder is files already."""
        raise InputError(f"{self.config.name}: backup is for LSV2 controls")


def with_files(connector: Connector, machine: MachineBase) -> Connector:
    """``connector``, its programs going through ``machine``'s folder where it has one."""
    if machine.files is None:
        return connector
    return FilesConnector(connector, drop_for(machine.files, machine.name), machine)


def capabilities_with(caps: Capabilities, machine: MachineBase) -> Capabilities:
    """``caps`` of the kind, with what the folder adds (receiving its files)."""
    if machine.files is None or not machine.files.receive:
        return caps
    return replace(caps, receive=True)


def receive_of(machine: MachineBase) -> ReceiveFolder | None:
    """The folder collected into the inbox, where the machine's files table asks for it."""
    files = machine.files
    if files is None or not files.receive:
        return None
    return ReceiveFolder(
        files.receive_folder, files.receive_pattern, files.receive_every, files.after_receive
    )
