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
    lease_seconds = 10                     # several servers: a dead one's machines move after this
    cluster = true                         # PostgreSQL: false for a lone server (no fencing)
    resume_wait = 60                       # a feed taken over: seconds its position is awaited

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
    servers = ["dnc-1"]                    # several servers: only dnc-1 reaches this port
    [machines.serial_profile]              # plain text, not XModem (docs/server.md#serial-profile)
    baud = 9600
    protocol = "text"
    eob = "CRLF"
    leader = 20                            # NULs before the program, trailer after it
    trailer = 20
    line_delay = 0.05                      # seconds after each line (small-buffer controls)
    wait_for_xon = true
    idle_timeout = 5.0                     # a text punch without its closing % fails after this

    [netshare]                             # hybrid net share (server/netshare/share.py)
    path = "/mnt/nas/programs"             # programs dropped here go to every machine's share
                                           # (or "smb://nas.local/cnc/programs", polled, with
    # username = "dnc"                     #  its login here or in the URL: user:pw@host)
    # password = "..."
    machines = ["vf2-1", "vf2-2"]          # default: every machine with a share
    archive_at = "18:00"                   # daily, server's local time; or archive_every = 3600
    collect = true                         # programs made on the machines go to the inbox

    [mqtt]                                 # MQTT publisher (server/outputs/mqtt.py)
    url = "mqtt://127.0.0.1:1883"          # mqtts:// for TLS
    prefix = "acme/plant1/milling"         # ISA-95-like: enterprise/site/area
    username = "dnc"                       # optional, with password
    password = "secret"

    [sparkplug]                            # Sparkplug B edge node (server/outputs/sparkplug.py)
    url = "mqtt://127.0.0.1:1883"          # its own broker link (mqtts:// for TLS)
    group = "plant1"                       # the Sparkplug group id
    node = "dnc-1"                         # the edge node id (default: the server's name)
    primary_host = "scada"                 # optional: publish only while this host is online

    [clients]                              # what one HTTP client may hold (server/http/clients.py)
    send_timeout = 30                      # a client that takes nothing for this long is cut
    heartbeat = 5                          # an event stream's keep-alive comment, seconds
    stream_idle = 900                      # a stream with only keep-alives this long ends
    streams_per_user = 200                 # event streams open at once, per user
    streams_total = 2000                   # ... and on the server

    [[machines]]
    name = "okuma-1"                       # any kind: status from its MTConnect agent ...
    kind = "mtconnect"
    url = "http://10.0.0.31:5000"
    [machines.files]                       # ... programs through its FTP folder (docs/files.md)
    mode = "ftp"                           # or "ftp-server" (the board is the client), "share"
    host = "10.0.0.31"
    user = "dnc"
    password = "..."
    folder = "/programs"
    receive = true                         # files the control writes come to the inbox

    [mtconnect]                            # MTConnect SHDR adapter (server/outputs/shdr.py)
    bind = "127.0.0.1:7878"                # the first machine's port; the next ones count up
    ports = { "mill-1" = 7900 }            # optional: a machine's own port
