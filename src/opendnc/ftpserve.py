"""A small FTP server in a thread of its own (pyftpdlib): accounts, each with its own folder.

The server's ``ftp-server`` machines (a board that is an FTP client, such as Fanuc's Data
Server, fetches from and stores into its account's folder) and ``opendnc sim ftp`` (a virtual
control's FTP folder) both run one. pyftpdlib's loop is not thread-safe, so each server gets an
I/O loop of its own (never the library's shared one) and the thread that runs it is the only
one that touches it: :meth:`FtpFolders.close` asks it to stop and waits. pyftpdlib logs every
command at INFO; its logger is kept at WARNING.
"""

from __future__ import annotations

import logging
import threading
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from opendnc.errors import InputError, TransportError

__all__ = ["Account", "FtpFolders", "ftp_handler"]

POLL = 0.2  # seconds one turn of the loop waits before it looks whether to stop

_log = logging.getLogger("pyftpdlib")
_log.setLevel(logging.WARNING)  # per-command INFO lines are noise in a server's log
_log.addHandler(logging.NullHandler())  # else pyftpdlib installs its own stderr handler


@dataclass(frozen=True)
class Account:
    """One login and the folder it sees as its root (read, write, rename and delete there)."""

    user: str
    password: str
    folder: Path


def _modules() -> tuple[Any, Any, Any, Any]:
    try:
        with warnings.catch_warnings():
            # on Python 3.11 pyftpdlib stands on the standard library's asyncore and asynchat,
            # which warn that they are deprecated (3.12 has them no more: pyftpdlib then
            # carries its own copies)
            warnings.simplefilter("ignore", DeprecationWarning)
            from pyftpdlib.authorizers import DummyAuthorizer
            from pyftpdlib.handlers import FTPHandler
            from pyftpdlib.ioloop import IOLoop
            from pyftpdlib.servers import FTPServer
    except ImportError as exc:  # part of the server extra
        raise InputError("an FTP server needs pyftpdlib: pip install 'opendnc[server]'") from exc
    return DummyAuthorizer, FTPHandler, IOLoop, FTPServer


def ftp_handler() -> Any:
    """pyftpdlib's command handler class, to derive a control with a quirk from (tests)."""
    return _modules()[1]


class FtpFolders:
    """An FTP server for ``accounts`` on ``host:port`` (0: any free port), started by
    :meth:`start`; ``passive_ports`` the range data connections use (None: any).
    ``handler`` replaces pyftpdlib's command handler (a test's control with a quirk)."""

    def __init__(
        self,
        accounts: list[Account],
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        passive_ports: range | None = None,
        banner: str = "opendnc FTP ready.",
        handler: Any = None,
    ) -> None:
        self.accounts = accounts
        self.host = host
        self.port = port
        self.passive_ports = passive_ports
        self.banner = banner
        self.handler = handler
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> FtpFolders:
        """Listen, and serve in a thread; the bound port is in :attr:`port`."""
        authorizer_type, handler_type, ioloop_type, server_type = _modules()
        authorizer = authorizer_type()
        for account in self.accounts:
            account.folder.mkdir(parents=True, exist_ok=True)
            # e l r: enter, list, read; a d f m w: append, delete, rename, mkdir, write;
            # M T: change mode and time (a board setting a file's time after its upload)
            authorizer.add_user(
                account.user, account.password, str(account.folder), perm="elradfmwMT"
            )
        base = self.handler or handler_type
        handler = type(
            "OpendncFtpHandler",
            (base,),
            {
                "authorizer": authorizer,
                "passive_ports": list(self.passive_ports) if self.passive_ports else None,
                "banner": self.banner,
                "use_sendfile": False,  # the same bytes on every system, and in tests
            },
        )
        ioloop = ioloop_type()
        try:
            server = server_type((self.host, self.port), handler, ioloop=ioloop)
        except OSError as exc:
            ioloop.close()
            raise TransportError(
                f"FTP server on {self.host}:{self.port}: {exc.strerror or exc}"
            ) from exc
        self.port = server.address[1]
        self._stop.clear()
        self._thread = threading.Thread(
            target=self._serve, args=(server, ioloop), name=f"ftp:{self.port}", daemon=True
        )
        self._thread.start()
        return self

    def _serve(self, server: Any, ioloop: Any) -> None:
        try:
            while not self._stop.is_set():
                ioloop.loop(POLL, blocking=False)
        finally:
            server.close_all()

    def close(self) -> None:
        """Stop serving, drop every session, and wait for the thread."""
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.join(timeout=5)

    def __enter__(self) -> FtpFolders:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
