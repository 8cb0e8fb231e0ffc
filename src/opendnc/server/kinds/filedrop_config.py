"""The ``files`` capability's configuration: the ``[machines.files]`` table any machine kind may
carry, for controls that take programs as files in a folder (docs/files.md).

``mode`` says where the folder is:

- ``ftp``: an FTP folder on the control (the server is the FTP client; passive mode);
- ``ftp-server``: a folder this server holds and serves over FTP, for controls whose board is
  the FTP *client* (Fanuc's Data Server); the account is the machine's, the folder
  ``<ftp_server.root>/<user>`` (set by the shop's parser, which knows the root);
- ``share``: a local (mounted) folder or an SMB share, as a Haas NGC's net share.

A leaf: it imports only the key readers, so :mod:`opendnc.server.kinds.base` can name the
table's type on every machine.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from opendnc.server.core.configkeys import ConfigError, get_key, known_keys, port_range

__all__ = ["MODES", "FilesConfig", "parse_files", "served_folder"]

MODES = ("ftp", "ftp-server", "share")

_KEYS = {
    "mode", "host", "port", "user", "password", "folder", "passive", "timeout", "path",
    "receive", "receive_folder", "receive_pattern", "receive_every", "after_receive",
}  # fmt: skip
# An FTP folder or a relative folder below it: plain names joined by "/", no "..".
_FOLDER = re.compile(r"/?([^/\s\\]+(/[^/\s\\]+)*)?/?")
_USER = re.compile(r"[A-Za-z0-9_.-]{1,64}")


@dataclass(frozen=True)
class FilesConfig:
    """Where a machine's programs go as files, and which of its files come to the inbox."""

    mode: str  # one of MODES
    host: str = ""  # ftp: the control's address
    port: int = 21  # ftp: the control's FTP port
    user: str = ""  # ftp: the login on the control; ftp-server: the account the board uses
    password: str = ""
    folder: str = ""  # ftp: the folder on the control ("" its login folder); ftp-server: set
    passive: bool = True  # ftp: passive mode (the control opens no connection to us)
    timeout: float = 10.0  # ftp: seconds for the connection and each reply
    path: str = ""  # share: a local folder or smb://[USER:PASSWORD@]HOST[:PORT]/SHARE/PATH
    receive: bool = False  # files the control writes come to the inbox (auto-receive)
    receive_folder: str = ""  # below the folder ("" the folder itself)
    receive_pattern: str = "*"
    receive_every: int = 5  # status polls between two listings
    after_receive: str = "keep"  # or "delete" once received

    def where(self) -> str:
        """The folder for people (no password)."""
        if self.mode == "ftp":
            return f"ftp://{self.user + '@' if self.user else ''}{self.host}:{self.port}/" + (
                self.folder.strip("/")
            )
        if self.mode == "ftp-server":
            return f"this server's FTP account {self.user!r} ({self.folder})"
        return re.sub(r"//[^@/]*@", "//", self.path)


def parse_files(raw: object, prefix: str, machine: str) -> FilesConfig | None:
    """The ``[machines.files]`` table of machine ``machine``; None where there is none."""
    if raw is None:
        return None
    if not isinstance(raw, dict):
        raise ConfigError(prefix, "expected a table: [machines.files]")
    table: dict[str, Any] = raw
    known_keys(table, prefix, _KEYS)
    mode = get_key(table, prefix, "mode", str, "")
    if mode not in MODES:
        raise ConfigError(f"{prefix}.mode", f"expected one of {', '.join(MODES)}")
    receive = _receive(table, prefix)
    if mode == "ftp":
        return _ftp(table, prefix, receive)
    if mode == "ftp-server":
        user = get_key(table, prefix, "user", str, machine)
        if not _USER.fullmatch(user):
            raise ConfigError(f"{prefix}.user", "letters, digits, '_', '.' or '-' (at most 64)")
        password = get_key(table, prefix, "password", str, "")
        if not password:
            raise ConfigError(f"{prefix}.password", "the board's FTP account needs a password")
        return FilesConfig(mode=mode, user=user, password=password, **receive)
    path = get_key(table, prefix, "path", str, "")
    if not path:
        raise ConfigError(f"{prefix}.path", "a share needs its folder or smb:// location")
    return FilesConfig(mode=mode, path=path, **receive)


def _ftp(table: dict[str, Any], prefix: str, receive: dict[str, Any]) -> FilesConfig:
    host = get_key(table, prefix, "host", str, "")
    if not host or any(c.isspace() or c in "/@" for c in host):
        raise ConfigError(f"{prefix}.host", "expected the control's address")
    port = get_key(table, prefix, "port", int, 21)
    port_range(port, f"{prefix}.port")
    timeout = get_key(table, prefix, "timeout", float, 10.0)
    if not 0.5 <= timeout <= 300:
        raise ConfigError(f"{prefix}.timeout", "expected 0.5..300 seconds")
    return FilesConfig(
        mode="ftp",
        host=host,
        port=port,
        user=get_key(table, prefix, "user", str, "anonymous"),
        password=get_key(table, prefix, "password", str, ""),
        folder=_folder(get_key(table, prefix, "folder", str, ""), f"{prefix}.folder"),
        passive=get_key(table, prefix, "passive", bool, True),
        timeout=timeout,
        **receive,
    )


def _folder(value: str, key: str) -> str:
    if not _FOLDER.fullmatch(value) or ".." in value.split("/"):
        raise ConfigError(key, "expected a folder such as /programs, without '..'")
    return value


def _receive(table: dict[str, Any], prefix: str) -> dict[str, Any]:
    every = get_key(table, prefix, "receive_every", int, 5)
    if not 1 <= every <= 1000:
        raise ConfigError(f"{prefix}.receive_every", "expected 1..1000 status polls")
    after = get_key(table, prefix, "after_receive", str, "keep")
    if after not in ("keep", "delete"):
        raise ConfigError(f"{prefix}.after_receive", "expected keep or delete")
    folder = get_key(table, prefix, "receive_folder", str, "")
    return {
        "receive": get_key(table, prefix, "receive", bool, False),
        "receive_folder": _folder(folder, f"{prefix}.receive_folder").strip("/"),
        "receive_pattern": get_key(table, prefix, "receive_pattern", str, "*") or "*",
        "receive_every": every,
        "after_receive": after,
    }


def served_folder(root: Path, files: FilesConfig) -> str:
    """The folder of an ``ftp-server`` account below the FTP server's ``root``."""
    return str(root / files.user)
