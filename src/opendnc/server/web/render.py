"""Presentation helpers for the pages: templates, G-code highlighting, diffs, machine cards.

Nothing here touches the database or a machine: the views fetch through the service modules
and hand plain values to these functions.
"""

from __future__ import annotations

import difflib
import re
from dataclasses import dataclass, replace
from datetime import UTC, datetime, timedelta, tzinfo
from functools import cache
from pathlib import Path
from typing import Any

from jinja2 import Environment, FileSystemLoader, pass_context, select_autoescape
from jinja2.runtime import Context
from markupsafe import Markup, escape
from pygments import highlight
from pygments.formatters import HtmlFormatter
from pygments.lexers import GcodeLexer

from opendnc.server.actions.machines import LastJob
from opendnc.server.core.events import percent
from opendnc.server.core.state import State, classify
from opendnc.server.core.status import MachineStatus
from opendnc.server.kinds.registry import label_of
from opendnc.server.machines.state import MachineState

__all__ = [
    "Card",
    "DiffRow",
    "LastJob",
    "RunningJob",
    "Seen",
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
    env.filters["when"] = _when_filter
    env.filters["stamp"] = _stamp_filter
    env.filters["path"] = breakable_path
    env.filters["clock"] = _clock_filter
    env.globals["kind_label"] = label_of  # each kind names itself (its spec's label)
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


def _aware(value: datetime | str | None) -> datetime | None:
    if value is None or value == "":
        return None
    if isinstance(value, str):
        value = datetime.fromisoformat(value)
    return value if value.tzinfo is not None else value.replace(tzinfo=UTC)  # stored as UTC


def when(value: datetime | str | None, zone: tzinfo = UTC) -> str:
    """A timestamp on the shop's clock with its zone: ``2026-03-02 14:02:31 CET``."""
    at = _aware(value)
    if at is None:
        return ""
    return at.astimezone(zone).strftime("%Y-%m-%d %H:%M:%S %Z")


def zone_label(at: datetime | None = None, zone: tzinfo = UTC) -> str:
    """The shop's zone as its clock times name it at ``at`` (now by default): ``CET``,
    ``CEST``; the one label every page, card and clock shows."""
    return (at or datetime.now(UTC)).astimezone(zone).strftime("%Z")


def iso(value: datetime | str | None, zone: tzinfo = UTC) -> str:
    """A timestamp as ISO 8601 with the shop's offset: ``2026-03-02T14:02:31+01:00``."""
    at = _aware(value)
    return at.astimezone(zone).isoformat(timespec="seconds") if at is not None else ""


def clock(value: datetime | str | None, zone: tzinfo = UTC, now: datetime | None = None) -> str:
    """A time as people on the floor read it: ``14:02 CET`` today, with the date otherwise."""
    at = _aware(value)
    if at is None:
        return ""
    local = at.astimezone(zone)
    today = (now or datetime.now(UTC)).astimezone(zone).date()
    if local.date() == today:
        return local.strftime("%H:%M %Z")
    return local.strftime("%Y-%m-%d %H:%M %Z")


def stamp(value: datetime | str | None, zone: tzinfo = UTC, *, with_zone: bool = True) -> Markup:
    """A ``<time>`` element: the local time (with its zone unless the page names it once),
    ISO with the offset in its title and ``datetime``."""
    at = _aware(value)
    if at is None:
        return Markup("")
    full = iso(at, zone)
    text = when(at, zone) if with_zone else at.astimezone(zone).strftime("%Y-%m-%d %H:%M:%S")
    day, _, hour = text.partition(" ")
    # two unbreakable halves: a narrow column wraps between the date and the time, not inside
    return Markup(
        '<time class="stamp" datetime="{0}" title="{0}"><span>{1}</span> <span>{2}</span></time>'
    ).format(full, day, hour)


def breakable_path(value: str) -> Markup:
    """A control's path that may wrap after each folder (``TNC:/nc_prog/<wbr>POCKET.H``),
    never inside a name."""
    text = str(escape(value))
    return Markup(text.replace("/", "/<wbr>").replace("\\", "\\<wbr>"))


def _zone(ctx: Context) -> tzinfo:
    zone = ctx.get("zone")
    return zone if isinstance(zone, tzinfo) else UTC


@pass_context
def _when_filter(ctx: Context, value: datetime | str | None) -> str:
    return when(value, _zone(ctx))


@pass_context
def _clock_filter(ctx: Context, value: datetime | str | None) -> str:
    return clock(value, _zone(ctx))


@pass_context
def _stamp_filter(ctx: Context, value: datetime | str | None, with_zone: bool = True) -> Markup:
    return stamp(value, _zone(ctx), with_zone=with_zone)


@dataclass(frozen=True)
class Tick:
    """A time on a strip's axis: ``left`` percent from the strip's start."""

    left: float
    label: str
    iso: str


def axis_ticks(start: datetime, end: datetime, zone: tzinfo = UTC, *, hours: int = 1) -> list[Tick]:
    """The axis of a strip from ``start`` to ``end``: both ends (the last with the zone) and
    each full ``hours`` on the shop's clock between them, those too near an end left out."""
    span = (end - start).total_seconds()
    local_start = start.astimezone(zone)
    ticks = [Tick(0.0, local_start.strftime("%H:%M"), iso(start, zone))]
    # the first full hour after the start, in the shop's zone (a DST change shifts the hours)
    hour = local_start.replace(minute=0, second=0, microsecond=0)
    step = timedelta(hours=hours)
    at = hour.astimezone(UTC) + step
    while at < end:
        left = (at - start).total_seconds() / span * 100
        if 6 < left < 84:  # clear of the end labels (the last one carries the zone)
            ticks.append(Tick(round(left, 2), at.astimezone(zone).strftime("%H:%M"), iso(at, zone)))
        at += step
    ticks.append(Tick(100.0, end.astimezone(zone).strftime("%H:%M %Z"), iso(end, zone)))
    return ticks


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
    """What a machine's card shows (times already on the shop's clock, with their zone)."""

    name: str
    kind: str
    description: str
    state: State  # one of STATES: the classifier's word, also the card's colour class
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
    dprnt_at: str = ""  # when the server captured it (the shop's clock)
    # The last reading, to the minute: a card changes once a minute, not at every poll.
    updated: str = ""  # "14:02 CET"
    updated_iso: str = ""  # "2026-03-02T14:02:00+01:00"
    since: str = ""  # when the machine entered its state
    since_iso: str = ""
    rate: str = ""  # of the running job: "12.3 kB/s"
    left: str = ""  # of the running job: "about 2 min left"
    feed_line: int | None = None  # a drip-feed's line reached
    feed_lines: int | None = None  # ... of its lines
    parts: int | None = None  # the control's part counter (a Haas's MDC)
    tool: int | None = None  # the tool in the spindle
    overrides: str = ""  # "feed 100 %, spindle 90 %"
    last_job: LastJob | None = None
    last_job_at: str = ""  # when it ended, on the shop's clock
    last_job_iso: str = ""

    @property
    def dprnt_shown(self) -> str:
        """The last DPRNT line as the card shows it (a long one cut, its end marked)."""
        if len(self.dprnt) <= CARD_DPRNT_CHARS:
            return self.dprnt
        return self.dprnt[: CARD_DPRNT_CHARS - 1] + "…"


def _words(value: str) -> str:
    # MTConnect words for people: MANUAL_DATA_INPUT -> manual data input.
    return value.replace("_", " ").lower()


# The control's execution words that say no more than the state they make: "Running (active)"
# and "Alarm (stopped)" read as jargon, or as a contradiction.
_SAID_BY_STATE: dict[State, frozenset[str]] = {
    State.RUNNING: frozenset({"ACTIVE"}),
    State.READY: frozenset({"READY", "WAIT"}),
    State.STOPPED: frozenset({"STOPPED", "PROGRAM_STOPPED"}),
}


def state_detail(state: State, execution: str) -> str:
    """What the control's execution word adds to the state, in plain words (``"feed hold"``
    for a stopped machine, ``"program completed"`` for a ready one), or nothing: an alarm is
    said by its text, a running machine by its program."""
    if not execution or state in (State.ALARM, State.OFFLINE, State.UNKNOWN):
        return ""
    if execution in _SAID_BY_STATE.get(state, frozenset()):
        return ""
    return _words(execution)


def duration(seconds: float) -> str:
    """``75`` → ``1 min 15 s``; ``7300`` → ``2 h 1 min`` (two units at most)."""
    s = max(0, round(seconds))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60} s" if s % 60 and s < 600 else f"{s // 60} min"
    return f"{s // 3600} h {s % 3600 // 60} min"


PACE_AFTER = 2.0  # seconds of bytes flowing before a rate and a time left are said


def job_pace(
    done: int,
    total: int | None,
    started: datetime | None,
    now: datetime,
    flowing: tuple[datetime, int] | None = None,
) -> tuple[str, str]:
    """A running job's rate and time left (``"12.3 kB/s"``, ``"about 2 min left"``), from
    the bytes done since they began to flow (``flowing``: when the server first saw them
    move, and how many there were; without it, since the job started), once they have
    flowed :data:`PACE_AFTER` seconds; empty while too little is known to say. The wait for
    a control before its first byte (a Haas's NAK, a TNC's login) is no part of the rate."""
    since, base = flowing if flowing is not None else (started, 0)
    if since is None or done <= base:
        return "", ""
    elapsed = (now - since).total_seconds()
    if elapsed < (PACE_AFTER if flowing is not None else 1):
        return "", ""
    rate = (done - base) / elapsed
    left = ""
    if total and total > done:
        left = f"about {duration((total - done) / rate)} left"
    return f"{human_size(round(rate))}/s", left


def _overrides(values: dict[str, float] | None) -> str:
    if not values:
        return ""
    # a no-break space: "100 %" never splits at a line end
    return ", ".join(f"{k} {round(v)}\u00a0%" for k, v in values.items())


@dataclass(frozen=True)
class RunningJob:
    """The job a machine runs now, as its card tells it: its bytes of the program as stored,
    when it started and when its bytes began to flow (its rate), a drip-feed's line."""

    job_id: int
    label: str = ""  # "send O1000.nc v2"
    done: int = 0
    total: int | None = None
    started: datetime | None = None
    flowing: tuple[datetime, int] | None = None  # when the bytes began to move, and how many
    line: tuple[int, int] | None = None  # a drip-feed's line reached, of its lines


@dataclass(frozen=True)
class Seen:
    """What the server knows of one machine that its card shows: the status the classifier
    read and the state it made of it, and the server's own words about the link."""

    name: str
    kind: str
    status: MachineStatus | None
    state: State
    online: bool
    description: str = ""
    since: datetime | None = None  # when the machine entered ``state``
    last_error: str = ""
    last_error_at: datetime | None = None
    job: RunningJob | None = None

    @classmethod
    def of(cls, machine: MachineState, job_label: str = "") -> Seen:
        """A machine's live state as its card reads it (the status the one classifier
        reads, and the state it makes of it)."""
        reading = machine.reading()
        job = None
        if machine.job_id is not None:
            done, total = machine.job_progress
            job = RunningJob(
                machine.job_id,
                job_label,
                done,
                total,
                machine.job_started,
                machine.flowing(),
                machine.job_line,
            )
        return cls(
            machine.config.name,
            machine.config.kind,
            reading,
            classify(reading, online=machine.online),
            machine.online,
            machine.config.description,
            machine.state_since,
            machine.last_error,
            machine.last_error_at,
            job,
        )


@dataclass(frozen=True)
class _Control:
    """What a card says the control reports now (nothing of it while the link is down)."""

    mode: str = ""
    native_mode: str = ""
    execution: str = ""  # the control's word where it adds to the state
    program: str = ""
    line: int = 0
    parts: int | None = None
    tool: int | None = None
    overrides: str = ""


def _control(seen: Seen) -> _Control:
    status = seen.status
    if status is None or not seen.online:
        return _Control()
    execution = "" if status.execution == "UNAVAILABLE" else status.execution
    said = _Control(
        mode=_words(status.mode),
        native_mode=status.native_mode,
        execution=state_detail(seen.state, execution),
        program=status.program,
        line=status.line,
    )
    if not status.available:
        return said  # a control that does not answer reports no counter, tool or override
    return replace(
        said,
        parts=status.part_count,
        tool=status.tool or None,
        overrides=_overrides(status.overrides),
    )


@dataclass(frozen=True)
class _Transfer:
    """What a card says of the running job."""

    job_id: int | None = None
    label: str = ""
    percent: int | None = None
    done: int = 0
    total: int | None = None
    rate: str = ""
    left: str = ""
    feed_line: int | None = None
    feed_lines: int | None = None


def _transfer(job: RunningJob | None, label: str, now: datetime) -> _Transfer:
    if job is None:
        return _Transfer(label=label)
    rate, left = job_pace(job.done, job.total, job.started, now, job.flowing)
    feed_line, feed_lines = job.line if job.line is not None else (None, None)
    return _Transfer(
        job.job_id,
        job.label or label,
        percent(job.done, job.total),
        job.done,
        job.total,
        rate,
        left,
        feed_line,
        feed_lines,
    )


def card(
    seen: Seen,
    *,
    queued: int = 0,
    job_label: str = "",
    last_job: LastJob | None = None,
    zone: tzinfo = UTC,
    now: datetime | None = None,
) -> Card:
    """The card of one machine from what the server knows of it (:class:`Seen`), whose
    ``state`` is the classifier's: a job under way is not the machine running (a load into
    memory runs nothing), and a control that tells nothing is unknown, not ready. Times are
    shown on ``zone``'s clock."""
    now = now or datetime.now(UTC)
    status = seen.status
    control = _control(seen)
    job = _transfer(seen.job, job_label, now)
    # the last reading, to the minute: a card changes once a minute, not at every poll
    minute = status.at.replace(second=0, microsecond=0) if status is not None else None
    finished = last_job.finished if last_job is not None else None
    return Card(
        name=seen.name,
        kind=seen.kind,
        description=seen.description,
        state=seen.state,
        online=seen.online,
        mode=control.mode,
        native_mode=control.native_mode,
        execution=control.execution,
        program=control.program,
        line=control.line,
        job_id=job.job_id,
        job_label=job.label,
        percent=job.percent,
        done=job.done,
        total=job.total,
        queued=queued,
        last_error=seen.last_error,
        last_error_at=when(seen.last_error_at, zone),
        alarm="; ".join(status.errors) if status is not None else "",
        # A printed line is a fact of the past with its time: shown whether or not the
        # machine answers now.
        dprnt=status.dprnt if status is not None else "",
        dprnt_at=when(status.dprnt_at, zone) if status is not None else "",
        updated=clock(minute, zone, now),
        updated_iso=iso(minute, zone),
        since=clock(seen.since, zone, now),
        since_iso=iso(seen.since, zone),
        rate=job.rate,
        left=job.left,
        feed_line=job.feed_line,
        feed_lines=job.feed_lines,
        parts=control.parts,
        tool=control.tool,
        overrides=control.overrides,
        last_job=last_job,
        last_job_at=clock(finished, zone, now),
        last_job_iso=iso(finished, zone),
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
