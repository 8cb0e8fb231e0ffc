"""Entry point: ``opendnc <group> <command>``."""

from __future__ import annotations

import typer

from opendnc import __version__
from opendnc.cli import demo_server, dprnt, haas, lsv2, serve, sim, surface, xmodem

app = typer.Typer(
    name="opendnc",
    help="Open DNC toolkit: talk to CNC controls, simulate them, move programs.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
)
app.add_typer(lsv2.app, name="lsv2")
app.add_typer(sim.app, name="sim")
app.add_typer(xmodem.app, name="xmodem")
app.add_typer(haas.app, name="haas")
app.add_typer(dprnt.app, name="dprnt")
app.add_typer(surface.app, name="surface")
app.command("demo")(demo_server.demo)
app.command("serve")(serve.serve)
app.add_typer(serve.keys_app, name="keys")


@app.command("version")
def version() -> None:
    """Print the opendnc version."""
    typer.echo(__version__)


if __name__ == "__main__":
    app()
