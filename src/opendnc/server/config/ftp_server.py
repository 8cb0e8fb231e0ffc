"""The ``[ftp_server]`` table: the FTP server this server runs for the machines whose board is
an FTP client (``[machines.files] mode = "ftp-server"``, docs/files.md#ftp-server-for-a-board),
and where each such machine's account folder is.

Example::

    [ftp_server]
    bind = "0.0.0.0:2121"            # where the boards connect
    root = "ftp"                     # one folder per account below it (relative: to the file)
    passive_ports = "60000-60049"    # data connections (a firewall opens this range); "" any
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from opendnc.server.core.configkeys import ConfigError, get_key, known_keys, port_range
from opendnc.server.kinds.base import MachineConfig
from opendnc.server.kinds.filedrop_config import served_folder

__all__ = ["FtpServerConfig", "parse_ftp_server", "with_account_folders"]


@dataclass(frozen=True)
class FtpServerConfig:
    """Where the FTP server listens and keeps its accounts' folders."""

    host: str = "0.0.0.0"
    port: int = 2121
    root: Path = Path("ftp")
    passive_ports: range | None = None


def parse_ftp_server(table: dict[str, Any], base: Path) -> FtpServerConfig:
    """The ``[ftp_server]`` table; relative ``root`` from ``base``."""
    known_keys(table, "ftp_server", {"bind", "root", "passive_ports"})
    bind = get_key(table, "ftp_server", "bind", str, "0.0.0.0:2121")
    host, sep, port_text = bind.rpartition(":")
    if not sep or not host or not port_text.isdigit():
        raise ConfigError("ftp_server.bind", f"expected HOST:PORT, got {bind!r}")
    port = int(port_text)
    if port:  # 0: any free port (a test's server)
        port_range(port, "ftp_server.bind")
    root = get_key(table, "ftp_server", "root", str, "ftp")
    return FtpServerConfig(
        host=host.strip("[]"),
        port=port,
        root=(base / root).resolve(),
        passive_ports=_ports(get_key(table, "ftp_server", "passive_ports", str, "")),
    )


def _ports(text: str) -> range | None:
    if not text:
        return None
    first, sep, last = text.partition("-")
    if not (sep and first.isdigit() and last.isdigit()) or not (
        1024 <= int(first) <= int(last) <= 65535
    ):
        raise ConfigError("ftp_server.passive_ports", 'expected "FIRST-LAST" above 1023')
    return range(int(first), int(last) + 1)


def with_account_folders(
    machines: tuple[MachineConfig, ...], ftp: FtpServerConfig | None
) -> tuple[MachineConfig, ...]:
    """``machines`` with each ``ftp-server`` machine's folder set below the server's root;
    :class:`ConfigError` where such a machine has no server or shares an account."""
    users: dict[str, str] = {}
    done = []
    for i, machine in enumerate(machines):
        files = machine.files
        if files is None or files.mode != "ftp-server":
            done.append(machine)
            continue
        if ftp is None:
            raise ConfigError(f"machines[{i}].files.mode", "ftp-server needs an [ftp_server] table")
        other = users.setdefault(files.user.lower(), machine.name)
        if other != machine.name:
            raise ConfigError(f"machines[{i}].files.user", f"{files.user!r} is {other}'s account")
        folder = served_folder(ftp.root, files)
        done.append(replace(machine, files=replace(files, folder=folder)))
    return tuple(done)
