"""``opendnc check FILE``: a dry run of an NC program on a virtual control, without I/O.

Prints one problem a line (``FILE:LINE: error|warning: message``), then a summary line;
``--json`` prints the whole result instead. Exit status 1 when there is an error, 0
otherwise (warnings allowed), 2 for a usage error (docs/check.md#command-line).
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import typer

if TYPE_CHECKING:
    from opendnc.nccheck import CheckResult

__all__ = ["check"]


def check(
    file: Path = typer.Argument(..., help="The program to check.", dir_okay=False),
    control: str = typer.Option(
        "",
        "--control",
        help="haas, heidenhain, iso, or a G-code control: haas-mill, haas-lathe, fanuc-mill, "
        "fanuc-lathe (default: guessed from the text).",
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
    from opendnc.errors import InputError
    from opendnc.nccheck import Budget, Control, MachineLimits, check_file, limits_for
    from opendnc.nccheck.dialects import DIALECTS, dialect_named

    chosen = None
    dialect: str | None = None
    if control:
        try:
            chosen = Control(control.lower())
        except ValueError:
            try:  # a G-code control by name: haas-lathe, fanuc-mill, ...
                dialect = dialect_named(control).name
            except InputError:
                names = ", ".join(("haas", "heidenhain", "iso", *DIALECTS))
                raise typer.BadParameter(f"expected {names}", param_hint="'--control'") from None
            chosen = Control.HAAS
    limits: MachineLimits | None = None
    if machine or config:
        if not (machine and config):
            raise typer.BadParameter("--machine and --config go together", param_hint="'--machine'")
        from opendnc.server.config.shop import load_config

        try:
            limits = limits_for(load_config(config).machine(machine))
        except InputError as exc:
            raise typer.BadParameter(str(exc), param_hint="'--machine'") from None
    if dialect is not None:
        # the named control wins over the machine's own control key
        limits = replace(limits, dialect=dialect) if limits else MachineLimits(dialect=dialect)
    _readable(file)
    # read as a stream (latin-1: every byte keeps its place), so memory does not grow with
    # the program; no time limit: each block runs once and the block budget ends any loop.
    # The moves are kept only for --json (its preview reads them)
    budget = Budget(seconds=None, moves=Budget().moves if json_output else 0)
    result = check_file(file, control=chosen, name=str(file), machine=limits, budget=budget)
    _print(result, str(file), json_output)
    raise typer.Exit(0 if result.ok else 1)


def _readable(file: Path) -> None:
    """Refuse what is not a readable regular file (a usage error).

    Only a regular file is read: a device (``/dev/zero``) never ends and a FIFO may never
    deliver, so both are usage errors rather than a hang or a read until memory runs out.
    """
    import os
    import stat

    try:
        # stat, not open: opening a FIFO blocks until a writer comes
        mode = os.stat(file).st_mode
        if not stat.S_ISREG(mode):
            what = "a FIFO" if stat.S_ISFIFO(mode) else "a device or other special file"
            raise typer.BadParameter(f"{file} is {what}, not a regular file", param_hint="'FILE'")
        with open(file, "rb") as stream:
            stream.read(1)
    except OSError as exc:
        raise typer.BadParameter(
            f"cannot read {file}: {exc.strerror or exc}", param_hint="'FILE'"
        ) from None


def _print(result: CheckResult, name: str, json_output: bool) -> None:
    if json_output:
        sys.stdout.write(result.to_json() + "\n")
    else:
        out = [problem.format(name) for problem in result.problems]
        out.append(result.summary())
        sys.stdout.write("\n".join(out) + "\n")
    sys.stdout.flush()
