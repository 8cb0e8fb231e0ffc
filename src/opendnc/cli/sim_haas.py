"""`opendnc sim haas`."""

from __future__ import annotations

import typer


def haas() -> None:
    """(being built)"""
    typer.echo("not built yet")
    raise typer.Exit(2)
