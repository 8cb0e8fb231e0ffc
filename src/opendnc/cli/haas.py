"""`opendnc haas` commands."""

from __future__ import annotations

import typer

app = typer.Typer(help="haas commands", no_args_is_help=True)
