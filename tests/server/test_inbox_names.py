"""A punch without an O-number is named after the time it came, on the shop's clock: a UTC
stamp in a CET shop read as an hour off."""

from __future__ import annotations

import re
from datetime import UTC, datetime, timedelta
from pathlib import Path
from zoneinfo import ZoneInfo

from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.jobs import queue as jobs
from opendnc.server.kinds.haas_ngc import HaasNgcMachine
from opendnc.server.library import inbox
from tests.server.conftest import on

BERLIN = ZoneInfo("Europe/Berlin")


@on("sqlite")
def test_a_name_made_of_the_time_is_on_the_shops_clock(
    sessions: sessionmaker[Session], tmp_path: Path
) -> None:
    with sessions.begin() as session:
        jobs.sync_machines(session, [HaasNgcMachine(name="vf2", host="127.0.0.1")])
        before = datetime.now(UTC)
        row = inbox.store(session, "vf2", b"G01 X1.\n", folder=tmp_path, zone=BERLIN)
        after = datetime.now(UTC)
    found = re.fullmatch(r"vf2-(\d{8}-\d{6})\.nc", row.name)
    assert found, row.name
    named = datetime.strptime(found.group(1), "%Y%m%d-%H%M%S").replace(tzinfo=BERLIN)
    assert before - timedelta(seconds=1) <= named <= after
