"""`opendnc lsv2` commands."""

from __future__ import annotations

import typer

app = typer.Typer(help="lsv2 commands", no_args_is_help=True)
