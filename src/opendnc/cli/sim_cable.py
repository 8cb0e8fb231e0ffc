"""`opendnc sim cable`."""

from __future__ import annotations

import typer


def cable() -> None:
    """(being built)"""
    typer.echo("not built yet")
    raise typer.Exit(2)
