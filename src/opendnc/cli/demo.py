"""`opendnc demo`: a live tour against virtual controls, with no setup."""

from __future__ import annotations

import typer


def demo() -> None:
    """Start virtual controls and show what opendnc does with them."""
    typer.echo("opendnc demo: the virtual controls are being built; see README.")