"""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from opendnc.errors import InputError
from opendnc.haas.share import ShareTarget, parse_target
from opendnc.server.config.alerts import AlertsConfig, parse_alerts
from opendnc.server.config.clients import ClientLimits, parse_clients
from opendnc.server.config.downtime import DowntimeConfig, parse_downtime
from opendnc.server.config.ftp_server import (
    FtpServerConfig,
    parse_ftp_server,
    with_account_folders,
)
from opendnc.server.config.goals import GoalsConfig, parse_goals
from opendnc.server.core.configkeys import NAME as _NAME
from opendnc.server.core.configkeys import ConfigError, get_key, known_keys, port_range, table_at
from opendnc.server.core.requests import RequestRule, RequestSettings
from opendnc.server.core.shifts import Calendar, CalendarError, parse_calendar
from opendnc.server.kinds.base import MachineConfig, SerialProfile
from opendnc.server.kinds.registry import parse_machine, shares_of

# The parser's helpers under the names this module has always used.
_get = get_key
_known = known_keys
_table = table_at
_port_range = port_range

__all__ = [
    "ConfigError",
    "LibraryConfig",
    "MachineConfig",
    "MqttConfig",
    "MtconnectConfig",
    "NetShareConfig",
    "SerialProfile",
    "ServerConfig",
    "ShopConfig",
    "SparkplugConfig",
    "load_config",
    "parse_config",
]


@dataclass(frozen=True)
class LibraryConfig:
    """The folders the server keeps programs in."""

    path: Path
    inbox: Path
    archive: Path
    backups: Path | None = None  # LSV2 backups, one folder per machine (default: ./backups)
    poll: bool = False  # poll the library folder instead of change notifications (shares)
    # program check errors refuse a release and a send (unless overridden); False ("warn"):
    # they are shown only (docs/server.md#program-checks)
    check_blocks: bool = True


@dataclass(frozen=True)
class NetShareConfig:
    """The hybrid net share: a NAS folder fanned out to machines' shares
    (server/netshare/share.py)."""

    path: Path | ShareTarget  # the NAS folder: mounted, or reached over SMB (with its login)
    machines: tuple[str, ...]  # subscribed machines (each has a share)
    archive: Path  # where archived programs go, in one folder per day
    archive_at: tuple[int, int] | None = (18, 0)  # daily, server's local time
    archive_every: float | None = None  # or every so many seconds
    collect: bool = True  # programs made on the machines go to the inbox
    interval: float = 5.0  # seconds between scans


@dataclass(frozen=True)
class MqttConfig:
    """Where the MQTT publisher sends the machines' state (server/outputs/mqtt.py)."""

    host: str
    port: int = 1883
    tls: bool = False  # mqtts://
    ca_file: Path | None = None  # a private CA for the broker's certificate (TLS)
    prefix: str = "opendnc"
    username: str = ""
    password: str = ""
    queue: int = 10000  # messages kept while the broker is away; the oldest go first


@dataclass(frozen=True)
class SparkplugConfig:
    """The Sparkplug B edge node: its broker and its ids (server/outputs/sparkplug.py)."""

    broker: MqttConfig  # host, port, TLS and login (its prefix and queue are not used)
    group: str
    node: str = ""  # "": the server's name (app.py fills it in)
    primary_host: str = ""  # "": publish whenever connected


@dataclass(frozen=True)
class MtconnectConfig:
    """The MTConnect SHDR adapter: one TCP port per machine (server/outputs/shdr.py)."""

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
    lease_seconds: float = 10.0  # a cluster's machine leases: a dead server's go after this
    # PostgreSQL: share the database with other servers (leases, fencing); False: the only
    # server, which drives its machines through a database outage (docs/server.md)
    cluster: bool = True
    # seconds a machine taken over mid-feed stays silent waiting for the fenced server's
    # exact position (docs/server.md#a-fenced-drip-feed)
    resume_wait: float = 60.0


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
    sparkplug: SparkplugConfig | None = None
    mtconnect: MtconnectConfig | None = None
    calendar: Calendar = field(default_factory=Calendar)  # time zone and shifts
    clients: ClientLimits = field(default_factory=ClientLimits)  # [clients]: bounded clients
    alerts: AlertsConfig | None = None  # [alerts] (server/config/alerts.py)
    # [downtime]: the reasons an operator picks for a stop (server/utilization/downtime.py)
    downtime: DowntimeConfig = field(default_factory=DowntimeConfig)
    # [ftp_server]: for boards that are FTP clients (server/config/ftp_server.py)
    ftp_server: FtpServerConfig | None = None
    # [goals]: parts per shift or per day of each machine (server/config/goals.py)
    goals: GoalsConfig = field(default_factory=GoalsConfig)

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
    try:
        return parse_config(text, base=path.parent.resolve(), source=path)
    except ConfigError as exc:
        if exc.source is not None:
            raise
        raise ConfigError(exc.key, exc.problem, source=path) from None


