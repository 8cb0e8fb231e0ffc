"""The machine page's DPRNT console updates: only new lines, and out-of-band deletes of the
lines that fell out of the newest ones the console keeps (so a page never grows without end
and never shows a line twice)."""

from __future__ import annotations

import re
from datetime import UTC, datetime, timedelta

from sqlalchemy.orm import Session, sessionmaker

from tests.peers import require_module

require_module("jinja2")

from opendnc.server.actions.dprnt import DprntLineOut  # noqa: E402
from opendnc.server.core.state import State  # noqa: E402
from opendnc.server.core.status import MachineStatus  # noqa: E402
from opendnc.server.machines.dprnt_capture import newest_lines  # noqa: E402
from opendnc.server.store.models import DprntLine  # noqa: E402
from opendnc.server.web import render  # noqa: E402
from opendnc.server.web.pages.live import CONSOLE_LINES, Console  # noqa: E402

T0 = datetime(2026, 1, 5, 8, 0, tzinfo=UTC)


def _print(sessions: sessionmaker[Session], machine: str, texts: list[str]) -> list[int]:
    with sessions.begin() as session:
        rows = [
            DprntLine(machine=machine, at=T0 + timedelta(seconds=i), text=t, fields=[])
            for i, t in enumerate(texts)
        ]
        session.add_all(rows)
        session.flush()
        return [r.id for r in rows]


def _newest(sessions: sessionmaker[Session], machine: str) -> list[DprntLineOut]:
    # what the console is given: the machine's newest lines, as the read action returns them
    with sessions() as session:
        found = newest_lines(session, machine, CONSOLE_LINES)
    return [DprntLineOut.model_validate(x) for x in found]


def _parts(html: str) -> tuple[list[int], list[int]]:
    added = [int(i) for i in re.findall(r'<li id="dprnt-(\d+)"><time', html)]
    gone = [int(i) for i in re.findall(r'<li id="dprnt-(\d+)" hx-swap-oob="delete">', html)]
    return added, gone


def test_new_lines_are_added_and_old_ones_deleted(sessions: sessionmaker[Session]) -> None:
    shown = _print(sessions, "vf2", ["A 1", "A 2", "A 3"])
    _print(sessions, "other", ["B 1"])  # another machine's line is not this console's
    console = Console("vf2", shown)
    assert console.update(_newest(sessions, "vf2")) == ""  # nothing new
    more = _print(sessions, "vf2", [f"C {i}" for i in range(CONSOLE_LINES)])
    added, gone = _parts(console.update(_newest(sessions, "vf2")))
    assert added == more  # all of them: each is among the newest
    assert gone == shown  # the page's three fell out
    last = _print(sessions, "vf2", ['<b>&"x"</b>'])
    html = console.update(_newest(sessions, "vf2"))
    added, gone = _parts(html)
    assert (added, gone) == (last, more[:1])
    assert "&lt;b&gt;&amp;&#34;x&#34;&lt;/b&gt;" in html  # a printed line is text, not markup
    assert len(console.shown) == CONSOLE_LINES


def test_a_card_shows_the_last_line_cut_and_whole_in_its_title() -> None:
    long = "PASS " + "1234567890" * 30  # longer than a card shows
    at = datetime(2026, 1, 5, 8, 0, tzinfo=UTC)
    status = MachineStatus(at, False, dprnt=long, dprnt_at=at)
    # a printed line is shown whether or not the machine answers now
    card = render.card(render.Seen("vf2", "haas_ngc", status, State.OFFLINE, online=False))
    template = render.environment().get_template("_card.html")
    html = template.render(c=card)
    shown = re.search(r'<dd class="dprnt" title="([^"]*)">([^<]*)</dd>', html)
    assert shown is not None, html
    assert shown[1] == f"{long} (printed 2026-01-05 08:00:00 UTC)"
    assert shown[2] == long[: render.CARD_DPRNT_CHARS - 1] + "…"
    # A machine's own page has the room: the whole line.
    whole = re.search(r'<dd class="dprnt"[^>]*>([^<]*)</dd>', template.render(c=card, whole=True))
    assert whole is not None
    assert whole[1] == long
