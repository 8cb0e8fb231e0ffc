"""The server's configuration file (``shop.toml``) as typed, validated dataclasses.

Every error names the key it is about (``machines[2].port: expected ...``), so a shop that
edits the file by hand finds the mistake without reading a stack trace. Relative paths are
taken relative to the configuration file, not to the working directory, so the same file works
whether the service is started by hand or by a service manager.

Example::

    [server]
    bind = "127.0.0.1:8000"
    database = "sqlite:///opendnc.db"      # or postgresql+psycopg://user@host/db
    name = "dnc-1"                         # names this process's claims in a shared database

    [library]
    path = "programs"                      # the watched library folder
    watch = "notify"                       # or "poll" on a network share
    inbox = "inbox"                        # programs received from the controls
    archive = "archive"

    [requests]                             # remote request from the control
    delay = 5.0                            # seconds to switch the control to receive
    reports = "failures"                   # report programs sent back: failures, all, none

    [[machines]]
    name = "mill-1"
    kind = "lsv2"                          # lsv2 | haas_serial | haas_ngc
    host = "10.0.0.21"
    released_only = true

    [netshare]                             # hybrid net share (server/netshare.py)
    path = "/mnt/nas/programs"             # programs dropped here go to every machine's share
    machines = ["vf2-1", "vf2-2"]          # default: every machine with a share
    archive_at = "18:00"                   # daily, server's local time; or archive_every = 3600
    collect = true                         # programs made on the machines go to the inbox
"""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any

from opendnc.errors import InputError
from opendnc.server.requests import RequestRule, RequestSettings

__all__ = [
    "ConfigError",
    "LibraryConfig",
    "MachineConfig",
    "MachineKind",
    "NetShareConfig",
    "SerialProfile",
    "ServerConfig",
    "ShopConfig",
    "load_config",
    "parse_config",
]

# Machine names appear in URLs, file names and MQTT topics: keep them to a safe alphabet.
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")


class ConfigError(InputError):
    """The configuration file is malformed; the message names the key."""

    def __init__(self, key: str, problem: str) -> None:
        self.key = key
        self.problem = problem
        super().__init__(f"{key}: {problem}" if key else problem)


class MachineKind(StrEnum):
    """How the server reaches a control."""

    LSV2 = "lsv2"  # Heidenhain over LSV2 (TCP, or serial with `serial = "..."`)
    HAAS_SERIAL = "haas_serial"  # Haas RS-232: XModem, drip-feed, DPRNT
    HAAS_NGC = "haas_ngc"  # Haas NGC over Ethernet: MDC Q-commands and the net share


@dataclass(frozen=True)
class SerialProfile:
    """Line settings of one serial port, as set on the control."""

    baud: int = 9600
    parity: str = "N"
    bytesize: int = 8
    stopbits: float = 1
    flow: str = "xonxoff"
    eob: str = "CRLF"
    leader: int = 0  # NUL characters before the program (tape leader)
    trailer: int = 0
    line_delay: float = 0.0  # seconds after each line, for controls without handshake
    wait_for_xon: bool = False


@dataclass(frozen=True)
class MachineConfig:
    """One machine of the shop and how to reach it."""

    name: str
    kind: MachineKind
    host: str = ""
    port: int | str = 0
    serial: str = ""  # device or URL for serial links
    profile: SerialProfile = field(default_factory=SerialProfile)
    mdc_port: int = 5051
    share: str = ""  # Haas net share folder (local path or smb://)
    folder: str = ""  # where programs go on the control (LSV2: default TNC:/nc_prog)
    released_only: bool = False
    dripfeed: bool = False  # drip-feeding runs the program on the machine: an explicit opt-in
    poll_interval: float = 1.0
    description: str = ""
    mdc: bool = False  # haas_serial: status by MDC Q-commands on the port (Setting 143 ON)
    mdc_interval: float = 3.0  # haas_serial: least seconds between two MDC status reads
    dprnt: str = ""  # DPRNT to capture: tcp://HOST:PORT (NGC Setting 263), "serial" (RS-232)


