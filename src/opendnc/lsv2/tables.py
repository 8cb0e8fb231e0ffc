"""Heidenhain table files (tool ``.T``, pocket ``.TCH``, ``.TAB``, datum ``.D``): parse and write.

Fixed-width text: ``BEGIN <NAME> [MM|INCH] ...``, optional ``#STRUCTBEGIN ... #STRUCTEND`` or
``TableDescription ( ... )`` block, a header line whose column-name positions define the
widths, one row per line, ``[END]``. Pure text in, typed values out; no I/O.

>>> t = parse_table("BEGIN TOOL.T MM\\nT    NAME   L\\n0    A      +10.5\\n[END]\\n")
>>> t.typed_rows()
[{'T': 0, 'NAME': 'A', 'L': 10.5}]
"""

from __future__ import annotations

import csv
import io
import json
import re
from dataclasses import dataclass, field

from opendnc.errors import InputError

__all__ = ["Cell", "Column", "Table", "fixed_columns", "parse_table"]

Cell = int | float | str | None

_INT = re.compile(r"^[+-]?\d+$")
_FLOAT = re.compile(r"^[+-]?(\d+\.\d*|\.\d+|\d+)([eE][+-]?\d+)?$")


def _typed(text: str) -> Cell:
    if not text:
        return None
    if _INT.match(text):
        return int(text)
    if _FLOAT.match(text):
        return float(text)
    return text


@dataclass(frozen=True, slots=True)
class Column:
    """A column: name, start offset and width (``None`` = to the end of the line)."""

    name: str
    start: int
    width: int | None


def fixed_columns(*spec: tuple[str, int]) -> list[Column]:
    """Columns laid out left to right from ``(name, width)`` pairs, for writing a new table."""
    columns, start = [], 0
    for name, width in spec:
        columns.append(Column(name, start, width))
        start += width
    return columns


@dataclass
class Table:
    """A parsed table; ``rows`` keep the cell text exactly as in the file."""

    begin: str
    columns: list[Column]
    rows: list[dict[str, str]] = field(default_factory=list)
    preamble: list[str] = field(default_factory=list)
    """Lines between ``BEGIN`` and the header (structure descriptions), kept verbatim."""

    @property
    def name(self) -> str:
        """Table file name from the ``BEGIN`` line, e.g. ``TOOL.T``."""
        parts = self.begin.split()
        return parts[1] if len(parts) > 1 else ""

    @property
    def unit(self) -> str | None:
        """``MM`` or ``INCH`` if the ``BEGIN`` line says so."""
        for word in self.begin.split()[2:]:
            if word.upper() in ("MM", "INCH"):
                return word.upper()
        return None

    @property
    def column_names(self) -> list[str]:
        """Column names in file order."""
        return [c.name for c in self.columns]

    def typed_rows(self) -> list[dict[str, Cell]]:
        """Rows with numbers as int/float and empty cells as ``None``."""
        return [{k: _typed(v) for k, v in row.items()} for row in self.rows]

    def to_csv(self) -> str:
        """CSV with a header row; cell text as in the table."""
        out = io.StringIO()
        writer = csv.DictWriter(out, fieldnames=self.column_names, lineterminator="\n")
        writer.writeheader()
        writer.writerows(self.rows)
        return out.getvalue()

    def to_json(self) -> str:
        """JSON: name, unit, columns and typed rows."""
        doc = {
            "name": self.name,
            "unit": self.unit,
            "columns": self.column_names,
            "rows": self.typed_rows(),
        }
        return json.dumps(doc, indent=2)

    def to_text(self, line_end: str = "\r\n") -> str:
        """Render back to the fixed-width file format."""
        header = "".join(
            c.name.ljust(c.width) if c.width is not None else c.name for c in self.columns
        )
        lines = [self.begin, *self.preamble, header.rstrip()]
        for row in self.rows:
            cells = []
            for c in self.columns:
                text = row.get(c.name, "")
                if c.width is not None:
                    if len(text) > c.width:
                        raise InputError(f"{c.name} value {text!r} wider than {c.width}")
                    text = text.ljust(c.width)
                cells.append(text)
            lines.append("".join(cells).rstrip())
        lines.append("[END]")
        return line_end.join(lines) + line_end


def _columns(header: str) -> list[Column]:
    marks = [(m.start(), m.group()) for m in re.finditer(r"\S+", header)]
    if not marks:
        raise InputError("table has no header line")
    cols = []
    for i, (start, name) in enumerate(marks):
        width = marks[i + 1][0] - start if i + 1 < len(marks) else None
        cols.append(Column(name, start, width))
    return cols


def parse_table(text: str) -> Table:
    """Parse table text; raises :class:`InputError` naming what is wrong."""
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines or not lines[0].lstrip().upper().startswith("BEGIN"):
        raise InputError("not a table file: first line must start with BEGIN")
    begin = lines[0]
    i = 1
    preamble: list[str] = []
    if i < len(lines) and lines[i].lstrip().upper().startswith("#STRUCTBEGIN"):
        while i < len(lines):
            preamble.append(lines[i])
            i += 1
            if preamble[-1].lstrip().upper().startswith("#STRUCTEND"):
                break
    elif i < len(lines) and lines[i].lstrip().startswith("TableDescription"):
        depth = 0
        while i < len(lines):
            preamble.append(lines[i])
            depth += lines[i].count("(") - lines[i].count(")")
            i += 1
            if depth <= 0:
                break
    if i >= len(lines):
        raise InputError("table has no header line")
    columns = _columns(lines[i])
    rows: list[dict[str, str]] = []
    ended = False
    for line in lines[i + 1 :]:
        if line.strip().upper() == "[END]":
            ended = True
            break
        row = {}
        for c in columns:
            end = None if c.width is None else c.start + c.width
            row[c.name] = line[c.start : end].strip()
        rows.append(row)
    if not ended:
        raise InputError("table ends without [END] (truncated file?)")
    return Table(begin, columns, rows, preamble)
