"""``opendnc check FILE``: a dry run of an NC program on a virtual control, without I/O.

Prints one problem a line (``FILE:LINE: error|warning: message``), then a summary line;
``--json`` prints the whole result instead. Exit status 1 when there is an error, 0
otherwise (warnings allowed), 2 for a usage error (docs/check.md#command-line).
"""

from __future__ import annotations

import sys
from pathlib import Path

import typer

__all__ = ["check"]


def check(
    file: Path = typer.Argument(..., help="The program to check.", dir_okay=False),
    control: str = typer.Option(
        "", "--control", help="haas, heidenhain or iso (default: guessed from the text)."
    ),
    machine: str = typer.Option(
        "", "--machine", help="Check against this machine of --config (family, travel, ...)."
    ),
    config: Path | None = typer.Option(
        None, "--config", help="The server's configuration file (shop.toml) for --machine."
    ),
    json_output: bool = typer.Option(False, "--json", help="Print the result as JSON."),
) -> None:
    """Dry-run an NC program: problems with their lines, tools, extents, estimated time."""
    from opendnc.nccheck import Control, MachineLimits, check_text, limits_for

    chosen = None
    if control:
        try:
            chosen = Control(control.lower())
        except ValueError:
            raise typer.BadParameter(
                "expected haas, heidenhain or iso", param_hint="'--control'"
            ) from None
    limits: MachineLimits | None = None
    if machine or config:
        if not (machine and config):
            raise typer.BadParameter("--machine and --config go together", param_hint="'--machine'")
        from opendnc.errors import InputError
        from opendnc.server.config import load_config

        try:
            limits = limits_for(load_config(config).machine(machine))
        except InputError as exc:
            raise typer.BadParameter(str(exc), param_hint="'--machine'") from None
    try:
        data = file.read_bytes()
    except OSError as exc:
        raise typer.BadParameter(
            f"cannot read {file}: {exc.strerror or exc}", param_hint="'FILE'"
        ) from None
    # NC programs are 7-bit text; latin-1 never fails and keeps every byte's position
    text = data.decode("latin-1")
    result = check_text(text, control=chosen, name=str(file), machine=limits, library=None)
    if json_output:
        sys.stdout.write(result.to_json() + "\n")
    else:
        out = [problem.format(str(file)) for problem in result.problems]
        out.append(result.summary())
        sys.stdout.write("\n".join(out) + "\n")
    sys.stdout.flush()
    raise typer.Exit(0 if result.ok else 1)