@dataclass(frozen=True)
class LibraryConfig:
    """The folders the server keeps programs in."""

    path: Path
    inbox: Path
    archive: Path
    backups: Path | None = None  # LSV2 backups, one folder per machine (default: ./backups)
    poll: bool = False  # poll the library folder instead of change notifications (shares)


@dataclass(frozen=True)
class NetShareConfig:
    """The hybrid net share: a NAS folder fanned out to machines' shares (server/netshare.py)."""

    path: Path  # the NAS folder (mounted)
    machines: tuple[str, ...]  # subscribed machines (each has a share)
    archive: Path  # where archived programs go, in one folder per day
    archive_at: tuple[int, int] | None = (18, 0)  # daily, server's local time
    archive_every: float | None = None  # or every so many seconds
    collect: bool = True  # programs made on the machines go to the inbox
    interval: float = 5.0  # seconds between scans


@dataclass(frozen=True)
class ServerConfig:
    """The service itself: where it listens, which database, its own name."""

    bind_host: str = "127.0.0.1"
    bind_port: int = 8000
    database: str = ""
    name: str = "opendnc"
    timeline_days: float = 7.0  # status samples older than this are pruned


@dataclass(frozen=True)
class ShopConfig:
    """The whole configuration file."""

    server: ServerConfig
    library: LibraryConfig
    machines: tuple[MachineConfig, ...]
    source: Path | None = None
    requests: RequestSettings = field(default_factory=RequestSettings)
    netshare: NetShareConfig | None = None

    def machine(self, name: str) -> MachineConfig:
        """The machine called ``name``; :class:`InputError` if there is none."""
        for machine in self.machines:
            if machine.name == name:
                return machine
        raise InputError(f"no machine named {name!r} in the configuration")


