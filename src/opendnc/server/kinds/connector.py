"""The connector interface every machine kind implements (:class:`Connector`), and the small
pieces around it: a reception, a cancel that reached a job, network-only connectors.

The status a connector fills is :class:`opendnc.server.core.status.MachineStatus`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Protocol, runtime_checkable

from opendnc.errors import InputError, TransferError
from opendnc.server.core.status import DripProgress, MachineStatus, Progress
from opendnc.transport.base import ByteStream

if TYPE_CHECKING:
    from opendnc.server.kinds.base import MachineBase
    from opendnc.server.kinds.files import RemoteFile

__all__ = [
    "Connector",
    "FolderSource",
    "JobCancelled",
    "NetworkOnly",
    "Reception",
    "StatusOnly",
    "StreamWrapper",
]


class JobCancelled(TransferError):
    """A cancel requested in the database reached the job at a safe point; ``nbytes`` the
    program bytes it had moved by then (its row's Bytes say the same as its message)."""

    def __init__(self, reason: str, nbytes: int | None = None) -> None:
        super().__init__(reason)
        self.nbytes = nbytes


@dataclass(frozen=True)
class Reception:
    """A program the control sent by itself (a punch); ``failed`` says why it broke off,
    ``name`` is the name the program carries where the link told it (a tape punch)."""

    data: bytes
    failed: str = ""
    name: str | None = None


class Connector(Protocol):
    """What the supervisor needs from a control."""

    listens: bool
    """True if the control can send programs by itself (the supervisor then calls
    :meth:`listen` between status polls instead of sleeping)."""

    async def connect(self) -> None:
        """Open the link (raise a :class:`~opendnc.errors.DncError` if the control is away)."""

    async def close(self) -> None:
        """Close the link; safe to call at any time."""

    async def status(self) -> MachineStatus:
        """Read the control's state now."""

    async def send(self, name: str, data: bytes, progress: Progress) -> None:
        """Load program ``name`` into the control."""

    async def verify(self, name: str, data: bytes) -> bool | None:
        """Whether the control now holds exactly ``data`` as ``name``; None if it cannot tell."""

    async def listen(self, seconds: float) -> Reception | None:
        """Wait up to ``seconds`` for the control to start sending; None if it did not."""

    async def fetch(self, path: str) -> bytes:
        """Read the file ``path`` from the control (:class:`InputError` where it cannot)."""

    async def delete(self, path: str) -> None:
        """Delete the file ``path`` on the control (:class:`InputError` where it cannot)."""

    async def backup(self, path: str, target: Path) -> dict[str, int]:
        """Copy the folder ``path`` into ``target``, skipping unchanged files; counts."""

    async def dripfeed(
        self, name: str, data: bytes, from_line: int, progress: DripProgress
    ) -> dict[str, int]:
        """Stream a program the control runs as it arrives (:class:`InputError` where the
        control cannot); ``progress`` may raise to stop the feed. Returns counts."""


@runtime_checkable
class FolderSource(Connector, Protocol):
    """A connector that can also list a folder on its control (LSV2): what auto-receive
    needs beside :meth:`Connector.fetch` and :meth:`Connector.delete`."""

    async def list_files(self, folder: str) -> list[RemoteFile]:
        """The entries of ``folder`` on the control."""


class NetworkOnly:
    """What a control reached over the network lacks: it sends no programs by itself (it is
    asked for them) and runs nothing by drip-feed."""

    listens = False
    config: MachineBase

    async def listen(self, seconds: float) -> Reception | None:
        """Nothing to listen for."""
        return None

    async def dripfeed(
        self, name: str, data: bytes, from_line: int, progress: DripProgress
    ) -> dict[str, int]:
        """Drip-feed is a serial Haas's way of running a program."""
        raise InputError(
            f"{self.config.name}: drip-feed is for serial machines (haas_serial, serial)"
        )


class StatusOnly(NetworkOnly):
    """A machine read through a status interface of its own (an MTConnect agent, an OPC UA
    server): it takes no programs and holds no files this server can reach. ``through``
    names that interface in the refusals."""

    through = "its status interface"

    def _read_only(self, what: str) -> InputError:
        return InputError(f"{self.config.name}: {what} is not possible through {self.through}")

    async def send(self, name: str, data: bytes, progress: Progress) -> None:
        """No programs go this way."""
        raise self._read_only("sending a program")

    async def verify(self, name: str, data: bytes) -> bool | None:
        """Nothing to compare with."""
        return None

    async def fetch(self, path: str) -> bytes:
        """No files this way."""
        raise self._read_only("reading a file")

    async def delete(self, path: str) -> None:
        """No files this way."""
        raise self._read_only("deleting a file")

    async def backup(self, path: str, target: Path) -> dict[str, int]:
        """No files this way."""
        raise self._read_only("a backup")


class StreamWrapper:
    """A :class:`~opendnc.transport.base.ByteStream` that passes everything to ``inner``;
    subclasses change how it is read."""

    def __init__(self, inner: ByteStream) -> None:
        self.inner = inner

    def read(self, max_bytes: int) -> bytes:
        """Read from the port."""
        return self.inner.read(max_bytes)

    def write(self, data: bytes) -> None:
        """Write to the port."""
        self.inner.write(data)

    def set_timeout(self, seconds: float | None) -> None:
        """Change the port's read timeout."""
        self.inner.set_timeout(seconds)

    def close(self) -> None:
        """Close the port."""
        self.inner.close()
