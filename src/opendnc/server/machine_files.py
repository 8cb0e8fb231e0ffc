"""The files on a Heidenhain control, through the server: list, read, write, delete.

Each call opens its own short LSV2 session next to the supervisor's status session (a TNC
serves several LSV2 connections), so a person browsing never holds up a machine's queue.
Paths stay on the control's ``TNC:`` drive and never climb with ``..``. Writes and deletes are
recorded in the audit trail by the caller's transaction.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from datetime import datetime

from opendnc.errors import InputError
from opendnc.lsv2 import AsyncClient
from opendnc.server.config import Lsv2Machine, MachineConfig

__all__ = ["RemoteFile", "check_path", "delete", "list_folder", "read", "write"]

_PATH = re.compile(r"^TNC:([\\/][A-Za-z0-9_.+$ -]{1,100})*[\\/]?$", re.IGNORECASE)
TIMEOUT = 10.0


@dataclass(frozen=True)
class RemoteFile:
    """One entry of a folder on the control."""

    name: str
    path: str
    size: int
    modified: datetime
    is_dir: bool


def _lsv2(machine: MachineConfig) -> AsyncClient:
    if not isinstance(machine, Lsv2Machine):
        raise InputError(f"{machine.name} has no file browser (only LSV2 controls have one)")
    return AsyncClient(machine.host, machine.port, timeout=TIMEOUT)


def check_path(path: str) -> str:
    """``path`` normalised to ``TNC:/a/b``; :class:`InputError` for anything off the drive."""
    path = path.strip().replace("\\", "/")
    if not _PATH.fullmatch(path) or any(part in {".", ".."} for part in path.split("/")):
        raise InputError(f"path {path[:60]!r}: a folder or file on TNC:, no '..'")
    return path.rstrip("/") if path.upper() != "TNC:/" else "TNC:/"


def default_folder(machine: MachineConfig) -> str:
    """Where the server puts programs on ``machine`` (the browser opens there)."""
    folder = machine.folder if isinstance(machine, Lsv2Machine) else ""
    return check_path(folder or "TNC:/nc_prog")


async def list_folder(machine: MachineConfig, folder: str) -> list[RemoteFile]:
    """The entries of ``folder``, folders first, then by name."""
    folder = check_path(folder)
    client = _lsv2(machine)
    await client.connect()
    try:
        entries = await client.list_dir(folder)
    finally:
        await client.close()
    base = folder.rstrip("/")
    files = [
        RemoteFile(e.name, f"{base}/{e.name}", e.size, e.modified, e.is_dir)
        for e in entries
        if e.name not in {".", ".."} and not e.hidden and not e.is_drive
    ]
    return sorted(files, key=lambda f: (not f.is_dir, f.name.lower()))


async def read(machine: MachineConfig, path: str) -> bytes:
    """The bytes of the file at ``path``."""
    path = check_path(path)
    client = _lsv2(machine)
    await client.connect()
    try:
        return await client.read_file(path)
    finally:
        await client.close()


async def write(machine: MachineConfig, path: str, data: bytes) -> None:
    """Write ``data`` to ``path`` (the control keeps the old file until the new one is whole)."""
    path = check_path(path)
    client = _lsv2(machine)
    await client.connect()
    try:
        await client.write_file(path, data)
    finally:
        await client.close()


async def delete(machine: MachineConfig, path: str) -> None:
    """Delete the file at ``path``."""
    path = check_path(path)
    client = _lsv2(machine)
    await client.connect()
    try:
        await client.delete_file(path)
    finally:
        await client.close()
