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
    receive_folder = "TNC:/nc_prog/out"    # files put here go to the inbox (auto-receive)
    receive_pattern = "*.h"                # optional, default every file
    after_receive = "keep"                 # or "delete" on the control once received

    [[machines]]
    name = "lathe-2"
    kind = "haas_serial"
    serial = "/dev/ttyUSB0"
    [machines.serial_profile]              # plain text, not XModem (docs/server.md#serial-profile)
    baud = 9600
    protocol = "text"
    eob = "CRLF"
    leader = 20                            # NULs before the program, trailer after it
    trailer = 20
    line_delay = 0.05                      # seconds after each line (small-buffer controls)
    wait_for_xon = true
    idle_timeout = 5.0                     # a text punch without its closing % fails after this

    [netshare]                             # hybrid net share (server/netshare.py)
    path = "/mnt/nas/programs"             # programs dropped here go to every machine's share
                                           # (or "smb://nas.local/cnc/programs", polled, with
    # username = "dnc"                     #  its login here or in the URL: user:pw@host)
    # password = "..."
    machines = ["vf2-1", "vf2-2"]          # default: every machine with a share
    archive_at = "18:00"                   # daily, server's local time; or archive_every = 3600
    collect = true                         # programs made on the machines go to the inbox

    [mqtt]                                 # MQTT publisher (server/mqtt.py)
    url = "mqtt://127.0.0.1:1883"          # mqtts:// for TLS
    prefix = "acme/plant1/milling"         # ISA-95-like: enterprise/site/area
    username = "dnc"                       # optional, with password
    password = "secret"

    [mtconnect]                            # MTConnect SHDR adapter (server/shdr.py)
    bind = "127.0.0.1:7878"                # the first machine's port; the next ones count up
    ports = { "mill-1" = 7900 }            # optional: a machine's own port
"""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass, field, replace
from enum import StrEnum
from pathlib import Path
from typing import Any

from opendnc.errors import InputError
from opendnc.haas.share import ShareTarget, parse_target
from opendnc.server.requests import RequestRule, RequestSettings
from opendnc.server.shifts import Calendar, CalendarError, parse_calendar

__all__ = [
    "ConfigError",
    "LibraryConfig",
    "MachineConfig",
    "MachineKind",
    "MqttConfig",
    "MtconnectConfig",
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
    protocol: str = "xmodem"  # haas_serial: "xmodem" or "text" for loads and punches
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
    receive_folder: str = ""  # lsv2: a folder on the control whose files come to the inbox
    receive_pattern: str = "*"  # lsv2: which files of receive_folder (a glob, any case)
    receive_every: int = 5  # lsv2: status polls between two listings of receive_folder
    after_receive: str = "keep"  # lsv2: keep or delete a received file on the control


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

    path: Path | ShareTarget  # the NAS folder: mounted, or reached over SMB (with its login)
    machines: tuple[str, ...]  # subscribed machines (each has a share)
    archive: Path  # where archived programs go, in one folder per day
    archive_at: tuple[int, int] | None = (18, 0)  # daily, server's local time
    archive_every: float | None = None  # or every so many seconds
    collect: bool = True  # programs made on the machines go to the inbox
    interval: float = 5.0  # seconds between scans


@dataclass(frozen=True)
class MqttConfig:
    """Where the MQTT publisher sends the machines' state (server/mqtt.py)."""

    host: str
    port: int = 1883
    tls: bool = False  # mqtts://
    ca_file: Path | None = None  # a private CA for the broker's certificate (TLS)
    prefix: str = "opendnc"
    username: str = ""
    password: str = ""
    queue: int = 10000  # messages kept while the broker is away; the oldest go first


