"""The entry point: guess the control, run the right dry run, add the machine's checks."""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

from opendnc.nccheck.limits import MachineLimits
from opendnc.nccheck.result import CheckResult, Control, Problem, Severity
from opendnc.nccheck.source import Source

__all__ = ["Budget", "Library", "check_file", "check_source", "check_text", "guess_control"]

Library = Callable[[str], str | None]
"""Looks a called program up by name (``"O09010"``, ``"PART2.H"``): its text, or None."""


@dataclass(frozen=True, slots=True)
class Budget:
    """How far a dry run may go before it calls the program endless."""

    blocks: int = 1_000_000
    """Blocks run again (each pass of a loop after the first reading of its blocks counts);
    every block of the file runs once outside this budget."""
    seconds: float | None = 5.0
    """CPU time of the dry run itself (its thread's, so a busy machine does not shorten it);
    None: no time limit (the command line: the block budget still ends any loop)."""
    moves: int = 1_000_000
    """Moves kept for the preview (counting and checks go on past it); 0 keeps none."""


# Matched against one line at a time, after its leading blanks are stripped: the classes
# that follow each other (digits, then blanks, then a word) never overlap, so a match is
# linear in the line's length. (A MULTILINE ``^\s*\d*\s*`` over the head spanned lines and
# backtracked cubically on a file of blank lines: 4,096 of them froze the server.)
_KLARTEXT = re.compile(r"\d*[ \t]*BEGIN[ \t]+PGM\b", re.IGNORECASE)
_ISO_HEAD = re.compile(r"%[ \t]*\w[\w.-]*[ \t]+G7[01]\b")
_LINE_END = re.compile(r"\r\n?|\n")


def _head_lines(text: str) -> list[str]:
    """The lines of ``text`` (CR LF, LF or CR-only ends), each without its leading blanks."""
    return [line.lstrip(" \t") for line in _LINE_END.split(text)]


def guess_control(text: str, name: str = "") -> Control:
    """The control a program is written for, from its text (and file name).

    ``BEGIN PGM`` is Heidenhain conversational; a ``.I``/``.i`` file name, or a
    ``%NAME G71`` start line, Heidenhain ISO; anything else (``%``, ``O`` numbers,
    G-words) G-code for a Haas / Fanuc macro-B control.
    """
    lines = _head_lines(text[:4096])
    if any(_KLARTEXT.match(line) for line in lines):
        return Control.HEIDENHAIN
    lowered = name.lower()
    if lowered.endswith(".h"):
        return Control.HEIDENHAIN
    if lowered.endswith(".i") or any(_ISO_HEAD.match(line) for line in lines):
        return Control.ISO
    return Control.HAAS


def check_text(
    text: str,
    *,
    control: Control | None = None,
    name: str = "",
    machine: MachineLimits | None = None,
    library: Library | None = None,
    budget: Budget | None = None,
) -> CheckResult:
    """Dry-run ``text`` and report what a control would stop on, and what it would do.

    ``control`` defaults to :func:`guess_control`; ``machine`` adds the machine's checks
    (family, travel with its work offsets, tools, protected program numbers); ``library``
    resolves called programs (a call it cannot resolve is a warning). Never raises on any
    text; always ends within ``budget``.
    """
    from opendnc.nccheck.source import TextSource

    return check_source(
        TextSource(text),
        control=control,
        name=name,
        machine=machine,
        library=library,
        budget=budget,
    )


def check_file(
    path: Path,
    *,
    control: Control | None = None,
    name: str = "",
    machine: MachineLimits | None = None,
    library: Library | None = None,
    budget: Budget | None = None,
) -> CheckResult:
    """:func:`check_text` on a file read as a stream: its memory does not grow with the
    program's length (docs/check.md#large-programs). The file is read as latin-1."""
    from opendnc.nccheck.source import FileSource

    return check_source(
        FileSource(path),
        control=control,
        name=name or str(path),
        machine=machine,
        library=library,
        budget=budget,
    )


def check_source(
    source: Source,
    *,
    control: Control | None = None,
    name: str = "",
    machine: MachineLimits | None = None,
    library: Library | None = None,
    budget: Budget | None = None,
) -> CheckResult:
    """:func:`check_text` on the lines of ``source``."""
    chosen = control or guess_control(source.head(4096), name)
    budget = budget or Budget()
    try:
        if chosen is Control.HEIDENHAIN:
            from opendnc.nccheck.klartext import run_klartext

            result = run_klartext(
                source, name=name, machine=machine, library=library, budget=budget
            )
        else:
            from opendnc.nccheck.gcode import run_gcode

            result = run_gcode(
                source, control=chosen, name=name, machine=machine, library=library, budget=budget
            )
    except (RecursionError, MemoryError, ArithmeticError, LookupError, ValueError) as exc:
        # last resort, so a release or send is never blocked by a crash: the program is then
        # reported as not checked (the property tests assert this never happens)
        problem = Problem(1, Severity.ERROR, f"internal error: the dry run failed ({exc!r})")
        result = CheckResult(control=chosen, name=name, problems=(problem,))
    if chosen is Control.HAAS:
        text_problem = _text_problem(source)
        if text_problem is not None:
            result = replace(result, problems=_merged(result.problems, text_problem))
    if machine is not None and not machine.accepts(chosen):
        # the machine's G-code control by name where it has one (a Fanuc is no Haas)
        family = machine.dialect or machine.family or "unknown"
        mismatch = Problem(
            1,
            Severity.ERROR,
            f"a {chosen.value} program cannot run on {machine.name or 'this machine'} "
            f"({family} control)",
        )
        result = replace(result, problems=(mismatch, *result.problems))
    return result


def _text_problem(source: Source) -> Problem | None:
    """The first byte no Haas program holds (docs/nc-text.md): senders refuse such a file."""
    from opendnc.nctext import TextScanner

    scanner = TextScanner()
    try:
        for piece in source.pieces():
            scanner.feed(piece)
            if scanner.problem is not None:
                break
    except UnicodeEncodeError as exc:
        text = source.head(exc.start)
        line = text.count("\n") + 1
        return Problem(line, Severity.ERROR, "a character beyond 8 bits is not NC program text")
    found = scanner.finish()
    if found is None:
        return None
    return Problem(
        found.line,
        Severity.ERROR,
        f"byte 0x{found.byte:02X} ({found.reason}) at column {found.column} is not NC "
        "program text: the file would be refused before sending",
    )


def _merged(problems: tuple[Problem, ...], extra: Problem) -> tuple[Problem, ...]:
    return tuple(sorted((*problems, extra), key=lambda p: p.line))
