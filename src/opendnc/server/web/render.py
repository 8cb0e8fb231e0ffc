"""Presentation helpers for the pages: templates, G-code highlighting, diffs, machine cards.

Nothing here touches the database or a machine: the views fetch through the service modules
and hand plain values to these functions.
"""

from __future__ import annotations

import difflib
import re
from dataclasses import dataclass
from datetime import UTC, datetime
from functools import cache
from pathlib import Path
from typing import Any

from jinja2 import Environment, FileSystemLoader, select_autoescape
from markupsafe import Markup, escape
from pygments import highlight
from pygments.formatters import HtmlFormatter
from pygments.lexers import GcodeLexer

from opendnc.server.events import percent
from opendnc.server.state import State

__all__ = [
    "Card",
    "DiffRow",
    "card",
    "card_oob",
    "environment",
    "highlight_lines",
    "language_of",
    "pygments_css",
    "side_by_side",
    "word_diff",
    "words",
]

HERE = Path(__file__).parent
KIND_LABEL = {
    "lsv2": "Heidenhain · LSV2",
    "haas_ngc": "Haas NGC · Ethernet",
    "haas_serial": "Haas · RS-232",
}
# How a card is filed by the overview's filters: the classifier's states, andon-coloured
# (docs/dashboard.md#live-overview).
STATES = tuple(s.value for s in State if s is not State.NO_RECORD)
CARD_DPRNT_CHARS = 120  # of the last DPRNT line on a card (the whole line is in its title)


@cache
def environment() -> Environment:
    """The Jinja environment of the templates folder (autoescaped HTML)."""
    env = Environment(
        loader=FileSystemLoader(HERE / "templates"),
        autoescape=select_autoescape(["html"]),
        trim_blocks=True,
        lstrip_blocks=True,
    )
    env.filters["size"] = human_size
    env.filters["when"] = when
    env.globals["KIND_LABEL"] = KIND_LABEL
    env.globals["percent"] = percent  # one rounding for the card and the queue table
    return env


def render(template: str, **context: Any) -> str:
    """Render ``template`` with ``context``."""
    return environment().get_template(template).render(**context)


def human_size(n: int | None) -> str:
    """``1234`` → ``1.2 kB``."""
    if n is None:
        return "?"
    if n < 1000:
        return f"{n} B"
    for unit in ("kB", "MB", "GB"):
        n_f = n / 1000
        if n_f < 1000 or unit == "GB":
            return f"{n_f:.1f} {unit}"
        n = int(n_f)
    return f"{n} B"  # pragma: no cover


def when(value: datetime | str | None) -> str:
    """A timestamp as ``YYYY-MM-DD HH:MM:SS`` UTC (what a shop's records use)."""
    if value is None or value == "":
        return ""
    if isinstance(value, str):
        value = datetime.fromisoformat(value)
    if value.tzinfo is not None:
        value = value.astimezone(UTC)
    return value.strftime("%Y-%m-%d %H:%M:%S")


# -- G-code -------------------------------------------------------------------------------

_FORMATTER = HtmlFormatter(nowrap=True)


def highlight_lines(text: str) -> list[Markup]:
    """``text`` highlighted as G-code, one safe HTML string per line."""
    if not text:
        return []
    # The formatter closes its spans at every line end, so the output splits into lines.
    html = highlight(text, GcodeLexer(stripnl=False, ensurenl=False), _FORMATTER)
    lines = html.split("\n")
    if lines and lines[-1] == "" and text.endswith("\n"):
        lines.pop()
    return [Markup(line) for line in lines]


@cache
def pygments_css() -> str:
    """Colours of the highlighted code (scoped to ``.code``)."""
    return str(HtmlFormatter(style="default").get_style_defs(".code"))  # type: ignore[no-untyped-call]


def language_of(name: str, data: bytes) -> str:
    """``klartext`` for a Heidenhain conversational program, else ``gcode`` (what the
    editor highlights; the checker's own guess)."""
    from opendnc.nccheck import Control, guess_control

    control = guess_control(data[:4096].decode("latin-1"), name)
    return "klartext" if control is Control.HEIDENHAIN else "gcode"


