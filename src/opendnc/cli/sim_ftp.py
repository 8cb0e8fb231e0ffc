"""`opendnc sim ftp`: a virtual control's FTP folder."""

from __future__ import annotations

import signal
import threading
from pathlib import Path

import typer

from opendnc.cli.common import READY_FILE_HELP, cli_errors, console, ready_file


def ftp(
    folder: Path = typer.Argument(..., help="The control's program folder (created if absent)."),
    port: int = typer.Option(2121, "--port", help="TCP port (0 = any free port)."),
    host: str = typer.Option("127.0.0.1", "--host", help="Address to listen on."),
    user: str = typer.Option("dnc", "--user", help="The login."),
    password: str = typer.Option("dnc", "--password", help="Its password."),
    ready: Path | None = typer.Option(None, "--ready-file", help=READY_FILE_HELP),
) -> None:
    """Serve a folder over FTP as a control does (passive mode, one login)."""
    from opendnc.sim.ftp import VirtualFtpFolder

    with cli_errors(), ready_file(ready) as mark_ready:
        stop = threading.Event()
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: stop.set())
        with VirtualFtpFolder(folder, user=user, password=password, host=host, port=port) as srv:
            console.print(
                f"virtual control FTP folder {folder} on ftp://{user}@{host}:{srv.port}/",
                highlight=False,
                soft_wrap=True,
            )
            mark_ready()
            while not stop.wait(1.0):
                pass
        console.print("stopped")
