"""`opendnc sim` commands: virtual controls and the virtual null-modem cable."""

from __future__ import annotations

import typer

app = typer.Typer(
    help="Virtual controls and links for testing without a machine.", no_args_is_help=True
)