def program_text(data: bytes) -> str:
    """Program bytes as text: G-code is ASCII; latin-1 shows a stray byte instead of failing."""
    return data.decode("latin-1").replace("\r\n", "\n").replace("\r", "\n")


@dataclass(frozen=True)
class DiffRow:
    """One row of a side-by-side diff: ``tag`` is equal, replace, delete, insert or skip.

    A replace row's cells mark the words that changed (``wd-del``, ``wd-ins``); a skip row
    says how many unchanged lines it stands for (``skipped``)."""

    tag: str
    old_no: int | None
    old: Markup
    new_no: int | None
    new: Markup
    skipped: int = 0


# The words of an NC line a diff compares: a comment, a macro variable, an address with its
# value (G01, X-1.5, FMAX, Q12), a run of spaces, or a run of anything else.
_WORD = re.compile(r"\([^)]*\)?|;.*|#\[[^\]]*\]?|#\d+|[A-Za-z]+[-+]?[\d.]*|\s+|[^\sA-Za-z(;#]+")
WORD_DIFF_CHARS = 2000  # longer lines are marked whole (a word diff is quadratic)


def words(line: str) -> list[str]:
    """``line`` cut into the words a diff compares (joined again they give ``line``)."""
    return _WORD.findall(line)


def word_diff(old: str, new: str) -> tuple[Markup, Markup]:
    """The two lines with the words that differ marked: removed words in ``old`` as
    ``<span class="wd-del">``, added ones in ``new`` as ``<span class="wd-ins">``."""
    if len(old) > WORD_DIFF_CHARS or len(new) > WORD_DIFF_CHARS:
        return (
            Markup('<span class="wd-del">%s</span>') % old if old else Markup(""),
            Markup('<span class="wd-ins">%s</span>') % new if new else Markup(""),
        )
    a, b = words(old), words(new)
    left: list[str] = []
    right: list[str] = []
    matcher = difflib.SequenceMatcher(None, a, b, autojunk=False)
    for tag, i1, i2, j1, j2 in matcher.get_opcodes():
        gone, came = "".join(a[i1:i2]), "".join(b[j1:j2])
        if tag == "equal":
            left.append(escape(gone))
            right.append(escape(came))
            continue
        if gone:
            left.append(Markup('<span class="wd-del">%s</span>') % gone)
        if came:
            right.append(Markup('<span class="wd-ins">%s</span>') % came)
    return Markup("").join(left), Markup("").join(right)


def _skip(count: int) -> DiffRow:
    return DiffRow("skip", None, Markup(""), None, Markup(""), skipped=count)


def side_by_side(old: str, new: str, *, context: int = 3) -> list[DiffRow]:
    """Rows of a side-by-side diff of two programs: unchanged runs shortened to ``context``
    lines and a skip row saying how many were left out, changed words marked inside a
    replaced line (:func:`word_diff`). No rows when the two are the same."""
    a, b = old.splitlines(), new.splitlines()
    ha, hb = highlight_lines(old), highlight_lines(new)
    rows: list[DiffRow] = []
    matcher = difflib.SequenceMatcher(None, a, b, autojunk=False)
    groups = list(matcher.get_grouped_opcodes(context))
    if not groups:
        return []  # the same text
    shown_to = 0  # the old side's line after the last row shown
    for group in groups:
        if group[0][1] > shown_to:
            rows.append(_skip(group[0][1] - shown_to))
        for tag, i1, i2, j1, j2 in group:
            span = max(i2 - i1, j2 - j1)
            for k in range(span):
                i, j = i1 + k, j1 + k
                has_old, has_new = i < i2, j < j2
                row_tag = tag
                if tag == "replace" and not has_old:
                    row_tag = "insert"
                elif tag == "replace" and not has_new:
                    row_tag = "delete"
                old_html = ha[i] if has_old and i < len(ha) else Markup("")
                new_html = hb[j] if has_new and j < len(hb) else Markup("")
                if row_tag == "replace":
                    old_html, new_html = word_diff(a[i], b[j])
                rows.append(
                    DiffRow(
                        row_tag,
                        i + 1 if has_old else None,
                        old_html,
                        j + 1 if has_new else None,
                        new_html,
                    )
                )
        shown_to = group[-1][2]
    if shown_to < len(a):
        rows.append(_skip(len(a) - shown_to))
    return rows


