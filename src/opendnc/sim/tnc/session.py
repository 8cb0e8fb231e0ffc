"""Per-connection LSV2 session: login state, current directory, running sequences.

:class:`Session` is sans-IO: :meth:`Session.handle` takes one typed request decoded by the
shared codec (:mod:`opendnc.lsv2.messages`) and returns the typed answers to send (possibly
none, e.g. after ``T_FD`` without secure file send) plus deferred messages the server emits
later (``M_CC`` after ``C_CC`` 27).  Buffer size and the secure-send flag are tracked by the
shared engine (:class:`~opendnc.lsv2.connection.Lsv2Connection` in the server role), which
the session reads.  Handlers live in ``handlers_*`` modules and register in :data:`HANDLERS`.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import Any

from opendnc.errors import ControlRefused, InputError
from opendnc.lsv2.connection import Lsv2Connection
from opendnc.lsv2.constants import DRIVE_LOGINS, Login
from opendnc.lsv2.constants import ErrorCode as E
from opendnc.lsv2.messages import BlockDefect, FileData, FileDone, Message, Ok, Opaque, Refused
from opendnc.sim.tnc.control import Control
from opendnc.sim.tnc.filesystem import WirePath
from opendnc.sim.tnc.scope import Signal


class Priv(Enum):
    """Minimum login a telegram needs (docs/lsv2.md#logins)."""

    NONE = "none"  # allowed before any login (A_LG)
    ANY = "any"  # any login
    INSPECT = "inspect"  # INSPECT or a login that includes it
    FILE = "file"  # FILE/FILEPLC/FILESYS/FILELOG; the drive is checked by the handler
    MONITOR = "monitor"  # MONITOR or DIAGNOSTICS (keyboard lock and key emulation)
    DIAGNOSTICS = "diagnostics"
    DNC = "dnc"
    PLCDEBUG = "plcdebug"
    DATA = "data"
    OSZI = "oszi"


INSPECT_LEVEL = frozenset(
    {
        Login.INSPECT,
        Login.DIAGNOSTICS,
        Login.FILE,
        Login.MONITOR,
        Login.DNC,
        Login.PLCDEBUG,
        Login.DATA,
    }
)
_MONITOR_LEVEL = frozenset({Login.MONITOR, Login.DIAGNOSTICS})
_FILE_LEVEL = frozenset(DRIVE_LOGINS.values())


def error(code: int) -> Refused:
    """A ``T_ER``: always 2 bytes, type 1 (docs/lsv2.md#transfer-control-and-errors)."""
    return Refused(code)


def block_defect(code: int) -> BlockDefect:
    """A ``T_BD`` with a 100-199 code."""
    return BlockDefect(code)


OK = Ok()
DONE = FileDone()


#: Upload bytes collected before one write to the partial file.
UPLOAD_BUFFER = 1 << 20


@dataclass(slots=True)
class Upload:
    """An upload in progress: data goes to a hidden partial file, renamed on ``T_FD``.

    Blocks are collected in memory and written once per :data:`UPLOAD_BUFFER` bytes: a write
    syscall per 4 KiB block sat between every ``S_FL`` and its ``T_OK``.
    """

    target: WirePath
    partial: Path
    fd: int
    binary: bool
    overwrite: bool
    size: int = 0
    pending: list[bytes] = field(default_factory=list)
    pending_size: int = 0

    def add(self, data: bytes) -> None:
        """Take one block; raises ``OSError`` if writing the collected bytes fails."""
        self.pending.append(data)
        self.pending_size += len(data)
        self.size += len(data)
        if self.pending_size >= UPLOAD_BUFFER:
            self.flush()

    def flush(self) -> None:
        """Write the collected bytes to the partial file."""
        view = memoryview(b"".join(self.pending))
        self.pending.clear()
        self.pending_size = 0
        while view:
            view = view[os.write(self.fd, view) :]


@dataclass(slots=True)
class Deferred:
    """A frame the server sends later on its own (``M_CC``)."""

    delay: float
    make: Callable[[], Message | None]


@dataclass(slots=True)
class Result:
    """What to send now and what to send later."""

    frames: list[Message] = field(default_factory=list)
    deferred: Sequence[Deferred] = ()


Handler = Callable[["Session", Any], "list[Message] | Result"]
HANDLERS: dict[type[Message] | str, tuple[Priv, Handler]] = {}
"""Request class (or telegram name for layout-less ``Opaque`` telegrams) -> handler."""


def handler(request: type[Message] | str, priv: Priv) -> Callable[[Handler], Handler]:
    """Register the handler of a request class (or of an opaque telegram name)."""

    def register(fn: Handler) -> Handler:
        HANDLERS[request] = (priv, fn)
        return fn

    return register


_ids = iter(range(1, 2**62))


class Session:
    """State of one client connection."""

    def __init__(self, control: Control, link: Lsv2Connection) -> None:
        self.id = next(_ids)
        self.control = control
        self.link = link
        self.logins: set[str] = set()
        self.cwd = WirePath("TNC:", ())
        self.upload: Upload | None = None
        self.sequence: Iterator[Message] | None = None
        self.error_index = 0
        self.keyboard_locked = False
        self.scope_signals: list[Signal] = []
        self.scope_interval = 3000

    # -- privileges -------------------------------------------------------------------------
    def allowed(self, priv: Priv) -> bool:
        """Does the session hold a login that unlocks ``priv``?"""
        have = self.logins
        match priv:
            case Priv.NONE:
                return True
            case Priv.ANY:
                return bool(have)
            case Priv.INSPECT:
                return bool(have & INSPECT_LEVEL)
            case Priv.FILE:
                return not have.isdisjoint(_FILE_LEVEL)
            case Priv.MONITOR:
                return not have.isdisjoint(_MONITOR_LEVEL)
            case Priv.DIAGNOSTICS:
                return Login.DIAGNOSTICS in have
            case _:
                return priv.value.upper() in have

    def check_drive(self, wp: WirePath) -> None:
        """Refuse (23) a path on a drive whose file login the session lacks."""
        if self.logins.isdisjoint(self.control.profile.drive_logins(wp.drive)):
            raise ControlRefused(E.T_ER_NO_PRIV, f"no login for {wp.drive}")

    def path(self, text: str) -> WirePath:
        """Parse a wire path against the current directory and check the drive login."""
        wp = self.control.fs.parse(text, self.cwd)
        self.check_drive(wp)
        return wp

    @property
    def buffer_size(self) -> int:
        """Negotiated telegram size (kept by the shared engine)."""
        return self.link.buffer_size

    @property
    def secure_send(self) -> bool:
        """True once ``C_CC`` 19 was accepted in this session."""
        return self.link.secure_send

    # -- dispatch ---------------------------------------------------------------------------
    def handle(self, request: Message, wire_size: int) -> Result:
        """Answer one decoded request that arrived as ``wire_size`` bytes."""
        if wire_size > self.link.buffer_size:
            # Too large for the negotiated buffer (docs/lsv2.md#buffer-size): refuse and abort a
            # running upload.
            if self.upload is not None and isinstance(request, FileData):
                self.abort_upload()
                return Result([block_defect(E.T_BD_BAD_FORMAT)])
            return Result([error(E.T_ER_BAD_FORMAT)])
        if self.sequence is not None:
            if isinstance(request, Ok):
                following = next(self.sequence, None)
                if following is None:
                    self.sequence = None
                    return Result([DONE])
                return Result([following])
            self.sequence = None
            if isinstance(request, BlockDefect):
                return Result([])  # client stops a list, download or scope stream
        if self.upload is not None and not isinstance(request, FileData | FileDone | BlockDefect):
            self.abort_upload()
        key: type[Message] | str = (
            request.mnemonic if isinstance(request, Opaque) else type(request)
        )
        entry = HANDLERS.get(key)
        if entry is None:
            if request.mnemonic[:2] in ("S_", "T_", "M_"):
                return Result([error(E.T_ER_UNEXPECTED_TELE)])  # an answer nobody asked for
            return Result([error(E.T_ER_WRONG_PARA)])  # exists, not supported here
        priv, fn = entry
        if not self.allowed(priv):
            return Result([error(E.T_ER_NO_PRIV)])
        try:
            out = fn(self, request)
        except ControlRefused as exc:
            # Handlers and the control model refuse with the code the control answers.
            return Result([error(exc.code)])
        except InputError:
            # A value we cannot put on the wire (e.g. a non-Latin-1 host file name).
            return Result([error(E.T_ER_BAD_FNAME)])
        return out if isinstance(out, Result) else Result(out)

    def start_sequence(self, frames: Iterator[Message]) -> list[Message]:
        """Send the first frame of a block sequence; later ``T_OK``s pull the rest."""
        first = next(frames, None)
        if first is None:
            return [DONE]
        self.sequence = frames
        return [first]

    def data_limit(self) -> int:
        """Largest data block that keeps a telegram within the buffer (as pyLSV2 does)."""
        return self.buffer_size - 10

    def abort_upload(self) -> None:
        """Drop an unfinished upload: close and delete its partial file."""
        up = self.upload
        self.upload = None
        if up is None:
            return
        with contextlib.suppress(OSError):
            os.close(up.fd)
        up.partial.unlink(missing_ok=True)

    def close(self) -> None:
        """Connection gone: release exclusive logins and partial files."""
        self.abort_upload()
        self.sequence = None
        if self.control.monitor_owner == self.id:
            self.control.monitor_owner = None
        self.logins.clear()
