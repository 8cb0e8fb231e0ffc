"""The files on a control, through the machine's own connector: list, read, put, delete.

Nothing here opens a link of its own. A listing or a read is an *errand*: the machine's task
runs it on its connector between jobs (:class:`Errands`), so the browser uses the session the
server already holds (LSV2 over TCP or RS-232 alike) and never meets a transfer half-way.
Changing a file (put, delete) is a job like every other (``put_file``, ``delete``), queued by
the actions layer (:mod:`opendnc.server.actions.files`) with the roles and the machine's
policy, and run by its executor (:mod:`opendnc.server.jobs.executors`). Paths stay on the control's
``TNC:`` drive and never climb with ``..``.
"""

from __future__ import annotations

import asyncio
import re
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from datetime import datetime
from typing import TYPE_CHECKING, Any, Protocol, TypeVar, runtime_checkable

from opendnc.errors import InputError
from opendnc.server.core.errors import Unavailable

if TYPE_CHECKING:
    from opendnc.server.core.status import Progress
    from opendnc.server.kinds.connector import Connector

__all__ = [
    "Errands",
    "FileBrowser",
    "RemoteFile",
    "browser_of",
    "check_path",
    "file_name",
]

T = TypeVar("T")
_PATH = re.compile(r"^TNC:([\\/][A-Za-z0-9_.+$ -]{1,100})*[\\/]?$", re.IGNORECASE)


@dataclass(frozen=True)
class RemoteFile:
    """One entry of a folder on the control."""

    name: str
    path: str
    size: int
    modified: datetime
    is_dir: bool


@runtime_checkable
class FileBrowser(Protocol):
    """A connector whose control has a file system the server may browse and change."""

    async def list_files(self, folder: str) -> list[RemoteFile]:
        """The entries of ``folder`` on the control."""

    async def fetch(self, path: str) -> bytes:
        """The bytes of the file at ``path``."""

    async def put_file(self, path: str, data: bytes, progress: Progress) -> None:
        """Write ``data`` to ``path`` (the control keeps the old file until the new one is
        whole)."""


def check_path(path: str) -> str:
    """``path`` normalised to ``TNC:/a/b``; :class:`InputError` for anything off the drive."""
    path = path.strip().replace("\\", "/")
    if not _PATH.fullmatch(path) or any(part in {".", ".."} for part in path.split("/")):
        raise InputError(f"path {path[:60]!r}: a folder or file on TNC:, no '..'")
    return path.rstrip("/") if path.upper() != "TNC:/" else "TNC:/"


def file_name(path: str) -> str:
    """The last part of a path on a control (``TNC:/nc_prog/1001.I`` -> ``1001.I``)."""
    return path.replace("\\", "/").rstrip("/").rsplit("/", 1)[-1]


def browser_of(connector: Connector) -> FileBrowser:
    """``connector`` as a :class:`FileBrowser`; :class:`InputError` if its control has none."""
    if not isinstance(connector, FileBrowser):
        raise InputError("this control has no file system the server can browse")
    return connector


Work = Callable[["Connector"], Awaitable[Any]]


class Errands:
    """Short work for one machine's connector (a listing, a read), run by the machine's task
    between jobs and status polls: the only way a request reaches a control outside a job.

    Posted from the event loop (an async route); :meth:`run` is awaited by the machine's task,
    :meth:`fail_all` when its link is lost."""

    def __init__(self) -> None:
        self._pending: list[tuple[Work, asyncio.Future[Any]]] = []

    def __len__(self) -> int:
        return len(self._pending)

    async def call(
        self, work: Callable[[Connector], Awaitable[T]], wake: Callable[[], None], timeout: float
    ) -> T:
        """Run ``work`` on the connector at the task's next chance; its result. ``wake``
        tells the machine's task; after ``timeout`` s :class:`Unavailable`."""
        future: asyncio.Future[T] = asyncio.get_running_loop().create_future()
        self._pending.append((work, future))
        wake()
        try:
            return await asyncio.wait_for(asyncio.shield(future), timeout)
        except TimeoutError:
            future.cancel()  # the task skips it if it has not started it yet
            raise Unavailable(f"the control did not answer within {timeout:.0f} s") from None

    async def run(self, connector: Connector) -> None:
        """Run every pending errand in turn (the machine's task calls this)."""
        while self._pending:
            work, future = self._pending.pop(0)
            if future.done():
                continue
            try:
                result = await work(connector)
            except asyncio.CancelledError:
                future.cancel()
                raise
            except Exception as exc:  # the caller gets it; the machine's task goes on
                if not future.done():
                    future.set_exception(exc)
            else:
                if not future.done():
                    future.set_result(result)

    def fail_all(self, reason: str) -> None:
        """Answer every pending errand with :class:`Unavailable` (the link is gone)."""
        pending, self._pending = self._pending, []
        for _work, future in pending:
            if not future.done():
                future.set_exception(Unavailable(reason))