def parse_config(text: str, *, base: Path, source: Path | None = None) -> ShopConfig:
    """Validate the TOML ``text``; relative paths are taken from ``base``."""
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError("", f"not valid TOML: {exc}") from exc
    _known(
        raw,
        "",
        {
            "server", "library", "machines", "requests", "netshare", "mqtt", "sparkplug",
            "mtconnect", "shifts", "clients", "alerts", "downtime", "ftp_server", "goals",
        },
    )  # fmt: skip
    server = _server(_table(raw, "server"), base)
    library = _library(_table(raw, "library"), base)
    machines_raw = raw.get("machines", [])
    if not isinstance(machines_raw, list):
        raise ConfigError("machines", "expected an array of tables ([[machines]])")
    machines = tuple(parse_machine(item, f"machines[{i}]") for i, item in enumerate(machines_raw))
    ftp_server = None
    if "ftp_server" in raw:
        ftp_server = parse_ftp_server(_table(raw, "ftp_server"), base)
    machines = with_account_folders(machines, ftp_server)  # docs/files.md
    seen: set[str] = set()
    for i, machine in enumerate(machines):
        if machine.name.lower() in seen:
            raise ConfigError(f"machines[{i}].name", f"{machine.name!r} is used twice")
        seen.add(machine.name.lower())
    requests = _requests(_table(raw, "requests"))
    clients = parse_clients(_table(raw, "clients"))  # server/http/clients.py
    netshare = None
    if "netshare" in raw:
        netshare = _netshare(_table(raw, "netshare"), base, library, machines)
    mqtt = _mqtt(_table(raw, "mqtt"), base) if "mqtt" in raw else None
    sparkplug = None
    if "sparkplug" in raw:
        sparkplug = _sparkplug(_table(raw, "sparkplug"), base)
    mtconnect = _mtconnect(_table(raw, "mtconnect"), machines) if "mtconnect" in raw else None
    try:
        calendar = parse_calendar(raw)  # [server] timezone and [[shifts]] (server/core/shifts.py)
    except CalendarError as exc:
        key, _, problem = str(exc).partition(": ")  # the calendar's messages start with the key
        raise ConfigError(key, problem) from None
    names = {m.name for m in machines}
    alerts = parse_alerts(_table(raw, "alerts"), base, names) if "alerts" in raw else None
    downtime = parse_downtime(_table(raw, "downtime"))
    goals = parse_goals(_table(raw, "goals"), names, calendar)
    return ShopConfig(
        server=server,
        library=library,
        machines=machines,
        source=source,
        requests=requests,
        netshare=netshare,
        mqtt=mqtt,
        sparkplug=sparkplug,
        mtconnect=mtconnect,
        calendar=calendar,
        clients=clients,
        alerts=alerts,
        downtime=downtime,
        ftp_server=ftp_server,
        goals=goals,
    )


def _mqtt(table: dict[str, Any], base: Path) -> MqttConfig:
    keys = {"url", "prefix", "username", "password", "ca_file", "queue"}
    _known(table, "mqtt", keys)
    broker = _broker(table, "mqtt", base)
    prefix = _get(table, "mqtt", "prefix", str, "opendnc")
    levels = prefix.split("/")
    # Wildcards and '$' topics belong to subscribers and the broker; an empty level is a typo.
    if not prefix or any(not level or set(level) & {"+", "#", "\0"} for level in levels):
        raise ConfigError("mqtt.prefix", "expected topic levels like enterprise/site/area")
    if prefix.startswith("$"):
        raise ConfigError("mqtt.prefix", "topics starting with '$' are the broker's")
    queue = _get(table, "mqtt", "queue", int, 10000)
    if not 10 <= queue <= 1_000_000:
        raise ConfigError("mqtt.queue", "expected 10..1000000 messages")
    return replace(broker, prefix=prefix, queue=queue)


