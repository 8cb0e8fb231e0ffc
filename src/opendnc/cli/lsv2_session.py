"""Shared plumbing of the `opendnc lsv2` commands: global options, connecting, progress."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING

import typer

from opendnc.cli.common import err_console
from opendnc.errors import (
    ControlRefused,
    PeerClosed,
    RemoteProtocolError,
    SafetyLockError,
    TransportTimeout,
)

if TYPE_CHECKING:  # imported when a command connects, not for --help
    from rich.progress import Progress

    from opendnc.lsv2 import Client
    from opendnc.lsv2.serial_stream import SerialLine

__all__ = [
    "JsonOpt",
    "Settings",
    "bar",
    "connect",
    "relabel",
    "require_unsafe",
    "settings",
    "want_json",
]

JsonOpt = typer.Option(False, "--json", help="Print the result as JSON (same as lsv2 --json).")


@dataclass(frozen=True, slots=True)
class Settings:
    """Global options of the ``lsv2`` group."""

    host: str
    port: int
    timeout: float
    json: bool
    unsafe: bool
    serial: SerialLine | None = None
    """Set by ``--serial``: the control is on an RS-232 line instead of TCP."""


def settings(ctx: typer.Context) -> Settings:
    """The group's options (defaults when a command runs without the group callback)."""
    obj = ctx.find_root().obj if ctx.obj is None else ctx.obj
    if isinstance(obj, Settings):
        return obj
    return Settings("127.0.0.1", 19000, 10.0, False, False)


def want_json(ctx: typer.Context, local: bool) -> bool:
    """True if ``--json`` was given on the group or on the command."""
    return local or settings(ctx).json


@contextmanager
def connect(ctx: typer.Context) -> Iterator[Client]:
    """A connected client for the group's host and port (closed on exit)."""
    from opendnc.lsv2 import Client

    opts = settings(ctx)
    if opts.serial is not None:
        from opendnc.cli.lsv2_serial import resolve_baud

        client = Client.over_serial(
            resolve_baud(opts.serial), timeout=opts.timeout, safe_mode=not opts.unsafe
        )
    else:
        client = Client(opts.host, opts.port, timeout=opts.timeout, safe_mode=not opts.unsafe)
    try:
        client.connect()
    except (RemoteProtocolError, PeerClosed) as exc:
        # something answered, but not in LSV2 (a web server, a serial server in another mode)
        client.close()
        where = opts.serial.describe() if opts.serial is not None else f"{opts.host}:{opts.port}"
        raise RemoteProtocolError(f"{where} is not an LSV2 control ({exc})") from exc
    except TransportTimeout as exc:
        # a port that accepts but stays silent: most often another service, not a busy TNC
        client.close()
        raise TransportTimeout(
            f"{exc}: is it an LSV2 control? (a TNC listens on TCP port 19000)"
        ) from exc
    try:
        yield client
    finally:
        client.close()


def require_unsafe(ctx: typer.Context, action: str) -> None:
    """Refuse a machine-changing ``action`` before connecting unless ``--unsafe`` was given."""
    if not settings(ctx).unsafe:
        raise SafetyLockError(action)


@contextmanager
def relabel(context: str) -> Iterator[None]:
    """Re-word a control's refusal as ``<context>: <text> (<code>)`` for the one-line error."""
    try:
        yield
    except ControlRefused as exc:
        raise ControlRefused(exc.code, exc.text, context=context) from exc


def bar(quiet: bool) -> Progress:
    """One transfer progress bar on stderr (stdout stays clean for --json)."""
    from rich.progress import (
        BarColumn,
        DownloadColumn,
        Progress,
        TextColumn,
        TimeRemainingColumn,
        TransferSpeedColumn,
    )

    return Progress(
        TextColumn("{task.description}", markup=False),
        BarColumn(),
        DownloadColumn(),
        TransferSpeedColumn(),
        TimeRemainingColumn(),
        console=err_console,
        transient=True,
        # not on a terminal (logs, pipes, CI): a bar would only add stray lines to stderr
        disable=quiet or not err_console.is_terminal,
    )
