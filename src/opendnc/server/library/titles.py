"""A program's title, as the library list shows it: what the program says it is.

* ISO/Fanuc/Haas G-code: the comment on the O-number line, ``O1000 (BRACKET OP1)``
  (``%`` lines and blank lines before it skipped; ``:1000`` is an O-number too);
* Heidenhain Klartext: the comment line right after ``BEGIN PGM`` (``1 ; BRACKET OP1``),
  otherwise the program's name from ``BEGIN PGM BRACKET MM``.

Only the first :data:`HEAD` bytes are read (the library reads no more of a large program).
"""

from __future__ import annotations

import re

__all__ = ["HEAD", "MAX_TITLE", "title_of"]

HEAD = 2048  # bytes of a program read for its title
MAX_TITLE = 80

_O_LINE = re.compile(r"^\s*(?:N\d+\s*)?[O:]\s*\d{1,8}\b[^(]*\(([^)]*)\)?", re.IGNORECASE)
# matched on a line with its leading blanks stripped: digits, blanks and words follow each
# other without overlapping classes, so no pattern here backtracks more than linearly
_BEGIN = re.compile(r"\d*[ \t]*BEGIN[ \t]+PGM[ \t]+(\S+)", re.IGNORECASE)
_KLARTEXT_COMMENT = re.compile(r"\d*[ \t]*;(.*)$")
_CONTROL = re.compile(r"[\x00-\x1f\x7f]")


def _clean(text: str) -> str:
    text = _CONTROL.sub(" ", text).strip()
    text = re.sub(r"\s+", " ", text)
    return text[:MAX_TITLE].rstrip()


def title_of(head: bytes) -> str:
    """The title of a program from its first bytes; empty if it names none."""
    lines = head[:HEAD].decode("latin-1").splitlines()
    if lines and len(head) >= HEAD:
        lines = lines[:-1]  # the last line may be cut
    seen = [(i, line) for i, line in enumerate(lines) if line.strip() and line.strip() != "%"]
    for index, (_, line) in enumerate(seen[:3]):
        begin = _BEGIN.match(line.lstrip())
        if begin:
            after = seen[index + 1][1] if index + 1 < len(seen) else ""
            comment = _KLARTEXT_COMMENT.match(after.lstrip())
            if comment and _clean(comment.group(1)):
                return _clean(comment.group(1))
            return _clean(begin.group(1))
        o_line = _O_LINE.match(line)
        if o_line:
            return _clean(o_line.group(1) or "")
    return ""