@dataclass(frozen=True)
class MtconnectConfig:
    """The MTConnect SHDR adapter: one TCP port per machine (server/shdr.py)."""

    host: str
    ports: dict[str, int]  # machine name -> port (0: any free port)


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
    mqtt: MqttConfig | None = None
    mtconnect: MtconnectConfig | None = None
    calendar: Calendar = field(default_factory=Calendar)  # time zone and shifts

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
    _known(
        raw,
        "",
        {"server", "library", "machines", "requests", "netshare", "mqtt", "mtconnect", "shifts"},
    )
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
    mqtt = _mqtt(_table(raw, "mqtt"), base) if "mqtt" in raw else None
    mtconnect = _mtconnect(_table(raw, "mtconnect"), machines) if "mtconnect" in raw else None
    try:
        calendar = parse_calendar(raw)  # [server] timezone and [[shifts]] (server/shifts.py)
    except CalendarError as exc:
        key, _, problem = str(exc).partition(": ")  # the calendar's messages start with the key
        raise ConfigError(key, problem) from None
    return ShopConfig(
        server=server,
        library=library,
        machines=machines,
        source=source,
        requests=requests,
        netshare=netshare,
        mqtt=mqtt,
        mtconnect=mtconnect,
        calendar=calendar,
    )


def _mqtt(table: dict[str, Any], base: Path) -> MqttConfig:
    keys = {"url", "prefix", "username", "password", "ca_file", "queue"}
    _known(table, "mqtt", keys)
    url = _get(table, "mqtt", "url", str, "")
    match = re.fullmatch(r"(mqtts?)://([^:/\s]+|\[[0-9A-Fa-f:]+\])(?::(\d{1,5}))?/?", url)
    if match is None:
        raise ConfigError("mqtt.url", f"expected mqtt://HOST[:PORT] or mqtts://..., got {url!r}")
    tls = match.group(1) == "mqtts"
    port = int(match.group(3)) if match.group(3) else (8883 if tls else 1883)
    _port_range(port, "mqtt.url")
    prefix = _get(table, "mqtt", "prefix", str, "opendnc")
    levels = prefix.split("/")
    # Wildcards and '$' topics belong to subscribers and the broker; an empty level is a typo.
    if not prefix or any(not level or set(level) & {"+", "#", "\0"} for level in levels):
        raise ConfigError("mqtt.prefix", "expected topic levels like enterprise/site/area")
    if prefix.startswith("$"):
        raise ConfigError("mqtt.prefix", "topics starting with '$' are the broker's")
    username = _get(table, "mqtt", "username", str, "")
    password = _get(table, "mqtt", "password", str, "")
    if password and not username:
        raise ConfigError("mqtt.password", "a password needs a username")
    ca_text = _get(table, "mqtt", "ca_file", str, "")
    if ca_text and not tls:
        raise ConfigError("mqtt.ca_file", "a CA file is for TLS (mqtts://)")
    queue = _get(table, "mqtt", "queue", int, 10000)
    if not 10 <= queue <= 1_000_000:
        raise ConfigError("mqtt.queue", "expected 10..1000000 messages")
    return MqttConfig(
        host=match.group(2).strip("[]"),
        port=port,
        tls=tls,
        ca_file=(base / ca_text).resolve() if ca_text else None,
        prefix=prefix,
        username=username,
        password=password,
        queue=queue,
    )


def _mtconnect(table: dict[str, Any], machines: tuple[MachineConfig, ...]) -> MtconnectConfig:
    _known(table, "mtconnect", {"bind", "ports"})
    bind = _get(table, "mtconnect", "bind", str, "127.0.0.1:7878")
    host, sep, port_text = bind.rpartition(":")
    if not sep or not host or not port_text.isdigit() or not 0 <= int(port_text) < 65536:
        raise ConfigError("mtconnect.bind", f"expected HOST:PORT, got {bind!r}")
    first = int(port_text)
    explicit = table.get("ports", {})
    if not isinstance(explicit, dict):
        raise ConfigError("mtconnect.ports", "expected a table of machine = port")
    names = [m.name for m in machines]
    for name, port in explicit.items():
        key = f"mtconnect.ports.{name}"
        if name not in names:
            raise ConfigError(key, f"no machine named {name!r}")
        if isinstance(port, bool) or not isinstance(port, int):
            raise ConfigError(key, f"expected a port number, got {port!r}")
        _port_range(port, key)
    if first and first + len(machines) > 65536:
        raise ConfigError("mtconnect.bind", f"{len(machines)} machines need ports above {first}")
    ports: dict[str, int] = {}
    # Machines without their own port count up from the bind port in configuration order.
    for i, name in enumerate(names):
        ports[name] = explicit.get(name, first + i if first else 0)
    seen: dict[int, str] = {}
    for name, port in ports.items():
        if port and port in seen:
            key = f"mtconnect.ports.{name}" if name in explicit else "mtconnect.bind"
            raise ConfigError(key, f"{name} and {seen[port]} would both listen on port {port}")
        seen[port] = name
    return MtconnectConfig(host=host.strip("[]"), ports=ports)


