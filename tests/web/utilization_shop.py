"""A served shop whose status timeline the test writes: the utilization pages and API read it.

The machines point at a loopback port nobody listens on (the server sees them offline now,
which touches only the present); their past is the samples written here, in the shop's zone
Europe/Berlin with three shifts. The expected figures in the tests are worked out by hand from
this timeline (see :data:`EXPECTED`), not read back from the code.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any
from zoneinfo import ZoneInfo

from tests.peers import require_module

require_module("jinja2")
uvicorn = require_module("uvicorn")

from opendnc.server.access import auth  # noqa: E402
from opendnc.server.app import build  # noqa: E402
from opendnc.server.config.shop import parse_config  # noqa: E402
from opendnc.server.store.models import Role, StatusSample  # noqa: E402
from tests.server.serving import serving  # noqa: E402

BERLIN = ZoneInfo("Europe/Berlin")
DAY = (2026, 1, 5)  # a Monday in winter (UTC+1)


def local(hour: int, minute: int = 0, day: tuple[int, int, int] = DAY) -> datetime:
    """A wall-clock time in Berlin."""
    return datetime(*day, hour, minute, tzinfo=BERLIN)


# (machine, local time, stored state, execution, part count, alarm text)
TIMELINE: list[tuple[str, datetime, str, str, int | None, str]] = [
    # mill-1 (a TNC: no part counter). Early shift 06:00-14:00 = 8 h:
    # running 07-09, 10-12, 12:30-13 = 4.5 h -> 56.25 %; a 30 min alarm at 09:30.
    ("mill-1", local(6), "ready", "READY", None, ""),
    ("mill-1", local(7), "running", "ACTIVE", None, ""),
    ("mill-1", local(9), "ready", "READY", None, ""),
    ("mill-1", local(9, 30), "alarm", "READY", None, "1010 SPINDLE OVERLOAD"),
    ("mill-1", local(10), "running", "ACTIVE", None, ""),
    ("mill-1", local(12), "stopped", "FEED_HOLD", None, ""),
    ("mill-1", local(12, 30), "running", "ACTIVE", None, ""),
    ("mill-1", local(13), "ready", "READY", None, ""),
    ("mill-1", local(14), "offline", "", None, ""),
    ("mill-1", local(15), "none", "", None, ""),
    # vf2-long-name-1 (a Haas: part counter). Runs 06:00-12:00 in 20 min cycles with
    # 10 min between: 12 cycles of 20 min = 4 h running in the early shift -> 50 %;
    # 12 parts; written in the old vocabulary ("active").
    *[
        row
        for k in range(12)
        for row in (
            ("vf2-long-name-1", local(6 + k // 2, 30 * (k % 2)), "active", "ACTIVE", 100 + k, ""),
            (
                "vf2-long-name-1",
                local(6 + k // 2, 30 * (k % 2) + 20),
                "ready",
                "READY",
                101 + k,
                "",
            ),
        )
    ],
    ("vf2-long-name-1", local(12), "none", "", None, ""),
]

EXPECTED = {
    # machine: (utilization over the early shift, over the day's shifts, over recorded time)
    # Monday's shift time is 06:00-24:00 (the night shift from Sunday is not worked): 18 h.
    "mill-1": {"early": 56.25, "day": 25.0, "recorded": 50.0},  # 4.5 h of 18 h; of 9 h
    "vf2-long-name-1": {"early": 50.0, "day": 4.0 / 18 * 100, "recorded": 4.0 / 6 * 100},
    "lathe-3": {"early": 0.0, "day": 0.0, "recorded": None},
}

CONFIG = """
[server]
bind = "127.0.0.1:0"
timezone = "Europe/Berlin"
timeline_retention_days = 3660

[library]
path = "lib"

[[shifts]]
name = "early"
days = ["mon-fri"]
start = "06:00"
end = "14:00"

[[shifts]]
name = "late"
days = ["mon-fri"]
start = "14:00"
end = "22:00"

[[shifts]]
name = "night"
days = ["mon-fri"]
start = "22:00"
end = "06:00"

[[machines]]
name = "mill-1"
kind = "lsv2"
host = "127.0.0.1"
port = 1

[[machines]]
name = "vf2-long-name-1"
kind = "haas_ngc"
host = "127.0.0.1"
mdc_port = 1

[[machines]]
name = "lathe-3"
kind = "lsv2"
host = "127.0.0.1"
port = 1
"""


def write_timeline(sessions: Any) -> None:
    """Store :data:`TIMELINE` as status samples."""
    with sessions.begin() as session:
        session.add_all(
            StatusSample(
                machine=m,
                at=at,
                state=state,
                mode="AUTOMATIC" if state in ("running", "active") else "",
                execution=execution,
                program="O1000",
                part_count=count,
                alarm=alarm,
            )
            for m, at, state, execution, count, alarm in TIMELINE
        )


@dataclass
class UtilShop:
    """The served shop: its URL, the server, and an API key of a viewer."""

    url: str
    server: Any
    key: str


@contextmanager
def serve_util_shop(tmp_path: Path, password: str = "viewer-secret-1") -> Iterator[UtilShop]:
    """Serve the shop with :data:`TIMELINE` written; ``viewer`` logs in with ``password``."""
    database = tmp_path / "db.sqlite"
    server = build(parse_config(CONFIG, base=tmp_path), database=f"sqlite:///{database}")
    with server.sessions.begin() as session:
        auth.create_user(session, "viewer", Role.VIEWER, password=password)
        _row, key = auth.create_key(session, "viewer", Role.VIEWER, label="utilization test")
    write_timeline(server.sessions)
    with serving(server) as url:
        yield UtilShop(url, server, key)
