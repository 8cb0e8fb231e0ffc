"""Per-connection LSV2 session: login state, current directory, buffer size, running sequences.

:class:`Session` is sans-IO: :meth:`Session.handle` takes one received :class:`Frame` and
returns the frames to send (possibly none, e.g. after ``T_FD`` without secure file send) plus
deferred frames the server emits later (``M_CC`` after ``C_CC`` 27).  Handlers live in
``handlers_*`` modules and register themselves in :data:`HANDLERS`.
"""

from __future__ import annotations

import contextlib
import os
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path

from opendnc.errors import RemoteProtocolError
from opendnc.lsv2.constants import ErrorCode as E
from opendnc.lsv2.framing import Frame
from opendnc.sim.tnc.control import Control
from opendnc.sim.tnc.filesystem import FsError, WirePath


class Priv(Enum):
    """Minimum login a telegram needs (reference §3.2)."""

    NONE = "none"  # allowed before any login (A_LG)
    ANY = "any"  # any login
    INSPECT = "inspect"  # INSPECT or a login that includes it
    FILE = "file"  # FILE/FILEPLC/FILESYS/FILELOG; the drive is checked by the handler
    MONITOR = "monitor"  # MONITOR or DIAGNOSTICS (keys), FILE or MONITOR for screen dumps
    DIAGNOSTICS = "diagnostics"
    DNC = "dnc"
    PLCDEBUG = "plcdebug"
    DATA = "data"
    OSZI = "oszi"


INSPECT_LEVEL = frozenset({"INSPECT", "DIAGNOSTICS", "FILE", "MONITOR", "DNC", "PLCDEBUG", "DATA"})
FILE_LOGINS = {"TNC:": "FILE", "PLC:": "FILEPLC", "SYS:": "FILESYS", "LOG:": "FILELOG"}


class Refuse(Exception):
    """Raised by handlers: answer ``T_ER`` with ``code``."""

    def __init__(self, code: int, text: str = "") -> None:
        super().__init__(f"{code} {text}")
        self.code = code


def error(code: int) -> Frame:
    """A ``T_ER`` frame: always 2 bytes, type 1 (§2.2)."""
    return Frame("T_ER", bytes([1, code & 0xFF]))


def block_defect(code: int) -> Frame:
    """A ``T_BD`` frame with a 100-199 code."""
    return Frame("T_BD", bytes([1, code & 0xFF]))


OK = Frame("T_OK")
DONE = Frame("T_FD")


@dataclass(slots=True)
class Upload:
    """An upload in progress: data goes to a hidden partial file, renamed on ``T_FD``."""

    target: WirePath
    partial: Path
    fd: int
    binary: bool
    overwrite: bool
    size: int = 0


@dataclass(slots=True)
class Deferred:
    """A frame the server sends later on its own (``M_CC``)."""

    delay: float
    make: Callable[[], Frame | None]


@dataclass(slots=True)
class Result:
    """What to send now and what to send later."""

    frames: list[Frame] = field(default_factory=list)
    deferred: list[Deferred] = field(default_factory=list)


Handler = Callable[["Session", Frame], "list[Frame] | Result"]
HANDLERS: dict[str, tuple[Priv, Handler]] = {}
# Telegram names that exist on controls but whose layouts are not public (§5.12, §5.1).
KNOWN_UNSUPPORTED = frozenset(
    [
        "R_CD",
        "R_FO",
        "R_LB",
        "R_PD",
        "R_RS",
        "R_SD",
        "R_SE",
        "R_SP",
        "R_SS",
        "R_SW",
        "R_WD",
        "R_MP",
        "C_DT",
        "C_FA",
        "C_DS",
        "C_GC",
        "C_MB",
        "C_OP",
        "C_TP",
        "R_DS",
        "R_IN",
        "R_OH",
        "R_OI",
        "X_PC",
        "X_OK",
        "X_ER",
    ]
)


def handler(mnemonic: str, priv: Priv) -> Callable[[Handler], Handler]:
    """Register a telegram handler."""

    def register(fn: Handler) -> Handler:
        HANDLERS[mnemonic] = (priv, fn)
        return fn

    return register


_ids = iter(range(1, 2**62))


class Session:
    """State of one client connection."""

    def __init__(self, control: Control) -> None:
        self.id = next(_ids)
        self.control = control
        self.logins: set[str] = set()
        self.cwd = WirePath("TNC:", ())
        self.buffer_size = 256
        self.secure_send = False
        self.upload: Upload | None = None
        self.sequence: Iterator[Frame] | None = None
        self.error_index = 0
        self.keyboard_locked = False
        self.scope_signals: list[object] = []
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
                return bool(have & set(FILE_LOGINS.values()))
            case Priv.MONITOR:
                return bool(have & {"MONITOR", "DIAGNOSTICS", "FILE"})
            case Priv.DIAGNOSTICS:
                return "DIAGNOSTICS" in have
            case _:
                return priv.value.upper() in have

    def check_drive(self, wp: WirePath) -> None:
        """Refuse (23) a path on a drive whose file login the session lacks."""
        if FILE_LOGINS.get(wp.drive) not in self.logins:
            raise Refuse(E.T_ER_NO_PRIV, f"no login for {wp.drive}")

    def path(self, text: str) -> WirePath:
        """Parse a wire path against the current directory and check the drive login."""
        wp = self.control.fs.parse(text, self.cwd)
        self.check_drive(wp)
        return wp

    # -- dispatch ---------------------------------------------------------------------------
    def handle(self, frame: Frame) -> Result:
        """Answer one received telegram."""
        size = 8 + len(frame.payload)
        if size > self.buffer_size:
            # Too large for the negotiated buffer (§7): refuse and abort a running upload.
            if self.upload is not None and frame.mnemonic == "S_FL":
                self.abort_upload()
                return Result([block_defect(E.T_BD_BAD_FORMAT)])
            return Result([error(E.T_ER_BAD_FORMAT)])
        if self.sequence is not None:
            if frame.mnemonic == "T_OK":
                return Result([next(self.sequence, DONE)])
            self.sequence = None
            if frame.mnemonic == "T_BD":
                return Result([])  # client stops a list, download or scope stream
        if self.upload is not None and frame.mnemonic not in ("S_FL", "T_FD", "T_BD"):
            self.abort_upload()
        entry = HANDLERS.get(frame.mnemonic)
        if entry is None:
            if frame.mnemonic in KNOWN_UNSUPPORTED:
                return Result([error(E.T_ER_WRONG_PARA)])
            if frame.mnemonic in ("T_OK", "T_FD", "T_BD", "S_FL"):
                return Result([error(E.T_ER_UNEXPECTED_TELE)])
            return Result([error(E.T_ER_UNKNOWN_TELE)])
        priv, fn = entry
        if not self.allowed(priv):
            return Result([error(E.T_ER_NO_PRIV)])
        try:
            out = fn(self, frame)
        except Refuse as exc:
            return Result([error(exc.code)])
        except FsError as exc:
            return Result([error(exc.code)])
        except (RemoteProtocolError, struct.error, ValueError, UnicodeDecodeError):
            return Result([error(E.T_ER_BAD_FORMAT)])
        return out if isinstance(out, Result) else Result(out)

    def start_sequence(self, frames: Iterator[Frame]) -> list[Frame]:
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
