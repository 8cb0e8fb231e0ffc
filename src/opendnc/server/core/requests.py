"""Remote request: the operator asks for programs by sending a small program from the control.

A received program is a request when one of the ordered rules matches within its first
``scan_lines`` lines; every match names one program (``(REQ O1234 REQ O5678)`` asks for two).
The first rule that matches at all decides; its template builds the library name from the
match's named groups. The default rules take ``(REQ O1234)``, ``(REQ 1234)`` and
``(PRG=1234)`` and name the program ``O01234.nc`` (the five-digit form a Haas writes).

The answer goes back as programs: the requested ones after the request delay (time for the
operator to switch the control to receive), and a short report program for anything that
could not be sent, which the operator sees in the control's program list.
"""

from __future__ import annotations

import re
import string
from dataclasses import dataclass, field

from opendnc.errors import InputError

__all__ = [
    "COMMENT_WIDTH",
    "RequestMatch",
    "RequestRule",
    "RequestSettings",
    "find_request",
    "match_request",
    "report_program",
]


COMMENT_WIDTH = 60
"""Characters of a report line the control shows (a longer one is cut there)."""


@dataclass(frozen=True)
class RequestRule:
    """``pattern`` (a regular expression with named groups) and the name ``template``."""

    pattern: re.Pattern[str]
    template: str

    @classmethod
    def make(cls, pattern: str, template: str, *, key: str = "rule") -> RequestRule:
        """Compile a rule; :class:`InputError` names ``key`` if it is unusable."""
        try:
            compiled = re.compile(pattern, re.IGNORECASE)
        except re.error as exc:
            raise InputError(f"{key}.pattern: not a regular expression: {exc}") from None
        try:
            parts = list(string.Formatter().parse(template))
        except ValueError as exc:
            raise InputError(f"{key}.template: {exc}") from None
        literal = "".join(text for text, _, _, _ in parts)
        if "/" in literal or "\\" in literal or ".." in literal or not literal.isprintable():
            # The template only names a program in the library; it never reaches a folder.
            raise InputError(f"{key}.template: no folders, '..' or control characters")
        fields = {name for _, name, _, _ in parts if name is not None}
        if not all(name.isidentifier() for name in fields):
            raise InputError(f"{key}.template: fields are group names such as {{number}}")
        unknown = fields - set(compiled.groupindex) - {"number"}
        if unknown:
            raise InputError(f"{key}.template names groups the pattern lacks: {sorted(unknown)}")
        try:
            template.format(**dict.fromkeys(fields, "1"))
        except ValueError as exc:
            raise InputError(f"{key}.template: {exc}") from None
        return cls(compiled, template)

    def names(self, text: str) -> list[str]:
        """The program names this rule finds in ``text`` (empty: no match)."""
        out = []
        for match in self.pattern.finditer(text):
            groups = {k: v for k, v in match.groupdict().items() if v is not None}
            if "number" in groups:
                groups["number"] = f"{int(groups['number']):05d}"
            out.append(self.template.format(**groups))
        return out


DEFAULT_RULES = (
    RequestRule.make(r"\(\s*(?:/?REQ\s+O?(?P<number>\d{1,5})\s*)+\)", "O{number}.nc"),
    RequestRule.make(r"\(\s*PRG\s*=\s*O?(?P<number>\d{1,5})\s*\)", "O{number}.nc"),
)
# A request may name several programs inside one comment: "(REQ O111 REQ O222)".
_EACH_REQ = re.compile(r"REQ\s+O?(\d{1,5})", re.IGNORECASE)


@dataclass(frozen=True)
class RequestSettings:
    """The ``[requests]`` table of the configuration."""

    delay: float = 5.0  # seconds before the answer, so the operator can select receive
    scan_lines: int = 5
    report_program: int = 9998  # O-number of the report programs sent back
    reports: str = "failures"  # failures | all | none
    rules: tuple[RequestRule, ...] = field(default_factory=lambda: DEFAULT_RULES)


@dataclass(frozen=True)
class RequestMatch:
    """Which rule took a request (``index`` in the configured order) and the names it built."""

    index: int
    pattern: str
    names: list[str]


def match_request(data: bytes, settings: RequestSettings) -> RequestMatch | None:
    """The first rule that matches ``data`` and the program names it asks for; None when
    ``data`` is not a request. What ``opendnc requests test`` shows."""
    lines = data.decode("latin-1").splitlines()
    head = "\n".join(line for line in lines if line.strip() not in ("", "%"))
    head = "\n".join(head.splitlines()[: settings.scan_lines])
    for index, rule in enumerate(settings.rules):
        names = rule.names(head)
        if not names:
            continue
        if rule is DEFAULT_RULES[0]:
            # The default REQ rule matched the whole comment; take every REQ inside it.
            names = [f"O{int(n):05d}.nc" for n in _EACH_REQ.findall(head)]
        # each program once, in the order asked
        return RequestMatch(index, rule.pattern.pattern, list(dict.fromkeys(names)))
    return None


def find_request(data: bytes, settings: RequestSettings) -> list[str] | None:
    """The program names ``data`` asks for, or None when it is not a request."""
    found = match_request(data, settings)
    return None if found is None else found.names


def _comment(text: str) -> str:
    # A Haas comment cannot hold parentheses; keep it to the printable upper-case alphabet
    # that every control shows.
    cleaned = re.sub(r"[^A-Z0-9 .,:=/_+-]", " ", text.upper())
    return re.sub(r"\s+", " ", cleaned).strip()[:COMMENT_WIDTH]


def report_program(number: int, title: str, lines: list[str], digits: int = 5) -> bytes:
    """A short program the operator sees: ``O09998 (OPENDNC ...)`` with one comment a line
    (``digits``: the O-number's width, ``O9998`` on a control of 4-digit O-numbers)."""
    body = [f"O{number:0{digits}d} ({_comment('OPENDNC ' + title)})"]
    body += [f"({_comment(line)})" for line in lines]
    body.append("M30")
    return ("%\r\n" + "\r\n".join(body) + "\r\n%\r\n").encode("ascii")
