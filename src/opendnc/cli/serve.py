"""``opendnc serve`` and ``opendnc keys``: the DNC server and its API keys.

The server's modules are imported inside the commands, so the rest of the command line starts
without FastAPI, SQLAlchemy and uvicorn (and works where the ``server`` extra is missing).
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import importlib.util
import os
import signal
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from opendnc.cli.common import cli_errors, console, print_json, start_up
from opendnc.errors import InputError

if TYPE_CHECKING:
    from types import FrameType

    from sqlalchemy.orm import Session

    from opendnc.server.app import Server
    from opendnc.server.config.shop import ShopConfig

keys_app = typer.Typer(help="API keys of the DNC server.", no_args_is_help=True)
users_app = typer.Typer(help="People who log in to the DNC server.", no_args_is_help=True)
requests_app = typer.Typer(
    help="Remote-request rules of a server configuration.", no_args_is_help=True
)

ConfigOption = typer.Option(..., "--config", "-c", help="The server's TOML configuration.")
DbOption = typer.Option(None, "--db", help="Database URL (overrides the configuration).")
STOP_TIMEOUT = 10.0  # seconds from SIGTERM or SIGINT to the end of the process


def require_server_extra() -> None:
    """Raise :class:`InputError` naming the extra when the server's libraries are missing.

    Looked up, not imported: the key and user commands need the store, not the web framework
    (importing FastAPI to check for it cost them a sixth of their run)."""
    for name in ("fastapi", "sqlalchemy"):
        if importlib.util.find_spec(name) is None:
            raise InputError(
                f"the server needs the 'server' extra ({name} is missing): "
                "pip install 'opendnc[server]'"
            )


def serve(
    config: Path = ConfigOption,
    db: str | None = DbOption,
    bind: str | None = typer.Option(None, "--bind", help="HOST:PORT (default from the config)."),
    name: str | None = typer.Option(
        None, "--name", help="This server's name (default [server] name; one per cluster member)."
    ),
    stop_timeout: float = typer.Option(
        STOP_TIMEOUT,
        "--stop-timeout",
        min=1.0,
        max=600.0,
        help="Seconds SIGTERM or SIGINT may take to stop the server.",
    ),
) -> None:
    """Run the DNC server: the machines of CONFIG, the API and server-sent events."""
    with cli_errors():
        require_server_extra()
        with start_up():
            from opendnc.server.app import build
            from opendnc.server.config.shop import load_config

        shop = load_config(config)
        if name is not None:
            shop = _named(shop, name)
        host, port = shop.server.bind_host, shop.server.bind_port
        if bind is not None:
            host, port = bind_option(bind)
        # The address first: a port in use must stop the server before it migrates the
        # database or connects a single machine, with one line that says what to do.
        listener = listen_socket(host, port)
        plan = StopPlan(stop_timeout)
        plan.listen()
        from opendnc.server.cluster.single_server import SingleServerLock

        guard = SingleServerLock(db or shop.server.database)
        try:
            guard.acquire()  # a second server on one SQLite file: one line, before migrating
            with start_up():
                server = build(shop, database=db, stop_deadline=plan.components)
            try:
                asyncio.run(_serve(server, listener, host, plan))
            except KeyboardInterrupt:
                # uvicorn raises the SIGINT it handled again once it has stopped: the stop
                # is done, and ends below like a SIGTERM's.
                if not plan.signal:
                    raise
            finally:
                server.engine.dispose()
        finally:
            guard.release()
            listener.close()
        plan.exit_after_signal()


def _named(shop: ShopConfig, name: str) -> ShopConfig:
    """``shop`` with the server called ``name`` (several servers share one file)."""
    from dataclasses import replace

    from opendnc.server.core.configkeys import NAME

    if not NAME.fullmatch(name):
        raise InputError(f"--name {name!r}: use letters, digits, '-', '_' or '.' (at most 64)")
    return replace(shop, server=replace(shop.server, name=name))


def parse_bind(bind: str) -> tuple[str, int]:
    """``HOST:PORT`` (``[v6]:PORT`` too) as a host and a port; :class:`InputError` if not."""
    host, sep, port_text = bind.rpartition(":")
    if not sep or not host or not port_text.isdigit():
        raise InputError(f"--bind {bind!r}: expected HOST:PORT")
    if int(port_text) > 65535:
        raise InputError(f"--bind {bind!r}: a port is 0 to 65535")
    return host.strip("[]"), int(port_text)


def bind_option(bind: str) -> tuple[str, int]:
    """:func:`parse_bind` for a command's ``--bind``: a value that is no address is a usage
    error (one line, exit status 2, as the README says of usage errors), not a failure."""
    try:
        return parse_bind(bind)
    except InputError as exc:
        from opendnc.cli.common import err_console

        err_console.print(f"error: {exc}", highlight=False, soft_wrap=True, markup=False)
        raise typer.Exit(2) from None


def listen_socket(host: str, port: int) -> socket.socket:
    """A listening TCP socket on ``host``:``port`` (port 0: one the system picks).

    The server binds before it starts anything, so the error for a port in use is ours (one
    line naming the address and the way out), not the web server's after the machines were
    already connected. Reusing an address is allowed as asyncio does it on POSIX, so a
    restart does not wait for the old connections' TIME_WAIT; Windows' SO_REUSEADDR would
    let two servers share a port, so it stays off there.
    """
    where = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
    try:
        family, kind, proto, _name, address = socket.getaddrinfo(
            host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
        )[0]
    except (OSError, UnicodeError) as exc:
        raise InputError(f"cannot listen on {where}: {_reason(exc)}") from None
    sock = socket.socket(family, kind, proto)
    try:
        if os.name == "posix":
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(address)
        sock.listen(2048)
    except OSError as exc:
        sock.close()
        hint = ""
        if exc.errno == errno.EADDRINUSE:
            hint = "; another program has this port: choose another with --bind HOST:PORT"
        elif exc.errno in (errno.EACCES, errno.EPERM):
            hint = "; ports below 1024 need privileges: choose another with --bind HOST:PORT"
        raise InputError(f"cannot listen on {where}: {_reason(exc)}{hint}") from None
    return sock


def _reason(exc: BaseException) -> str:
    # strerror without "[Errno 98]"; lower case, as it ends our sentence
    text = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
    return text[0].lower() + text[1:]


class StopPlan:
    """How the seconds of a stop are shared (docs/server.md#stopping): open HTTP
    connections (event streams) get a short grace, the components the rest but a margin, and
    a watchdog armed by the first signal ends the process at the deadline whatever still runs
    (a worker thread blocked in a driver call cannot be cancelled, and would keep the
    interpreter from exiting)."""

    def __init__(self, deadline: float) -> None:
        self.deadline = deadline
        self.connections = min(1.0, deadline * 0.1)
        self.components = max(0.5, deadline - self.connections - 1.0)
        self.signal = 0
        self._lock = threading.Lock()

    def listen(self) -> None:
        """Arm the watchdog when a signal arrives, not when the main thread gets round to
        its handler (on a busy machine that can be seconds later): the signal's byte on
        Python's wakeup descriptor, written the moment the signal is caught, wakes a thread
        of ours. From the main thread only; the web server's handler arms it as well."""
        reader, writer = os.pipe()
        os.set_blocking(writer, False)
        try:
            signal.set_wakeup_fd(writer, warn_on_full_buffer=False)
        except ValueError:  # not the main thread (tests calling serve() from a thread)
            os.close(reader)
            os.close(writer)
            return
        threading.Thread(target=self._hear, args=(reader,), name="stop-ear", daemon=True).start()

    def _hear(self, reader: int) -> None:
        while not self.signal:
            try:
                data = os.read(reader, 64)
            except OSError:
                return
            for number in data:
                if number in (signal.SIGTERM, signal.SIGINT):
                    self.signalled(number)

    def signalled(self, sig: int) -> None:
        """The first SIGTERM or SIGINT: arm the watchdog."""
        with self._lock:
            if self.signal:
                return
            self.signal = sig
        threading.Thread(target=self._watchdog, name="stop-watchdog", daemon=True).start()

    def _watchdog(self) -> None:
        time.sleep(self.deadline)
        _last_words(f"error: the server did not stop within {self.deadline:g} s; ending it")
        os._exit(128 + self.signal)

    def exit_after_signal(self) -> None:
        """After a signalled stop (everything stopped, the database let go), end the process
        at once: the interpreter's own shutdown would wait for worker threads still blocked
        in a driver or a port read, and then tears down a shop's worth of objects (seconds
        on a busy machine, out of the watchdog's reach). Exit status 128 + the signal, as a
        shell reports a process the signal ended."""
        if not self.signal:
            return
        _last_words("")
        os._exit(128 + self.signal)


def _last_words(line: str) -> None:
    import logging
    import sys

    if line:
        sys.stderr.write(line + "\n")
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()


async def _serve(server: Server, listener: socket.socket, host: str, plan: StopPlan) -> None:
    """Run uvicorn on ``listener``; say where once it listens (scripts wait for that line)."""
    import uvicorn

    class Web(uvicorn.Server):
        def handle_exit(self, sig: int, frame: FrameType | None) -> None:
            plan.signalled(sig)
            super().handle_exit(sig, frame)

        @contextlib.contextmanager
        def capture_signals(self) -> Iterator[None]:
            # uvicorn raises a signal it handled again once it has stopped: SIGTERM's default
            # action then ended the process there ("Terminated"), before the database was let
            # go (SQLite's -wal and -shm files left behind). The stop is ours to end:
            # StopPlan.exit_after_signal, after the engine is disposed of.
            with super().capture_signals():
                try:
                    yield
                finally:
                    self._captured_signals.clear()

    mtconnect = server.outputs.mtconnect
    if mtconnect is not None:
        # Its ports open before the app starts, so a taken one is a plain error naming it.
        await mtconnect.start()
    port = listener.getsockname()[1]  # the real one for :0
    if server.cluster is not None:
        # where the others' `cluster status` says this server answers
        where = f"[{host}]" if ":" in host else host
        server.cluster.leases.url = f"http://{where}:{port}/"
    from opendnc.server.http.limits import Limits, raise_file_limit, uvicorn_protocol

    raise_file_limit()  # connections are limited by the server (limits.py), not by running out
    settings = uvicorn.Config(
        server.app,
        log_level="warning",
        lifespan="on",
        # Event streams never end by themselves: at a stop they get this long, then go.
        timeout_graceful_shutdown=max(1, round(plan.connections)),
        # The guarded protocol times out incomplete headers and refuses connections past the
        # limit (docs/server.md#limits).
        http=uvicorn_protocol(Limits()),
    )
    web = Web(settings)
    serving = asyncio.create_task(web.serve(sockets=[listener]))
    while not web.started:
        if serving.done():
            # uvicorn ends its start-up with SystemExit (a failed lifespan has logged why)
            with contextlib.suppress(SystemExit):
                serving.result()
            raise InputError(f"the server on {host}:{port} stopped at once (see above)")
        await asyncio.sleep(0.05)
    database = server.engine.url.render_as_string(hide_password=True)
    where = f"[{host}]" if ":" in host else host
    console.print(
        f"opendnc server on http://{where}:{port}/ ({len(server.config.machines)} machines, "
        f"database {database})",
        highlight=False,
        soft_wrap=True,
    )
    await serving


@keys_app.command("create")
def keys_create(
    role: str = typer.Option(..., "--role", help="viewer, operator, programmer, approver, admin"),
    config: Path = ConfigOption,
    user: str | None = typer.Option(None, "--user", help="Owner (created if missing)."),
    label: str = typer.Option("", "--label", help="What the key is for."),
    db: str | None = DbOption,
    json_out: bool = typer.Option(False, "--json", help="Print a JSON object."),
) -> None:
    """Create an API key and print it (it is shown only this once)."""
    with cli_errors():
        require_server_extra()
        from opendnc.server.access import auth
        from opendnc.server.config.shop import load_config
        from opendnc.server.store.db import make_engine, make_sessions, migrate
        from opendnc.server.store.models import Role

        shop = load_config(config)
        parsed = Role.parse(role)
        engine = make_engine(db or shop.server.database)
        try:
            migrate(engine)
            with make_sessions(engine).begin() as session:
                owner = user or parsed.name.lower()
                row, key = auth.create_key(
                    session, owner, parsed, label=label, actor="cli", create_user_role=parsed
                )
                key_id = row.id
        finally:
            engine.dispose()
        if json_out:
            print_json({"id": key_id, "key": key, "user": owner, "role": parsed.name.lower()})
        else:
            typer.echo(key)


def _read_password(stdin: bool) -> str:
    import getpass
    import sys

    if stdin:
        return sys.stdin.readline().rstrip("\r\n")
    first = getpass.getpass("password: ")
    if getpass.getpass("again: ") != first:
        raise InputError("the two passwords differ")
    return first


@contextlib.contextmanager
def _session(config: Path, db: str | None) -> Iterator[Session]:
    from opendnc.server.config.shop import load_config
    from opendnc.server.store.db import make_engine, make_sessions, migrate

    shop = load_config(config)
    engine = make_engine(db or shop.server.database)
    try:
        migrate(engine)
        with make_sessions(engine).begin() as session:
            yield session
    finally:
        engine.dispose()


@users_app.command("create")
def users_create(
    name: str = typer.Argument(..., help="The login name."),
    role: str = typer.Option(..., "--role", help="viewer, operator, programmer, approver, admin"),
    config: Path = ConfigOption,
    db: str | None = DbOption,
    password_stdin: bool = typer.Option(
        False, "--password-stdin", help="Read the password from standard input (scripts)."
    ),
) -> None:
    """Create a user who logs in to the dashboard (asks for the password twice)."""
    with cli_errors():
        require_server_extra()
        from opendnc.server.access import auth
        from opendnc.server.store.models import Role

        parsed = Role.parse(role)
        password = _read_password(password_stdin)
        with _session(config, db) as session:
            auth.create_user(session, name, parsed, password=password, actor="cli")
        typer.echo(f"user {name} created ({parsed.name.lower()})")


@users_app.command("password")
def users_password(
    name: str = typer.Argument(..., help="The login name."),
    config: Path = ConfigOption,
    db: str | None = DbOption,
    password_stdin: bool = typer.Option(
        False, "--password-stdin", help="Read the password from standard input (scripts)."
    ),
) -> None:
    """Set a user's password."""
    with cli_errors():
        require_server_extra()
        from opendnc.server.access import auth

        password = _read_password(password_stdin)
        with _session(config, db) as session:
            auth.set_password(session, name, password, actor="cli")
        typer.echo(f"password of {name} set")


@requests_app.command("test")
def requests_test(
    program: str = typer.Argument(
        ...,
        help="The request as the control sends it, e.g. '%\\nO9999 (REQ O1234)\\n%' "
        "(\\n is a new line); '-' reads it from stdin.",
    ),
    config: Path = ConfigOption,
    json_out: bool = typer.Option(False, "--json", help="Print a JSON object."),
) -> None:
    """Show which of the configured rules takes a request and the programs it asks for,
    and which of those names the server would refuse. Exit status 1 when no rule matches."""
    import sys

    with cli_errors():
        from opendnc.server.config.shop import load_config
        from opendnc.server.core.requests import match_request
        from opendnc.server.library import versions as library

        shop = load_config(config)
        text = sys.stdin.read() if program == "-" else program.replace("\\n", "\n")
        found = match_request(text.encode("latin-1", "replace"), shop.requests)
        refused: list[str] = []
        if found is not None:
            for name in found.names:
                try:
                    library.check_program_name(name)
                except InputError:
                    refused.append(name)
        if json_out:
            print_json(
                None
                if found is None
                else {
                    "rule": found.index,
                    "pattern": found.pattern,
                    "names": found.names,
                    "refused": refused,
                }
            )
        elif found is None:
            typer.echo("no rule matches: an ordinary program (it goes to the inbox)")
        else:
            typer.echo(f"rule {found.index}: {found.pattern}")
            for name in found.names:
                typer.echo(
                    f"  {name}" + ("  (refused: not a program name)" if name in refused else "")
                )
        if found is None:
            raise typer.Exit(1)