def _nas(table: dict[str, Any], path_text: str, base: Path) -> Path | ShareTarget:
    """The NAS of ``[netshare]``: a folder, or ``smb://`` with its login from the URL or from
    ``username`` / ``password`` (no message here repeats the URL or the password)."""
    for key in ("username", "password"):
        if key in table and not isinstance(table[key], str):
            raise ConfigError(f"netshare.{key}", "expected a string")
    username, password = table.get("username"), table.get("password")
    if not path_text.lower().startswith("smb://"):
        if "://" in path_text:
            raise ConfigError("netshare.path", "expected a folder or smb://HOST/SHARE/PATH")
        if username is not None or password is not None:
            key = "username" if username is not None else "password"
            raise ConfigError(f"netshare.{key}", "only for a NAS reached by smb://")
        return (base / path_text).resolve()
    try:
        target = parse_target(path_text)
    except InputError:
        raise ConfigError(
            "netshare.path", "expected smb://[USER[:PASSWORD]@]HOST[:PORT]/SHARE[/PATH]"
        ) from None
    if username is not None:
        if target.username is not None:
            raise ConfigError("netshare.username", "the user is in the URL already: use one")
        target = replace(target, username=username)
    if password is not None:
        if target.password is not None:
            raise ConfigError("netshare.password", "the password is in the URL already: use one")
        target = replace(target, password=password)
    return target