def load_config(path: str | Path) -> ShopConfig:
    """Read and validate ``path``; :class:`ConfigError` names the first bad key."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError("", f"cannot read {path}: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError("", f"{path} is not UTF-8 text") from exc
    return parse_config(text, base=path.parent.resolve(), source=path)


def parse_config(text: str, *, base: Path, source: Path | None = None) -> ShopConfig:
    """Validate the TOML ``text``; relative paths are taken from ``base``."""
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError("", f"not valid TOML: {exc}") from exc
    _known(raw, "", {"server", "library", "machines", "requests", "netshare"})
    server = _server(_table(raw, "server"), base)
    library = _library(_table(raw, "library"), base)
    machines_raw = raw.get("machines", [])
    if not isinstance(machines_raw, list):
        raise ConfigError("machines", "expected an array of tables ([[machines]])")
    machines = tuple(_machine(item, f"machines[{i}]") for i, item in enumerate(machines_raw))
    seen: set[str] = set()
    for i, machine in enumerate(machines):
        if machine.name.lower() in seen:
            raise ConfigError(f"machines[{i}].name", f"{machine.name!r} is used twice")
        seen.add(machine.name.lower())
    requests = _requests(_table(raw, "requests"))
    netshare = None
    if "netshare" in raw:
        netshare = _netshare(_table(raw, "netshare"), base, library, machines)
    return ShopConfig(
        server=server,
        library=library,
        machines=machines,
        source=source,
        requests=requests,
        netshare=netshare,
    )


def _netshare(
    table: dict[str, Any], base: Path, library: LibraryConfig, machines: tuple[MachineConfig, ...]
) -> NetShareConfig:
    keys = {"path", "machines", "archive", "archive_at", "archive_every", "collect", "interval"}
    _known(table, "netshare", keys)
    path_text = _get(table, "netshare", "path", str, "")
    if not path_text:
        raise ConfigError("netshare.path", "missing (the NAS folder, mounted on this computer)")
    if "://" in path_text:
        raise ConfigError("netshare.path", "expected a folder (mount the NAS share first)")
    with_share = {m.name: m for m in machines if m.share}
    names_raw = table.get("machines")
    if names_raw is None:
        names = tuple(with_share)
    else:
        if not isinstance(names_raw, list) or not names_raw:
            raise ConfigError("netshare.machines", "expected a list of machine names")
        for i, name in enumerate(names_raw):
            key = f"netshare.machines[{i}]"
            if not isinstance(name, str):
                raise ConfigError(key, f"expected a machine name, got {name!r}")
            if name not in {m.name for m in machines}:
                raise ConfigError(key, f"no machine named {name!r}")
            if name not in with_share:
                raise ConfigError(key, f"{name!r} has no share to push to")
        names = tuple(dict.fromkeys(names_raw))
    if not names:
        raise ConfigError("netshare.machines", "no machine has a share to subscribe")
    archive_at: tuple[int, int] | None = (18, 0)
    archive_every: float | None = None
    if "archive_at" in table and "archive_every" in table:
        raise ConfigError("netshare.archive_every", "use archive_at or archive_every, not both")
    if "archive_at" in table:
        text = _get(table, "netshare", "archive_at", str, "")
        match = re.fullmatch(r"([01]?\d|2[0-3]):([0-5]\d)", text.strip())
        if match is None:
            raise ConfigError("netshare.archive_at", f"expected HH:MM (24 h), got {text!r}")
        archive_at = (int(match.group(1)), int(match.group(2)))
    if "archive_every" in table:
        archive_every = _get(table, "netshare", "archive_every", float, 0.0)
        if not 1 <= archive_every <= 366 * 86400:
            raise ConfigError("netshare.archive_every", "expected seconds, 1 up to a year")
        archive_at = None
    interval = _get(table, "netshare", "interval", float, 5.0)
    if not 0.05 <= interval <= 3600:
        raise ConfigError("netshare.interval", "expected seconds between 0.05 and 3600")
    archive_text = _get(table, "netshare", "archive", str, "")
    return NetShareConfig(
        path=(base / path_text).resolve(),
        machines=names,
        archive=(base / archive_text).resolve() if archive_text else library.archive / "netshare",
        archive_at=archive_at,
        archive_every=archive_every,
        collect=_get(table, "netshare", "collect", bool, True),
        interval=interval,
    )


def _requests(table: dict[str, Any]) -> RequestSettings:
    _known(table, "requests", {"delay", "scan_lines", "report_program", "reports", "rules"})
    default = RequestSettings()
    delay = _get(table, "requests", "delay", float, default.delay)
    if not 0 <= delay <= 600:
        raise ConfigError("requests.delay", "expected 0..600 seconds")
    scan = _get(table, "requests", "scan_lines", int, default.scan_lines)
    if not 1 <= scan <= 100:
        raise ConfigError("requests.scan_lines", "expected 1..100 lines")
    number = _get(table, "requests", "report_program", int, default.report_program)
    if not 1 <= number <= 99999:
        raise ConfigError("requests.report_program", "expected an O-number 1..99999")
    reports = _get(table, "requests", "reports", str, default.reports)
    if reports not in ("failures", "all", "none"):
        raise ConfigError("requests.reports", "expected failures, all or none")
    rules_raw = table.get("rules")
    rules = default.rules
    if rules_raw is not None:
        if not isinstance(rules_raw, list) or not rules_raw:
            raise ConfigError("requests.rules", "expected an array of tables ([[requests.rules]])")
        built = []
        for i, item in enumerate(rules_raw):
            key = f"requests.rules[{i}]"
            if not isinstance(item, dict):
                raise ConfigError(key, "expected a table")
            _known(item, key, {"pattern", "template"})
            pattern = _get(item, key, "pattern", str, "")
            template = _get(item, key, "template", str, "")
            if not pattern or not template:
                raise ConfigError(key, "needs pattern and template")
            try:
                built.append(RequestRule.make(pattern, template, key=key))
            except InputError as exc:
                raise ConfigError(key, str(exc).removeprefix(f"{key}.")) from None
        rules = tuple(built)
    return RequestSettings(
        delay=delay, scan_lines=scan, report_program=number, reports=reports, rules=rules
    )


def _table(raw: dict[str, Any], key: str) -> dict[str, Any]:
    value = raw.get(key, {})
    if not isinstance(value, dict):
        raise ConfigError(key, "expected a table")
    return value


def _known(table: dict[str, Any], prefix: str, keys: set[str]) -> None:
    # A misspelt key silently ignored is the worst kind of configuration error.
    for key in table:
        if key not in keys:
            name = f"{prefix}.{key}" if prefix else key
            raise ConfigError(name, f"unknown key (expected one of {', '.join(sorted(keys))})")


def _get(table: dict[str, Any], prefix: str, key: str, kind: type, default: Any) -> Any:
    value = table.get(key, default)
    # bool is an int in Python; a TOML `port = true` must not pass as port 1.
    if kind in (int, float) and isinstance(value, bool):
        raise ConfigError(f"{prefix}.{key}", f"expected a number, got {value!r}")
    if kind is float and isinstance(value, int):
        value = float(value)
    if not isinstance(value, kind):
        raise ConfigError(f"{prefix}.{key}", f"expected {kind.__name__}, got {value!r}")
    return value


def _server(table: dict[str, Any], base: Path) -> ServerConfig:
    _known(table, "server", {"bind", "database", "name", "timeline_retention_days"})
    bind = _get(table, "server", "bind", str, "127.0.0.1:8000")
    host, sep, port_text = bind.rpartition(":")
    # Port 0 takes any free port (tests, the demo); the server prints the one it got.
    if not sep or not host or not port_text.isdigit() or not 0 <= int(port_text) < 65536:
        raise ConfigError("server.bind", f"expected HOST:PORT, got {bind!r}")
    database = _get(table, "server", "database", str, "")
    if not database:
        database = f"sqlite:///{base / 'opendnc.db'}"
    elif database.startswith("sqlite:///") and not database.startswith("sqlite:////"):
        relative = database.removeprefix("sqlite:///")
        if relative and relative != ":memory:":
            database = f"sqlite:///{base / relative}"
    elif not re.match(r"^(sqlite|postgresql)(\+\w+)?://", database):
        raise ConfigError("server.database", "expected a sqlite:/// or postgresql+psycopg:// URL")
    name = _get(table, "server", "name", str, "opendnc")
    if not _NAME.fullmatch(name):
        raise ConfigError("server.name", "use letters, digits, '-', '_' or '.' (at most 64)")
    days = _get(table, "server", "timeline_retention_days", float, 7.0)
    if not 0 < days <= 3660:
        raise ConfigError("server.timeline_retention_days", "expected days, more than 0")
    return ServerConfig(
        bind_host=host.strip("[]"),
        bind_port=int(port_text),
        database=database,
        name=name,
        timeline_days=float(days),
    )


def _library(table: dict[str, Any], base: Path) -> LibraryConfig:
    _known(table, "library", {"path", "inbox", "archive", "backups", "watch"})
    watch = _get(table, "library", "watch", str, "notify")
    if watch not in ("notify", "poll"):
        raise ConfigError("library.watch", "expected notify or poll (poll for network shares)")

    def folder(key: str, default: str) -> Path:
        value: str = _get(table, "library", key, str, default)
        if not value:
            raise ConfigError(f"library.{key}", "must not be empty")
        return (base / value).resolve()

    return LibraryConfig(
        path=folder("path", "programs"),
        inbox=folder("inbox", "inbox"),
        archive=folder("archive", "archive"),
        backups=folder("backups", "backups"),
        poll=watch == "poll",
    )


_MACHINE_KEYS = {
    "name", "kind", "host", "port", "serial", "serial_profile", "mdc_port", "share", "folder",
    "released_only", "dripfeed", "poll_interval", "description", "mdc", "mdc_interval", "dprnt",
}  # fmt: skip
_PROFILE_KEYS = {
    "baud", "parity", "bytesize", "stopbits", "flow", "eob", "leader", "trailer", "line_delay",
    "wait_for_xon",
}  # fmt: skip


def _machine(raw: Any, prefix: str) -> MachineConfig:
    if not isinstance(raw, dict):
        raise ConfigError(prefix, "expected a table")
    _known(raw, prefix, _MACHINE_KEYS)
    if "name" not in raw:
        raise ConfigError(f"{prefix}.name", "missing")
    name = _get(raw, prefix, "name", str, "")
    if not _NAME.fullmatch(name):
        raise ConfigError(f"{prefix}.name", "use letters, digits, '-', '_' or '.' (at most 64)")
    kind_text = _get(raw, prefix, "kind", str, "")
    try:
        kind = MachineKind(kind_text)
    except ValueError:
        choices = ", ".join(k.value for k in MachineKind)
        raise ConfigError(f"{prefix}.kind", f"expected one of {choices}") from None
    host = _get(raw, prefix, "host", str, "")
    serial = _get(raw, prefix, "serial", str, "")
    port = raw.get("port", 0)
    if raw.get("dripfeed") is True and kind is not MachineKind.HAAS_SERIAL:
        raise ConfigError(f"{prefix}.dripfeed", "drip-feed is for serial Haas machines")
    if kind is MachineKind.LSV2:
        if not host and not serial:
            raise ConfigError(f"{prefix}.host", "an LSV2 machine needs host (TCP) or serial")
        port = _get(raw, prefix, "port", int, 19000)
        _port_range(port, f"{prefix}.port")
    elif kind is MachineKind.HAAS_SERIAL:
        if not serial:
            raise ConfigError(f"{prefix}.serial", "a serial Haas needs a device or URL")
    elif not host:
        raise ConfigError(f"{prefix}.host", "a Haas NGC needs the control's address")
    mdc_port = _get(raw, prefix, "mdc_port", int, 5051)
    _port_range(mdc_port, f"{prefix}.mdc_port")
    poll = _get(raw, prefix, "poll_interval", float, 1.0)
    if not 0.05 <= poll <= 3600:
        raise ConfigError(f"{prefix}.poll_interval", "expected seconds between 0.05 and 3600")
    mdc = _get(raw, prefix, "mdc", bool, False)
    if mdc and kind is not MachineKind.HAAS_SERIAL:
        raise ConfigError(
            f"{prefix}.mdc", "only for haas_serial (a Haas NGC always reports by MDC over TCP)"
        )
    # Classic controls have frozen under fast serial polling: 3 s apart by default
    # (docs/haas.md#mdc-polling).
    mdc_interval = _get(raw, prefix, "mdc_interval", float, 3.0)
    if not 0.05 <= mdc_interval <= 3600:
        raise ConfigError(f"{prefix}.mdc_interval", "expected seconds between 0.05 and 3600")
    dprnt = _dprnt_source(_get(raw, prefix, "dprnt", str, ""), kind, f"{prefix}.dprnt")
    return MachineConfig(
        name=name,
        kind=kind,
        host=host,
        port=port,
        serial=serial,
        profile=_profile(
            _table(raw, "serial_profile"),
            f"{prefix}.serial_profile",
            # LSV2 over RS-232 runs at 57600 baud 8E1 without flow control by default (the
            # controls' own default); a Haas at 9600 8N1 with XON/XOFF.
            LSV2_SERIAL if kind is MachineKind.LSV2 else SerialProfile(),
        ),
        mdc_port=mdc_port,
        share=_get(raw, prefix, "share", str, ""),
        folder=_get(raw, prefix, "folder", str, ""),
        released_only=_get(raw, prefix, "released_only", bool, False),
        dripfeed=_get(raw, prefix, "dripfeed", bool, False),
        poll_interval=poll,
        description=_get(raw, prefix, "description", str, ""),
        mdc=mdc,
        mdc_interval=mdc_interval,
        dprnt=dprnt,
    )


def _dprnt_source(value: str, kind: MachineKind, key: str) -> str:
    """``tcp://HOST:PORT`` (where a Haas NGC prints, Setting 263) or ``serial`` (a serial
    Haas's own port); empty for none."""
    if not value:
        return ""
    if kind is MachineKind.LSV2:
        raise ConfigError(key, "DPRNT is a Haas feature")
    if value == "serial":
        if kind is not MachineKind.HAAS_SERIAL:
            raise ConfigError(key, "serial is for a haas_serial machine (its own port)")
        return value
    match = re.fullmatch(r"tcp://([^:/\s]+|\[[0-9A-Fa-f:]+\]):(\d{1,5})", value)
    if match is None or not 0 < int(match.group(2)) < 65536:
        raise ConfigError(key, f"expected tcp://HOST:PORT or serial, got {value!r}")
    return value


