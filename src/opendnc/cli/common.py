"""Helpers shared by the command groups: JSON output and one-line errors."""

from __future__ import annotations

import contextlib
import dataclasses
import enum
import gc
import json
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from datetime import datetime
from pathlib import PurePath
from typing import Any

import typer
from rich.console import Console
from rich.markup import escape

from opendnc.errors import DncError, SafetyLockError

# no emoji codes: user text such as a scope signal "0:X:1" or a path must print as typed;
# soft_wrap: a line with a long path stays one line when piped (rich wraps at 80 columns there)
console = Console(emoji=False, soft_wrap=True)
err_console = Console(stderr=True, emoji=False)


@contextmanager
def start_up() -> Iterator[None]:
    """Import and build a long-running command's parts with the cyclic garbage collector
    paused, then freeze what they made.

    A server's imports and set-up make a few hundred thousand objects (classes, routes, tables,
    models) that live as long as the process. The collector's passes over them while they are
    made cost a fifth of the server's start (measured: 1.55 CPU s to ready, 1.23 s paused).
    Frozen, they are not walked by its later passes either; the collector is back on for
    whatever the command makes from then on."""
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        if was_enabled:
            gc.enable()


def to_jsonable(value: Any) -> Any:
    """Turn dataclasses, enums, datetimes, bytes and paths into JSON-friendly values."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: to_jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, enum.Enum):
        return value.name.lower()
    if isinstance(value, datetime):
        return value.isoformat()
    if isinstance(value, bytes):
        return value.hex()
    if isinstance(value, PurePath):
        return str(value)
    if isinstance(value, dict):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple | set | frozenset):
        return [to_jsonable(v) for v in value]
    return value


def print_json(value: Any) -> None:
    """Write ``value`` as one JSON document on stdout."""
    sys.stdout.write(json.dumps(to_jsonable(value), indent=2, ensure_ascii=False) + "\n")


@contextmanager
def cli_errors() -> Iterator[None]:
    """Report any :class:`DncError` as one line on stderr and exit with status 1."""
    try:
        yield
    except SafetyLockError as exc:
        # the exact line that would run it, so nobody guesses where --unsafe goes
        err_console.print(
            f"[bold red]error:[/] {escape(exc.action)} can change machine behaviour and is locked; "
            f"to run it: {escape(unsafe_command_line())}",
            highlight=False,
            soft_wrap=True,
        )
        raise typer.Exit(1) from exc
    except DncError as exc:
        # soft_wrap keeps the message on one line; escape keeps paths like [1] literal
        err_console.print(
            f"[bold red]error:[/] {escape(str(exc))}", highlight=False, soft_wrap=True
        )
        raise typer.Exit(1) from exc
    except KeyboardInterrupt:
        err_console.print("[yellow]interrupted[/]")
        raise typer.Exit(130) from None


def unsafe_command_line() -> str:
    """The command line being run, with ``--unsafe`` added (for a refusal message)."""
    from opendnc.cli.lazy import unsafe_command_line as line

    return line()


def run_cli(func: Callable[[], None]) -> None:
    """Run ``func`` under :func:`cli_errors`."""
    with cli_errors():
        func()


READY_FILE_HELP = (
    "Create this file once everything listens, remove it on stop "
    "(a script waits for it with `opendnc wait FILE`)."
)


@contextmanager
def ready_file(path: PurePath | None) -> Iterator[Callable[[], None]]:
    """Yield ``mark()``, which creates ``path`` (a readiness flag for `opendnc wait`).

    A flag left by an earlier run that did not stop cleanly is removed at once; the flag is
    removed again when the block ends, so a waiter never takes a stopped run for a ready one.
    """
    import os

    if path is not None:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(path)

    def mark() -> None:
        if path is not None:
            with open(path, "w", encoding="utf-8") as flag:
                flag.write(f"{os.getpid()}\n")

    try:
        yield mark
    finally:
        if path is not None:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(path)
