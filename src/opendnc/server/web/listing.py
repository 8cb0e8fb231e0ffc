"""The program text on the program page: a window of lines the server renders, which the
page's script (``static/listing.js``) replaces by a virtual list over the whole text.

A program can hold a million lines; a page that lays all of them out is a 100,000-pixel page
that takes seconds to draw. The server sends one window (:data:`WINDOW` lines, around
``?line=N`` when given) with links to the windows before and after it, which is the whole
listing without scripts; the script fetches the version's bytes, draws only the rows in view
in a box of bounded height, and answers ``#L<n>`` anchors, go-to-line and find.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from markupsafe import Markup

from opendnc.nccheck import Control, guess_control
from opendnc.server.web.render import highlight_lines

__all__ = ["SCRIPT_MAX_BYTES", "WINDOW", "Listing", "Mark", "marks", "window"]

WINDOW = 100
"""Lines the server renders in one window."""
BEFORE = 20
"""Lines shown above the target of ``?line=N`` (so the reader sees where it comes from)."""
SCRIPT_MAX_BYTES = 32 * 1024 * 1024
"""Larger versions are read a window at a time only (the script would fetch it whole)."""


@dataclass(frozen=True)
class Listing:
    """One window of a program's lines, 1-based."""

    first: int
    lines: list[Markup]
    total: int
    target: int | None
    dialect: str
    """``gcode`` or ``klartext``: how the script highlights the text."""
    scripted: bool
    """Whether the script may fetch the whole text (it is at most :data:`SCRIPT_MAX_BYTES`)."""

    @property
    def last(self) -> int:
        """The last line of the window."""
        return self.first + len(self.lines) - 1

    @property
    def previous(self) -> int | None:
        """The ``?line=`` of the window before this one, if any."""
        if self.first <= 1:
            return None
        return min(self.total, max(1, self.first - WINDOW) + BEFORE)

    @property
    def next(self) -> int | None:
        """The ``?line=`` of the window after this one, if any."""
        return min(self.total, self.last + 1 + BEFORE) if self.last < self.total else None


def window(text: str, *, name: str, size: int, line: int | None = None) -> Listing:
    """The window of ``text`` that shows ``line`` (from the start without it); ``size`` is
    the version's size in bytes."""
    lines = text.split("\n")
    if lines and lines[-1] == "" and len(lines) > 1:
        lines.pop()  # the newline that ends the last line starts no line of its own
    total = len(lines) if text else 0
    target = min(line, total) if line is not None and total else None
    first = max(1, target - BEFORE) if target is not None else 1
    shown = lines[first - 1 : first - 1 + WINDOW] if total else []
    # one row a line: the highlighter may end with an empty line of its own, or drop an
    # empty last line
    rows = highlight_lines("\n".join(shown))[: len(shown)]
    rows += [Markup("")] * (len(shown) - len(rows))
    dialect = "klartext" if guess_control(text[:4096], name) is Control.HEIDENHAIN else "gcode"
    return Listing(
        first=first,
        lines=rows,
        total=total,
        target=target,
        dialect=dialect,
        scripted=size <= SCRIPT_MAX_BYTES,
    )


@dataclass(frozen=True)
class Mark:
    """What the program check found on one line: its worst severity and every message."""

    severity: str
    """``error`` or ``warning``."""
    message: str


def marks(problems: Iterable[Mapping[str, Any]]) -> dict[int, Mark]:
    """The program check's ``problems`` by line (an error outranks a warning on its line), for
    the listing's rows: the page marks them and shows the messages on hover."""
    found: dict[int, Mark] = {}
    for problem in problems:
        line, severity = int(problem["line"]), str(problem["severity"])
        message = f"{severity}: {problem['message']}"
        before = found.get(line)
        if before is not None:
            worst = "error" if "error" in (severity, before.severity) else severity
            message = f"{before.message}\n{message}"
            severity = worst
        found[line] = Mark(severity, message)
    return found
