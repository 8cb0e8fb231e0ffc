"""`opendnc sim tnc`."""

from __future__ import annotations

import typer


def tnc() -> None:
    """(being built)"""
    typer.echo("not built yet")
    raise typer.Exit(2)
