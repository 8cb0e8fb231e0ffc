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
    from opendnc.nccheck import Control, MachineLimits, check_text, limits_for
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
    data = _read(file)
    if data is None:
        from opendnc.nccheck import guess_control
        from opendnc.nccheck.oversize import not_checked

        size = file.stat().st_size
        result = not_checked(str(file), size, chosen or guess_control("", str(file)))
        _print(result, str(file), json_output)
        raise typer.Exit(1)
    # NC programs are 7-bit text; latin-1 never fails and keeps every byte's position
    text = data.decode("latin-1")
    result = check_text(text, control=chosen, name=str(file), machine=limits, library=None)
    _print(result, str(file), json_output)
    raise typer.Exit(0 if result.ok else 1)


def _read(file: Path) -> bytes | None:
    """The program's bytes; None when it is larger than the check reads.

    Only a regular file is read: a device (``/dev/zero``) never ends and a FIFO may never
    deliver, so both are usage errors rather than a hang or a read until memory runs out.
    """
    import os
    import stat

    from opendnc.nccheck.oversize import MAX_PROGRAM_BYTES

    try:
        # stat, not open: opening a FIFO blocks until a writer comes
        mode = os.stat(file).st_mode
        if not stat.S_ISREG(mode):
            what = "a FIFO" if stat.S_ISFIFO(mode) else "a device or other special file"
            raise typer.BadParameter(f"{file} is {what}, not a regular file", param_hint="'FILE'")
        with open(file, "rb") as stream:
            data = stream.read(MAX_PROGRAM_BYTES + 1)
    except OSError as exc:
        raise typer.BadParameter(
            f"cannot read {file}: {exc.strerror or exc}", param_hint="'FILE'"
        ) from None
    return None if len(data) > MAX_PROGRAM_BYTES else data


def _print(result: CheckResult, name: str, json_output: bool) -> None:
    if json_output:
        sys.stdout.write(result.to_json() + "\n")
    else:
        out = [problem.format(name) for problem in result.problems]
        out.append(result.summary())
        sys.stdout.write("\n".join(out) + "\n")
    sys.stdout.flush()