def _netshare(
    table: dict[str, Any], base: Path, library: LibraryConfig, machines: tuple[MachineConfig, ...]
) -> NetShareConfig:
    keys = {"path", "machines", "archive", "archive_at", "archive_every", "collect", "interval"}
    _known(table, "netshare", keys | {"username", "password"})
    path_text = _get(table, "netshare", "path", str, "")
    if not path_text:
        raise ConfigError(
            "netshare.path", "missing (the NAS folder, mounted here, or smb://HOST/SHARE/PATH)"
        )
    nas: Path | ShareTarget = _nas(table, path_text, base)
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
        path=nas,
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
    _known(table, "server", {"bind", "database", "name", "timeline_retention_days", "timezone"})
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
    "receive_folder", "receive_pattern", "receive_every", "after_receive",
}  # fmt: skip
_LINE_KEYS = {"baud", "parity", "bytesize", "stopbits", "flow"}
_PROFILE_KEYS = _LINE_KEYS | {
    "eob", "protocol", "leader", "trailer", "leader_char", "line_delay", "wait_for_xon",
    "start_trigger", "end_trigger", "idle_timeout",
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
    receive = _receive(raw, prefix, kind)
    profile = _profile(
        _table(raw, "serial_profile"),
        f"{prefix}.serial_profile",
        # LSV2 over RS-232 runs at 57600 baud 8E1 without flow control by default (the
        # controls' own default); a Haas at 9600 8N1 with XON/XOFF.
        LSV2_SERIAL if kind is MachineKind.LSV2 else SerialProfile(),
        lsv2=kind is MachineKind.LSV2,
    )
    if dprnt == "serial" and profile.protocol == "text":
        # Printed lines and a punched program are both plain text on the one port.
        raise ConfigError(
            f"{prefix}.dprnt",
            'serial DPRNT needs protocol = "xmodem" (a text '
            "punch and a printed line cannot be told apart)",
        )
    return MachineConfig(
        name=name,
        kind=kind,
        host=host,
        port=port,
        serial=serial,
        profile=profile,
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
        receive_folder=receive[0],
        receive_pattern=receive[1],
        receive_every=receive[2],
        after_receive=receive[3],
    )


def _receive(raw: dict[str, Any], prefix: str, kind: MachineKind) -> tuple[str, str, int, str]:
    """The auto-receive folder of an LSV2 machine: (folder, pattern, every, after)."""
    folder = _get(raw, prefix, "receive_folder", str, "")
    pattern = _get(raw, prefix, "receive_pattern", str, "*")
    every = _get(raw, prefix, "receive_every", int, 5)
    after = _get(raw, prefix, "after_receive", str, "keep")
    if not folder:
        for key in ("receive_pattern", "receive_every", "after_receive"):
            if key in raw:
                raise ConfigError(f"{prefix}.{key}", "needs receive_folder")
        return "", pattern, every, after
    if kind is not MachineKind.LSV2:
        raise ConfigError(
            f"{prefix}.receive_folder",
            "only for lsv2 (a serial Haas punches by itself, a Haas NGC's share is collected)",
        )
    from opendnc.server.machine_files import check_path  # it imports this module

    try:
        folder = check_path(folder)
    except InputError as exc:
        raise ConfigError(f"{prefix}.receive_folder", str(exc)) from None
    if not pattern or len(pattern) > 100 or any(c in pattern for c in "/\\:"):
        raise ConfigError(f"{prefix}.receive_pattern", "expected a file name glob like *.h")
    if not 1 <= every <= 10_000:
        raise ConfigError(f"{prefix}.receive_every", "expected 1..10000 polls")
    if after not in ("keep", "delete"):
        raise ConfigError(f"{prefix}.after_receive", "expected keep or delete")
    return folder, pattern, every, after


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


def _profile(
    raw: dict[str, Any], prefix: str, default: SerialProfile, *, lsv2: bool = False
) -> SerialProfile:
    # LSV2 frames its own telegrams: only the line settings mean anything there.
    _known(raw, prefix, _LINE_KEYS if lsv2 else _PROFILE_KEYS)
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
    if eob not in ("CR", "LF", "CRLF", "CRCR", "LFLF"):
        raise ConfigError(f"{prefix}.eob", "expected CR, LF, CRLF, CRCR or LFLF")
    protocol = _get(raw, prefix, "protocol", str, default.protocol)
    if protocol not in ("xmodem", "text"):
        raise ConfigError(f"{prefix}.protocol", "expected xmodem or text")
    leader = _get(raw, prefix, "leader", int, default.leader)
    trailer = _get(raw, prefix, "trailer", int, default.trailer)
    for key, value in (("leader", leader), ("trailer", trailer)):
        if not 0 <= value <= 4096:
            raise ConfigError(f"{prefix}.{key}", "expected 0..4096 characters")
    leader_char = _get(raw, prefix, "leader_char", str, default.leader_char)
    if len(leader_char) != 1 or ord(leader_char) > 0x7F or leader_char in "\r\n\x11\x13":
        raise ConfigError(
            f"{prefix}.leader_char",
            'expected one ASCII character ("\\u0000" or "%"), no EOB or XON/XOFF',
        )
    line_delay = _get(raw, prefix, "line_delay", float, default.line_delay)
    if not 0 <= line_delay <= 10:
        raise ConfigError(f"{prefix}.line_delay", "expected 0..10 seconds")
    triggers = {}
    for key in ("start_trigger", "end_trigger"):
        text = _get(raw, prefix, key, str, getattr(default, key))
        if len(text) > 16 or any(ord(c) > 0xFF for c in text):
            raise ConfigError(f"{prefix}.{key}", "expected at most 16 Latin-1 characters")
        triggers[key] = text
    wait_for_xon = _get(raw, prefix, "wait_for_xon", bool, default.wait_for_xon)
    if wait_for_xon and flow != "xonxoff":
        raise ConfigError(f"{prefix}.wait_for_xon", 'needs flow = "xonxoff" (the XON is DC1)')
    idle = _get(raw, prefix, "idle_timeout", float, default.idle_timeout)
    if not 0.1 <= idle <= 600:
        raise ConfigError(f"{prefix}.idle_timeout", "expected 0.1..600 seconds")
    return SerialProfile(
        baud=baud,
        parity=parity,
        bytesize=bytesize,
        stopbits=stopbits,
        flow=flow,
        eob=eob,
        protocol=protocol,
        leader=leader,
        trailer=trailer,
        leader_char=leader_char,
        line_delay=line_delay,
        wait_for_xon=wait_for_xon,
        start_trigger=triggers["start_trigger"],
        end_trigger=triggers["end_trigger"],
        idle_timeout=idle,
    )