# -- machine cards ------------------------------------------------------------------------


@dataclass(frozen=True)
class Card:
    """What a machine's card shows."""

    name: str
    kind: str
    description: str
    state: str  # one of STATES: the classifier's word, also the card's colour class
    online: bool
    mode: str
    native_mode: str  # the control's own word beside the MTConnect one (a Haas's MEM)
    execution: str
    program: str
    line: int
    job_id: int | None
    job_label: str
    percent: int | None
    done: int
    total: int | None
    queued: int
    last_error: str
    last_error_at: str
    alarm: str
    dprnt: str = ""  # the last line the program printed, whole
    dprnt_at: str = ""  # when the server captured it (UTC)

    @property
    def dprnt_shown(self) -> str:
        """The last DPRNT line as the card shows it (a long one cut, its end marked)."""
        if len(self.dprnt) <= CARD_DPRNT_CHARS:
            return self.dprnt
        return self.dprnt[: CARD_DPRNT_CHARS - 1] + "…"


def _words(value: str) -> str:
    # MTConnect words for people: MANUAL_DATA_INPUT -> manual data input.
    return value.replace("_", " ").lower()


def card(machine: dict[str, Any], *, queued: int = 0, job_label: str = "") -> Card:
    """The card of one machine from its live JSON (``MachineState.as_json()``), whose
    ``state`` is the classifier's: a job under way is not the machine running (a load into
    memory runs nothing), and a control that tells nothing is unknown, not ready."""
    status = machine.get("status") or {}
    job = machine.get("job")
    online = bool(machine.get("online"))
    errors = status.get("errors") or []
    execution = status.get("execution", "") if online else ""
    if execution == "UNAVAILABLE":
        execution = ""  # the control does not say: the state (unknown) tells it already
    alarm = "; ".join(errors)
    done, total = (job["bytes_done"], job["bytes_total"]) if job else (0, None)
    return Card(
        name=machine["name"],
        kind=machine["kind"],
        description=machine.get("description", ""),
        state=str(machine.get("state") or State.UNKNOWN.value),
        online=online,
        mode=_words(status.get("mode", "")) if online else "",
        native_mode=str(status.get("native_mode") or "") if online else "",
        execution=_words(execution),
        program=status.get("program", "") if online else "",
        line=int(status.get("line") or 0) if online else 0,
        job_id=job["id"] if job else None,
        job_label=job_label,
        percent=percent(done, total) if job else None,
        done=done,
        total=total,
        queued=queued,
        last_error=machine.get("last_error", ""),
        last_error_at=when(machine.get("last_error_at")),
        alarm=alarm,
        # A printed line is a fact of the past with its time: shown whether or not the
        # machine answers now.
        dprnt=str(status.get("dprnt") or ""),
        dprnt_at=when(status.get("dprnt_at")),
    )


def card_oob(name: str, html: str) -> str:
    """``html`` as the new inside of ``#card-<name>`` (an htmx out-of-band swap)."""
    return f'<div id="card-{escape(name)}" hx-swap-oob="innerHTML">{html}</div>'


def progress_text(c: Card) -> str:
    """The running job's progress as the card and the queue table both show it."""
    if c.job_id is None or c.percent is None:
        return ""
    return f" · {c.percent}%"


def queue_progress_oob(c: Card) -> str:
    """The machine page's queue table's progress of the running job, as the card has it (an
    out-of-band swap of ``#queue-progress-<name>``)."""
    return (
        f'<span id="queue-progress-{escape(c.name)}" hx-swap-oob="innerHTML">'
        f"{escape(progress_text(c))}</span>"
    )


def sse_event(name: str, html: str) -> bytes:
    """One server-sent event whose data is ``html`` (one ``data:`` line per line)."""
    data = "".join(f"data: {line}\n" for line in html.splitlines() or [""])
    return f"event: {name}\n{data}\n".encode()


def text_escape(value: object) -> Markup:
    """``value`` escaped for HTML."""
    return escape(str(value))
