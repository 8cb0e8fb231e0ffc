"""What every machine kind shares: the common configuration fields, the serial line profile,
the capabilities record, and :class:`KindSpec`, the one object a kind package exports.

A kind package (``kinds/<kind>/``) owns its configuration schema (a frozen dataclass with only
that kind's fields), the parser of its keys, its connector, its capabilities and the hooks
generic code asks instead of testing for a concrete class (where the control prints, which
folder it sends from, which share it reads). :mod:`opendnc.server.kinds.registry` holds the one
table of kinds (docs/server.md#shape-components-and-kinds).

This module names no kind: it imports only leaves (the program check's envelope, the key
readers), so every kind package, the registry and the generic server modules can import it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Any, ClassVar, Generic, TypeVar

from opendnc.nccheck.limits import Envelope
from opendnc.server.core.configkeys import ConfigError, get_key, known_keys
from opendnc.server.kinds.filedrop_config import FilesConfig

if TYPE_CHECKING:
    from opendnc.haas.listen import CapturedLine
    from opendnc.server.core.status import MachineStatus
    from opendnc.server.kinds.connector import Connector

__all__ = [
    "COMMON_KEYS",
    "Capabilities",
    "ConnectorHooks",
    "DprntSource",
    "KindSpec",
    "MachineBase",
    "MachineConfig",
    "ReceiveFolder",
    "SerialProfile",
    "SharedMachine",
    "parse_profile",
    "schema_keys",
]


@dataclass(frozen=True)
class Capabilities:
    """What the server can do with one machine."""

    file_browser: bool = False  # list, upload and delete files on the control (as jobs)
    dripfeed: bool = False  # run a program while it arrives (also needs the config's opt-in)
    dprnt: bool = False  # capture lines the program prints
    receive: bool = False  # the control sends programs by itself (punch or out-tray folder)
    status_fields: frozenset[str] = frozenset()  # which MachineStatus fields the control reports
    o_digits: int = 5  # digits of an O-number the server writes for it (a report program)


@dataclass(frozen=True, kw_only=True)
class MachineBase:
    """The fields every machine has, whatever its kind.

    ``kind`` is the kind's key in the configuration and the database (``kind = "lsv2"``),
    set by each schema; ``control_family`` and ``protected_programs`` are what the program
    check needs of the kind (:func:`opendnc.nccheck.limits_for` reads them: data, so the
    checker imports nothing of the server)."""

    kind: ClassVar[str]
    control_family: ClassVar[str | None] = None  # "heidenhain", "haas" (G-code); None: guess
    protected_programs: ClassVar[tuple[tuple[int, int], ...]] = ()  # O-numbers kept off limits

    name: str
    released_only: bool = False
    poll_interval: float = 1.0
    description: str = ""
    envelope: Envelope | None = None  # travel and work offsets for program checks (docs/check.md)
    servers: tuple[str, ...] = ()  # the servers that may serve it (a cluster); empty: any
    files: FilesConfig | None = None  # programs as files in a folder, any kind (docs/files.md)


COMMON_KEYS = {
    "name", "kind", "released_only", "poll_interval", "description", "travel", "work_offsets",
    "rapid_rate", "control", "servers", "files",
}  # fmt: skip


@dataclass(frozen=True)
class SerialProfile:
    """Line settings of one serial port, as set on the control.

    Which of them apply to an XModem transfer and which to plain text (a text load, a
    drip-feed, a text punch): docs/server.md#serial-profile.
    """

    baud: int = 9600
    parity: str = "N"
    bytesize: int = 8
    stopbits: float = 1
    flow: str = "xonxoff"
    eob: str = "CRLF"  # LF, CR, CRLF, CRCR, LFLF (Haas Setting 25)
    protocol: str = "xmodem"  # "xmodem" or "text" for loads and punches (where a kind offers both)
    leader: int = 0  # characters before the program (tape leader), plain text only
    trailer: int = 0  # characters after it
    leader_char: str = "\x00"  # what leader and trailer are made of (NUL, or e.g. "%")
    line_delay: float = 0.0  # seconds after each line, for controls without handshake
    wait_for_xon: bool = False  # a plain-text send starts at the control's first DC1
    start_trigger: str = "%"  # a text punch is captured from here ("": first character)
    end_trigger: str = "%"  # ... up to here ("": until the line goes quiet)
    idle_timeout: float = 5.0  # seconds of silence that end (or fail) a text punch

    def leader_bytes(self) -> bytes:
        """The tape leader as bytes."""
        return self.leader_char.encode("latin-1") * self.leader

    def trailer_bytes(self) -> bytes:
        """The tape trailer as bytes."""
        return self.leader_char.encode("latin-1") * self.trailer


_LINE_KEYS = {"baud", "parity", "bytesize", "stopbits", "flow"}
_PROFILE_KEYS = _LINE_KEYS | {
    "eob", "protocol", "leader", "trailer", "leader_char", "line_delay", "wait_for_xon",
    "start_trigger", "end_trigger", "idle_timeout",
}  # fmt: skip


def parse_profile(
    raw: dict[str, Any], prefix: str, default: SerialProfile, *, line_only: bool = False
) -> SerialProfile:
    """The ``serial_profile`` table; ``line_only`` for links that frame their own telegrams,
    where only the line settings mean anything."""
    known_keys(raw, prefix, _LINE_KEYS if line_only else _PROFILE_KEYS)
    # the checks run in the order of the keys below, so the first bad key is the one named
    line = _line_settings(raw, prefix, default)
    tape = _tape_settings(raw, prefix, default)
    wait_for_xon = get_key(raw, prefix, "wait_for_xon", bool, default.wait_for_xon)
    if wait_for_xon and line["flow"] != "xonxoff":
        raise ConfigError(f"{prefix}.wait_for_xon", 'needs flow = "xonxoff" (the XON is DC1)')
    idle = get_key(raw, prefix, "idle_timeout", float, default.idle_timeout)
    if not 0.1 <= idle <= 600:
        raise ConfigError(f"{prefix}.idle_timeout", "expected 0.1..600 seconds")
    return SerialProfile(**line, **tape, wait_for_xon=wait_for_xon, idle_timeout=idle)


_BAUDS = (300, 600, 1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400)
_Choice = TypeVar("_Choice", int, float, str)


def _one_of(value: _Choice, allowed: tuple[_Choice, ...], where: str, expected: str) -> _Choice:
    """``value`` if it is one of ``allowed``, else a :class:`ConfigError` at ``where``."""
    if value not in allowed:
        raise ConfigError(where, expected)
    return value


def _line_settings(raw: dict[str, Any], prefix: str, default: SerialProfile) -> dict[str, Any]:
    """The UART settings (baud, parity, bytesize, stopbits, flow) as SerialProfile fields."""
    baud = get_key(raw, prefix, "baud", int, default.baud)
    parity = get_key(raw, prefix, "parity", str, default.parity).upper()
    return {
        "baud": _one_of(baud, _BAUDS, f"{prefix}.baud", f"{baud} is not a standard rate"),
        "parity": _one_of(parity, ("N", "E", "O"), f"{prefix}.parity", "expected N, E or O"),
        "bytesize": _one_of(
            get_key(raw, prefix, "bytesize", int, default.bytesize),
            (7, 8),
            f"{prefix}.bytesize",
            "expected 7 or 8",
        ),
        "stopbits": _one_of(
            get_key(raw, prefix, "stopbits", float, float(default.stopbits)),
            (1.0, 1.5, 2.0),
            f"{prefix}.stopbits",
            "expected 1, 1.5 or 2",
        ),
        "flow": _one_of(
            get_key(raw, prefix, "flow", str, default.flow),
            ("none", "xonxoff", "rtscts"),
            f"{prefix}.flow",
            "expected none, xonxoff or rtscts",
        ),
    }


def _tape_settings(raw: dict[str, Any], prefix: str, default: SerialProfile) -> dict[str, Any]:
    """How a program is framed on the line (EOB, protocol, leader, delays, text triggers),
    as SerialProfile fields."""
    eob = get_key(raw, prefix, "eob", str, default.eob).upper()
    settings: dict[str, Any] = {
        "eob": _one_of(
            eob,
            ("CR", "LF", "CRLF", "CRCR", "LFLF"),
            f"{prefix}.eob",
            "expected CR, LF, CRLF, CRCR or LFLF",
        ),
        "protocol": _one_of(
            get_key(raw, prefix, "protocol", str, default.protocol),
            ("xmodem", "text"),
            f"{prefix}.protocol",
            "expected xmodem or text",
        ),
    }
    for key in ("leader", "trailer"):
        settings[key] = get_key(raw, prefix, key, int, getattr(default, key))
    for key in ("leader", "trailer"):
        if not 0 <= settings[key] <= 4096:
            raise ConfigError(f"{prefix}.{key}", "expected 0..4096 characters")
    settings["leader_char"] = _leader_char(raw, prefix, default)
    line_delay = get_key(raw, prefix, "line_delay", float, default.line_delay)
    if not 0 <= line_delay <= 10:
        raise ConfigError(f"{prefix}.line_delay", "expected 0..10 seconds")
    settings["line_delay"] = line_delay
    for key in ("start_trigger", "end_trigger"):
        text = get_key(raw, prefix, key, str, getattr(default, key))
        if len(text) > 16 or any(ord(c) > 0xFF for c in text):
            raise ConfigError(f"{prefix}.{key}", "expected at most 16 Latin-1 characters")
        settings[key] = text
    return settings


def _leader_char(raw: dict[str, Any], prefix: str, default: SerialProfile) -> str:
    """The leader character: one ASCII character that the control cannot take for an end of
    block or a flow-control byte (a leader of DC3 would stop the sender)."""
    leader_char: str = get_key(raw, prefix, "leader_char", str, default.leader_char)
    if len(leader_char) != 1 or ord(leader_char) > 0x7F or leader_char in "\r\n\x11\x13":
        raise ConfigError(
            f"{prefix}.leader_char",
            'expected one ASCII character ("\\u0000" or "%"), no EOB or XON/XOFF',
        )
    return leader_char


@dataclass(frozen=True)
class ConnectorHooks:
    """What the server hands a connector when it makes one: where lines the control prints
    on the connector's own link go (a control printing on the port it is loaded through), and
    where a connector whose control reports nothing tells what the server makes it do (a tape
    control drip-feeding: running), since no status poll runs during a job."""

    on_dprnt: Callable[[CapturedLine], None] | None = None
    on_status: Callable[[MachineStatus], None] | None = None


MachineConfig = MachineBase
"""One machine of the shop, of any kind (the registry's kinds parse into subclasses)."""


@dataclass(frozen=True)
class DprntSource:
    """Where a control prints its DPRNT lines: ``url`` (``tcp://HOST:PORT``) the server
    connects to, or ``own_port`` (the device the machine's connector owns and taps itself)."""

    url: str = ""
    own_port: str = ""


@dataclass(frozen=True)
class ReceiveFolder:
    """A folder on the control whose files come to the inbox by themselves (auto-receive)."""

    folder: str  # a path on the control
    pattern: str = "*"  # which files (a glob, any case)
    every: int = 5  # status polls between two listings
    after: str = "keep"  # keep or delete a received file on the control


@dataclass(frozen=True)
class SharedMachine:
    """A machine with a network share the net share fills and collects from."""

    config: MachineBase
    share: str  # a local folder or smb://...

    @property
    def name(self) -> str:
        """The machine's name."""
        return self.config.name


def _no_dprnt(config: MachineBase) -> DprntSource | None:
    return None


def _no_receive(config: MachineBase) -> ReceiveFolder | None:
    return None


def _no_text(config: MachineBase) -> str:
    return ""


M = TypeVar("M", bound=MachineBase)


@dataclass(frozen=True)
class KindSpec(Generic[M]):
    """One machine kind: its schema, the keys only it has, and what it does with a config.

    ``kind`` is the key in ``[[machines]]`` (``kind = "lsv2"``) and in the database;
    ``label`` what pages call it. ``parse(raw, prefix, common)`` reads the kind's keys from
    one ``[[machines]]`` table (``common`` holds the fields of :class:`MachineBase`, already
    checked); ``connector`` makes the link to the control; ``capabilities`` says what the
    machine can do as configured. ``misplaced`` names the kind's keys that another kind
    refuses, with the reason (the other keys of another kind are passed over with a warning:
    earlier versions took every key for every kind, and files written then keep working).

    The hooks answer what generic code needs of a configured machine, so that it never tests
    for a concrete class: ``dprnt`` where it prints, ``receive_folder`` which folder on the
    control is collected, ``program_folder`` where the file browser opens (a path on the
    control), ``share`` the network share the net share serves (``""``: none).
    """

    kind: str
    label: str
    schema: type[M]
    keys: frozenset[str]
    parse: Callable[[dict[str, Any], str, dict[str, Any]], M]
    connector: Callable[[M, ConnectorHooks], Connector]
    capabilities: Callable[[M], Capabilities]
    misplaced: dict[str, str] = field(default_factory=dict)
    dprnt: Callable[[M], DprntSource | None] = _no_dprnt
    receive_folder: Callable[[M], ReceiveFolder | None] = _no_receive
    program_folder: Callable[[M], str] = _no_text
    share: Callable[[M], str] = _no_text


def schema_keys(schema: type[MachineBase]) -> frozenset[str]:
    """The configuration keys of a schema's own fields (``profile`` is ``serial_profile``)."""
    names = {f.name for f in fields(schema)} - {f.name for f in fields(MachineBase)}
    return frozenset("serial_profile" if n == "profile" else n for n in names)