def _broker(table: dict[str, Any], name: str, base: Path) -> MqttConfig:
    """A broker link's keys (url, username, password, ca_file) of table ``name``."""
    url = _get(table, name, "url", str, "")
    match = re.fullmatch(r"(mqtts?)://([^:/\s]+|\[[0-9A-Fa-f:]+\])(?::(\d{1,5}))?/?", url)
    if match is None:
        raise ConfigError(f"{name}.url", f"expected mqtt://HOST[:PORT] or mqtts://..., got {url!r}")
    tls = match.group(1) == "mqtts"
    port = int(match.group(3)) if match.group(3) else (8883 if tls else 1883)
    _port_range(port, f"{name}.url")
    username = _get(table, name, "username", str, "")
    password = _get(table, name, "password", str, "")
    if password and not username:
        raise ConfigError(f"{name}.password", "a password needs a username")
    ca_text = _get(table, name, "ca_file", str, "")
    if ca_text and not tls:
        raise ConfigError(f"{name}.ca_file", "a CA file is for TLS (mqtts://)")
    return MqttConfig(
        host=match.group(2).strip("[]"),
        port=port,
        tls=tls,
        ca_file=(base / ca_text).resolve() if ca_text else None,
        username=username,
        password=password,
    )


# Sparkplug B ids are single topic levels: no '/', and none of MQTT's wildcards.
_SPARKPLUG_ID = re.compile(r"^[^/+#\s\x00]{1,64}$")


def _sparkplug(table: dict[str, Any], base: Path) -> SparkplugConfig:
    _known(
        table,
        "sparkplug",
        {"url", "group", "node", "primary_host", "username", "password", "ca_file"},
    )
    broker = _broker(table, "sparkplug", base)
    ids = {}
    for key in ("group", "node", "primary_host"):
        value = _get(table, "sparkplug", key, str, "")
        # The node may be left out: it is then the server's name, which `opendnc serve
        # --name` sets per cluster member after the file is read (app.py fills it in).
        if (value or key == "group") and not _SPARKPLUG_ID.match(value):
            raise ConfigError(
                f"sparkplug.{key}", f"expected one topic level (no '/', '+', '#'), got {value!r}"
            )
        ids[key] = value
    return SparkplugConfig(broker, ids["group"], ids["node"], ids["primary_host"])


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
    with_share = shares_of(machines)
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


def _server(table: dict[str, Any], base: Path) -> ServerConfig:
    _known(
        table,
        "server",
        {
            "bind",
            "database",
            "name",
            "timeline_retention_days",
            "timezone",
            "lease_seconds",
            "cluster",
            "resume_wait",
        },
    )
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
    lease = _get(table, "server", "lease_seconds", float, 10.0)
    if not 0.5 <= lease <= 300:
        raise ConfigError("server.lease_seconds", "expected seconds between 0.5 and 300")
    cluster = _get(table, "server", "cluster", bool, True)
    resume_wait = _get(table, "server", "resume_wait", float, 60.0)
    if not 0 <= resume_wait <= 3600:
        raise ConfigError("server.resume_wait", "expected seconds between 0 and 3600")
    return ServerConfig(
        resume_wait=float(resume_wait),
        cluster=bool(cluster),
        bind_host=host.strip("[]"),
        bind_port=int(port_text),
        database=database,
        name=name,
        timeline_days=float(days),
        lease_seconds=float(lease),
    )


def _library(table: dict[str, Any], base: Path) -> LibraryConfig:
    _known(table, "library", {"path", "inbox", "archive", "backups", "watch", "check"})
    watch = _get(table, "library", "watch", str, "notify")
    if watch not in ("notify", "poll"):
        raise ConfigError("library.watch", "expected notify or poll (poll for network shares)")
    check = _get(table, "library", "check", str, "block")
    if check not in ("block", "warn"):
        raise ConfigError("library.check", "expected block or warn (program check errors)")

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
        check_blocks=check == "block",
    )
