"""`opendnc dprnt` commands."""

from __future__ import annotations

import typer

app = typer.Typer(help="dprnt commands", no_args_is_help=True)