def _port_range(port: int, key: str) -> None:
    if not 0 < port < 65536:
        raise ConfigError(key, f"expected a TCP port 1..65535, got {port}")


LSV2_SERIAL = SerialProfile(baud=57600, parity="E", flow="none")


def _profile(raw: dict[str, Any], prefix: str, default: SerialProfile) -> SerialProfile:
    _known(raw, prefix, _PROFILE_KEYS)
    baud = _get(raw, prefix, "baud", int, default.baud)
    if baud not in (300, 600, 1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400):
        raise ConfigError(f"{prefix}.baud", f"{baud} is not a standard rate")
    parity = _get(raw, prefix, "parity", str, default.parity).upper()
    if parity not in ("N", "E", "O"):
        raise ConfigError(f"{prefix}.parity", "expected N, E or O")
    bytesize = _get(raw, prefix, "bytesize", int, default.bytesize)
    if bytesize not in (7, 8):
        raise ConfigError(f"{prefix}.bytesize", "expected 7 or 8")
    stopbits = _get(raw, prefix, "stopbits", float, float(default.stopbits))
    if stopbits not in (1.0, 1.5, 2.0):
        raise ConfigError(f"{prefix}.stopbits", "expected 1, 1.5 or 2")
    flow = _get(raw, prefix, "flow", str, default.flow)
    if flow not in ("none", "xonxoff", "rtscts"):
        raise ConfigError(f"{prefix}.flow", "expected none, xonxoff or rtscts")
    eob = _get(raw, prefix, "eob", str, default.eob).upper()
    if eob not in ("CR", "LF", "CRLF"):
        raise ConfigError(f"{prefix}.eob", "expected CR, LF or CRLF")
    leader = _get(raw, prefix, "leader", int, 0)
    trailer = _get(raw, prefix, "trailer", int, 0)
    for key, value in (("leader", leader), ("trailer", trailer)):
        if not 0 <= value <= 4096:
            raise ConfigError(f"{prefix}.{key}", "expected 0..4096 characters")
    line_delay = _get(raw, prefix, "line_delay", float, 0.0)
    if not 0 <= line_delay <= 10:
        raise ConfigError(f"{prefix}.line_delay", "expected 0..10 seconds")
    return SerialProfile(
        baud=baud,
        parity=parity,
        bytesize=bytesize,
        stopbits=stopbits,
        flow=flow,
        eob=eob,
        leader=leader,
        trailer=trailer,
        line_delay=line_delay,
        wait_for_xon=_get(raw, prefix, "wait_for_xon", bool, False),
    )
