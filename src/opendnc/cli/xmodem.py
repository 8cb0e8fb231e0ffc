"""`opendnc xmodem` commands."""

from __future__ import annotations

import typer

app = typer.Typer(help="xmodem commands", no_args_is_help=True)
