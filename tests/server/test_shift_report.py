"""The shift report of a finished shift: its longest stops with their reasons and its
alarms, the same utilization and OEE as the utilization page shows for that shift (one
function renders both), mailed through a real local SMTP server with the CSV attached.
The timeline is :mod:`tests.web.utilization_shop`'s; expected values are read off it."""

from __future__ import annotations

import csv
import io
import re
from datetime import date, datetime
from pathlib import Path

import pytest
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.config.alerts import EmailTarget
from opendnc.server.config.shop import parse_config
from opendnc.server.reports.mail import ShiftMailer, message_of
from opendnc.server.reports.render import mail_html
from opendnc.server.reports.shift import build, last_finished, shift_period
from opendnc.server.store.models import AuditEntry, DowntimeReason
from tests.server.alerts_support import smtp_server
from tests.server.conftest import on
from tests.web.utilization_shop import CONFIG, local, write_timeline

AFTER = local(23)  # "now": the early shift (06-14) of Monday 2026-01-05 is over


@on("sqlite")
def test_a_finished_shift_with_its_stops_reasons_and_alarms(
    sessions: sessionmaker[Session], tmp_path: Path
) -> None:
    config = parse_config(CONFIG, base=tmp_path)
    write_timeline(sessions)
    with sessions.begin() as session:
        session.add(DowntimeReason(machine="mill-1", start=local(13), reason="setup", by="op"))
    period = shift_period(config, date(2026, 1, 5), "early")
    assert (period.start, period.end) == (local(6), local(14))
    assert last_finished(config, AFTER).key == "2026-01-05 late"  # 14-22 ended at 22:00
    sr = build(sessions, config, period, AFTER)
    assert sr.finished
    # the longest stops of the shift, all machines: mill-1 06-07, 09-10 and 13:00-15:00 cut
    # at the shift's end are an hour each (the earliest first), then the feed hold 12-12:30
    longest = [(s.machine, s.stop.start, s.seconds, s.reason) for s in sr.stops[:4]]
    assert longest == [
        ("mill-1", local(6), 3600.0, ""),
        ("mill-1", local(9), 3600.0, ""),
        ("mill-1", local(13), 3600.0, "setup"),
        ("mill-1", local(12), 1800.0, ""),
    ]
    assert [(m, a.text, a.count, a.seconds) for m, a in sr.alarms] == [
        ("mill-1", "1010 SPINDLE OVERLOAD", 1, 1800.0)
    ]
    html = mail_html(sr, "shop-1")
    assert "1010 SPINDLE OVERLOAD" in html
    assert re.search(r'data-util="mill-1">56.3 %', html)  # 4.5 h of 8 h
    rows = {r["machine"]: r for r in csv.DictReader(io.StringIO(sr.csv)) if r["period"] == "total"}
    assert rows["mill-1"]["utilization_pct"] == "56.25"
    assert rows["mill-1"]["lost_h:setup"] == "1.000"

    with smtp_server() as peer:
        target = EmailTarget(host="127.0.0.1", port=peer.port, sender="dnc@shop.test",
                             to=("boss@shop.test",), timeout=5.0)  # fmt: skip
        mailer = ShiftMailer(sessions, config, target)
        assert mailer.send(period, AFTER)
        (mail,) = peer.taken()
    assert mail.subject == "[opendnc] Shift report on opendnc: early of Mon 05 Jan 2026"
    html_part = mail.message.get_body(("html",))
    assert html_part is not None
    assert "SPINDLE OVERLOAD" in str(html_part.get_content())
    (attached,) = list(mail.message.iter_attachments())
    assert attached.get_filename() == "shift-20260105-early.csv"
    assert "lost_h:setup" in str(attached.get_content())
    with sessions() as session:
        (row,) = session.query(AuditEntry).filter(AuditEntry.action == "report.shift").all()
    assert (row.result, row.detail["shift"]) == ("ok", "2026-01-05 early")
    # the message itself is what the mailer sends
    assert message_of(sr, target)["To"] == "boss@shop.test"


@on("sqlite")
def test_the_shift_report_and_the_utilization_page_agree(
    sessions: sessionmaker[Session], tmp_path: Path
) -> None:
    """One state, two pages: the utilization and OEE of a shift read the same on both."""
    from opendnc.server.utilization.answer import full_report
    from opendnc.server.utilization.collect import Group
    from opendnc.server.web import render
    from opendnc.server.web.pages.utilization import percent_text

    config = parse_config(CONFIG, base=tmp_path)
    write_timeline(sessions)
    period = shift_period(config, date(2026, 1, 5), "early")
    sr = build(sessions, config, period, AFTER)
    names = [m.name for m in config.machines]
    r = full_report(sessions, config, names, period.start, period.end, Group.SHIFT, AFTER)
    page = render.render(
        "utilization.html", page=None, path="/utilization", roles=[], report=r, floor=r.floor,
        zone="", zone_name="", zone_label="", first="", last="", group="shift", query="",
        rows=[], shown_pct=100, ticks=[], bars={}, states=[], percent=percent_text,
        duration=lambda s: "", clock=lambda at: "", shifts=config.calendar.shifts,
        span_label="", stops=[], alarms=[], reason_of=lambda m, s: "",
        fraction=lambda v: percent_text(None if v is None else 100.0 * v),
    )  # fmt: skip
    report = mail_html(sr)
    for name in names:
        for key in ("util", "oee", "parts"):
            mark = f'data-{key}="{name}">'
            on_page = page.split(mark, 1)[1].split("<", 1)[0]
            on_report = report.split(mark, 1)[1].split("<", 1)[0]
            assert on_page == on_report, (name, key)
    assert datetime.fromisoformat("2026-01-05T06:00:00+01:00") == period.start
    with pytest.raises(Exception, match="no shift 'noon'"):
        shift_period(config, date(2026, 1, 5), "noon")
