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
from dataclasses import dataclass, field

from opendnc.errors import InputError

__all__ = ["RequestRule", "RequestSettings", "find_request", "report_program"]


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
        fields = set(re.findall(r"{(\w+)", template))
        unknown = fields - set(compiled.groupindex) - {"number"}
        if unknown:
            raise InputError(f"{key}.template names groups the pattern lacks: {sorted(unknown)}")
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


def find_request(data: bytes, settings: RequestSettings) -> list[str] | None:
    """The program names ``data`` asks for, or None when it is not a request."""
    lines = data.decode("latin-1").splitlines()
    head = "\n".join(line for line in lines if line.strip() not in ("", "%"))
    head = "\n".join(head.splitlines()[: settings.scan_lines])
    for rule in settings.rules:
        names = rule.names(head)
        if not names:
            continue
        if rule is DEFAULT_RULES[0]:
            # The default REQ rule matched the whole comment; take every REQ inside it.
            names = [f"O{int(n):05d}.nc" for n in _EACH_REQ.findall(head)]
        return list(dict.fromkeys(names))  # each program once, in the order asked
    return None


def _comment(text: str) -> str:
    # A Haas comment cannot hold parentheses; keep it to the printable upper-case alphabet
    # that every control shows.
    cleaned = re.sub(r"[^A-Z0-9 .,:=/_+-]", " ", text.upper())
    return re.sub(r"\s+", " ", cleaned).strip()[:60]


def report_program(number: int, title: str, lines: list[str]) -> bytes:
    """A short program the operator sees: ``O09998 (OPENDNC ...)`` with one comment a line."""
    body = [f"O{number:05d} ({_comment('OPENDNC ' + title)})"]
    body += [f"({_comment(line)})" for line in lines]
    body.append("M30")
    return ("%\r\n" + "\r\n".join(body) + "\r\n%\r\n").encode("ascii")
