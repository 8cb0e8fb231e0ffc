"""``opendnc serve`` and ``opendnc keys``: the DNC server and its API keys.

The server's modules are imported inside the commands, so the rest of the command line starts
without FastAPI, SQLAlchemy and uvicorn (and works where the ``server`` extra is missing).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from opendnc.cli.common import cli_errors, console, print_json
from opendnc.errors import InputError

if TYPE_CHECKING:
    from sqlalchemy.orm import Session

    from opendnc.server.app import Server

keys_app = typer.Typer(help="API keys of the DNC server.", no_args_is_help=True)
users_app = typer.Typer(help="People who log in to the DNC server.", no_args_is_help=True)
requests_app = typer.Typer(
    help="Remote-request rules of a server configuration.", no_args_is_help=True
)

ConfigOption = typer.Option(..., "--config", "-c", help="The server's TOML configuration.")
DbOption = typer.Option(None, "--db", help="Database URL (overrides the configuration).")


def require_server_extra() -> None:
    """Raise :class:`InputError` naming the extra when the server's libraries are missing."""
    try:
        import fastapi  # noqa: F401
        import sqlalchemy  # noqa: F401
    except ImportError as exc:
        raise InputError(
            f"the server needs the 'server' extra ({exc.name} is missing): "
            "pip install 'opendnc[server]'"
        ) from None


def serve(
    config: Path = ConfigOption,
    db: str | None = DbOption,
    bind: str | None = typer.Option(None, "--bind", help="HOST:PORT (default from the config)."),
) -> None:
    """Run the DNC server: the machines of CONFIG, the API and server-sent events."""
    with cli_errors():
        require_server_extra()
        import asyncio

        from opendnc.server.app import build
        from opendnc.server.config import load_config

        shop = load_config(config)
        host, port = shop.server.bind_host, shop.server.bind_port
        if bind is not None:
            host, sep, port_text = bind.rpartition(":")
            if not sep or not port_text.isdigit():
                raise InputError(f"--bind {bind!r}: expected HOST:PORT")
            port = int(port_text)
        server = build(shop, database=db)
        try:
            asyncio.run(_serve(server, host, port))
        except OSError as exc:
            raise InputError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from exc
        finally:
            server.engine.dispose()


async def _serve(server: Server, host: str, port: int) -> None:
    """Run uvicorn; say where once it listens (scripts wait for that line)."""
    import asyncio

    import uvicorn

    if server.mtconnect is not None:
        # Its ports open before the app starts, so a taken one is a plain error naming it.
        await server.mtconnect.start()
    settings = uvicorn.Config(server.app, host=host, port=port, log_level="warning", lifespan="on")
    web = uvicorn.Server(settings)
    serving = asyncio.create_task(web.serve())
    while not web.started:
        if serving.done():
            serving.result()  # raises why it could not start
            raise InputError(f"the server on {host}:{port} stopped at once")
        await asyncio.sleep(0.05)
    port = web.servers[0].sockets[0].getsockname()[1]  # the real one for :0
    database = server.engine.url.render_as_string(hide_password=True)
    console.print(
        f"opendnc server on http://{host}:{port}/ ({len(server.config.machines)} machines, "
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
        from opendnc.server import auth
        from opendnc.server.config import load_config
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
    from opendnc.server.config import load_config
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
        from opendnc.server import auth
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
        from opendnc.server import auth

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
        from opendnc.server import library
        from opendnc.server.config import load_config
        from opendnc.server.requests import match_request

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
