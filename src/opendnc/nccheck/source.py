"""Where a dry run reads a program from: a file read in order, or a text in memory.

A dry run reads its program once, line by line, and keeps no copy of it; a jump back (a
loop, a sub-program after the main one) reads the lines again from a remembered offset.
:class:`FileSource` reads a file in pieces (so a program of any size costs the same memory);
:class:`TextSource` serves a text already in memory (the server's programs). Both give
lines without their ends (LF, CR LF or a lone CR) with their 1-based number and offset.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

__all__ = ["FileSource", "Source", "TextSource"]

_PIECE = 1 << 20  # bytes read at a time
_LINE_END = re.compile(r"\r\n?|\n")


class Source:
    """A program's lines, read from any remembered offset."""

    name: str = ""

    def lines(self, offset: int = 0, line: int = 1) -> Iterator[tuple[int, int, str]]:
        """``(line number, offset, text)`` of each line from ``offset`` (the start of line
        ``line``) to the end."""
        raise NotImplementedError

    def pieces(self) -> Iterator[bytes]:
        """The program's bytes in pieces (UnicodeEncodeError for a text beyond latin-1)."""
        raise NotImplementedError

    def head(self, size: int) -> str:
        """The first ``size`` characters (to guess the language and the control)."""
        raise NotImplementedError


class TextSource(Source):
    """A program text in memory."""

    def __init__(self, text: str) -> None:
        self.text = text

    def lines(self, offset: int = 0, line: int = 1) -> Iterator[tuple[int, int, str]]:
        text = self.text
        size = len(text)
        while offset < size:
            found = _LINE_END.search(text, offset)
            if found is None:
                yield line, offset, text[offset:]
                return
            yield line, offset, text[offset : found.start()]
            offset = found.end()
            line += 1

    def pieces(self) -> Iterator[bytes]:
        yield self.text.encode("latin-1")

    def head(self, size: int) -> str:
        return self.text[:size]


class FileSource(Source):
    """A program file, read in pieces of a MiB (latin-1: every byte keeps its place)."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def lines(self, offset: int = 0, line: int = 1) -> Iterator[tuple[int, int, str]]:
        with open(self.path, "rb") as stream:
            stream.seek(offset)
            rest = ""  # the start of a line cut by the end of a piece
            while piece := stream.read(_PIECE).decode("latin-1"):
                parts = (rest + piece).split("\n")
                rest = parts.pop()
                for part in parts:
                    if "\r" not in part:
                        yield line, offset, part
                        offset += len(part) + 1
                        line += 1
                        continue
                    # a CR LF end, or lone CRs ending lines of their own
                    crlf = part.endswith("\r")
                    pieces = part.split("\r")
                    if crlf:
                        pieces.pop()
                    for index, text in enumerate(pieces):
                        yield line, offset, text
                        last = index == len(pieces) - 1
                        offset += len(text) + (1 + crlf if last else 1)
                        line += 1
                cut = rest.rfind("\r", 0, len(rest) - 1)
                if cut >= 0:  # lone CRs (a CR-only file): the lines they end are complete
                    for text in rest[:cut].split("\r"):
                        yield line, offset, text
                        offset += len(text) + 1
                        line += 1
                    rest = rest[cut + 1 :]
            if rest:
                pieces = rest.split("\r")
                if not pieces[-1]:
                    pieces.pop()
                for text in pieces:
                    yield line, offset, text
                    offset += len(text) + 1
                    line += 1

    def pieces(self) -> Iterator[bytes]:
        with open(self.path, "rb") as stream:
            while piece := stream.read(_PIECE):
                yield piece

    def head(self, size: int) -> str:
        with open(self.path, "rb") as stream:
            return stream.read(size).decode("latin-1")
