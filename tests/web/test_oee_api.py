"""OEE, parts and downtime reasons over HTTP, on both databases (the new tables are the
subject): a supervisor sets a standard time, an operator reports parts and picks the reason
for stops, and ``/api/utilization`` (JSON and CSV) shows OEE, the Pareto and the lost time
per reason. The timeline is :mod:`tests.web.utilization_shop`'s; every expected figure below
is worked out by hand from it and from the formulas in docs/dashboard.md#oee."""

from __future__ import annotations

import csv
import io
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import select

from tests.peers import require_module

httpx = require_module("httpx")

from opendnc.server.access import auth  # noqa: E402
from opendnc.server.app import build  # noqa: E402
from opendnc.server.config.shop import parse_config  # noqa: E402
from opendnc.server.library import versions as library  # noqa: E402
from opendnc.server.store.models import AuditEntry, Role  # noqa: E402
from tests.server.serving import serving  # noqa: E402
from tests.web.utilization_shop import CONFIG, local, write_timeline  # noqa: E402

SHIFT = {"from": "2026-01-05", "to": "2026-01-06", "group": "shift"}


@contextmanager
def _served(db_url: str, tmp_path: Path) -> Iterator[tuple[str, dict[str, str], Any]]:
    server = build(parse_config(CONFIG, base=tmp_path), database=db_url)
    keys: dict[str, str] = {}
    with server.sessions.begin() as session:
        for name, role in (("viewer", Role.VIEWER), ("op", Role.OPERATOR), ("boss", Role.APPROVER)):
            _row, keys[name] = auth.create_key(session, name, role, create_user_role=role)
        library.add_version(session, "O1000", b"%\nO1000\nG0 X0\nM30\n%\n", author="test")
    write_timeline(server.sessions)
    try:
        with serving(server) as url:
            yield url, keys, server
    finally:
        server.engine.dispose()


def _call(url: str, key: str, method: str, path: str, **kw: Any) -> httpx.Response:
    headers = {"Authorization": f"Bearer {key}"}
    return httpx.request(method, url + path, headers=headers, timeout=30, **kw)


def test_oee_parts_and_reasons_through_the_api(db_url: str, tmp_path: Path) -> None:
    with _served(db_url, tmp_path) as (url, keys, server):
        # roles: a viewer sets nothing, an operator no standard
        std = {"seconds": 900}
        path = "/api/programs/O1000/versions/1/standard"
        assert _call(url, keys["viewer"], "PUT", path, json=std).status_code == 403
        assert _call(url, keys["op"], "PUT", path, json=std).status_code == 403
        r = _call(url, keys["boss"], "PUT", path, json=std)
        assert r.status_code == 200, r.text
        parts = {"good": 10, "scrap": 2, "at": local(11).isoformat()}
        assert _call(url, keys["viewer"], "POST", "/api/machines/vf2-long-name-1/parts",
                     json=parts).status_code == 403  # fmt: skip
        r = _call(url, keys["op"], "POST", "/api/machines/vf2-long-name-1/parts", json=parts)
        assert r.status_code == 201, r.text
        for at, reason in ((local(9), "tool change"), (local(6), "Material")):
            body = {"start": at.isoformat(), "reason": reason}
            r = _call(url, keys["op"], "POST", "/api/machines/mill-1/downtime", json=body)
            assert r.status_code == 200, r.text
        bad = {"start": local(9).isoformat(), "reason": "lunch"}
        r = _call(url, keys["op"], "POST", "/api/machines/mill-1/downtime", json=bad)
        assert r.status_code == 400
        assert "no operator" in r.text

        r = _call(url, keys["viewer"], "GET", "/api/utilization", params=SHIFT)
        assert r.status_code == 200, r.text
        data = r.json()
        vf2 = next(m for m in data["machines"] if m["machine"] == "vf2-long-name-1")
        early = vf2["periods"][0]["oee"]
        # early shift 06-14 = 28 800 s planned, 4 h running: A = 0.5; 12 runs of O1000 at a
        # standard of 900 s took 12 x 1200 s: P = 10 800 / 14 400 = 0.75; 10 good + 2 scrap
        # reported: Q = 10 / 12; OEE = 0.5 x 0.75 x 10/12 = 0.3125; goal 28 800 / 900 = 32
        assert early["availability"] == 50.0
        assert early["performance"] == 75.0
        assert early["quality"] == pytest.approx(83.33)
        assert early["oee"] == pytest.approx(31.25)
        assert (early["parts_made"], early["parts_good"], early["parts_scrap"]) == (12, 10, 2)
        assert early["parts_goal"] == 32
        # Monday's shifts 06-24 = 18 h: A = 4/18, goal 64 800 / 900 = 72
        total = vf2["oee"]
        assert total["availability"] == pytest.approx(400 / 18, abs=0.01)
        assert total["oee"] == pytest.approx(4 / 18 * 0.75 * 10 / 12 * 100, abs=0.01)
        assert total["parts_goal"] == 72
        assert {"program": "O1000", "version_id": 1, "version": 1, "seconds": 900.0,
                "source": "set"} in data["standards"]  # fmt: skip
        mill = next(m for m in data["machines"] if m["machine"] == "mill-1")
        # mill-1 (no counter) ran O1000 twice, back to ready at 09:00 and 13:00: 7 200 s and
        # 9 000 s running (the feed hold does not count); P = 2 x 900 / 16 200
        assert mill["oee"]["performance"] == pytest.approx(100 * 1800 / 16200, abs=0.01)
        reasons = {d["start"]: d["reason"] for d in mill["downtime"]}
        # mill-1's stops: 06-07 ready, 09-10 ready then alarm, 12-12:30 feed hold,
        # 13-15 ready then offline (ended by the server's stop)
        assert reasons == {
            "2026-01-05T06:00:00+01:00": "material",
            "2026-01-05T09:00:00+01:00": "tool change",
            "2026-01-05T12:00:00+01:00": None,
            "2026-01-05T13:00:00+01:00": None,
        }
        assert mill["lost_seconds"]["tool change"] == 3600.0

        only_mill = {**SHIFT, "machines": "mill-1"}
        pareto = _call(url, keys["viewer"], "GET", "/api/utilization", params=only_mill).json()
        assert [(p["reason"], p["seconds"], p["cumulative"]) for p in pareto["pareto"]] == [
            ("material", 3600.0, pytest.approx(22.22)),
            ("tool change", 3600.0, pytest.approx(44.44)),
            ("no reason given", 9000.0, 100.0),
        ]
        r = _call(url, keys["viewer"], "GET", "/api/utilization",
                  params={**only_mill, "format": "csv"})  # fmt: skip
        rows = {row["period"]: row for row in csv.DictReader(io.StringIO(r.text))}
        assert rows["2026-01-05 early"]["lost_h:tool change"] == "1.000"
        assert rows["2026-01-05 early"]["lost_h:no reason given"] == "2.500"
        assert rows["total"]["stops_h"] == "4.500"

        with server.sessions() as session:
            audited = session.scalars(
                select(AuditEntry.action).where(AuditEntry.actor.in_(["op", "boss"]))
            ).all()
        assert sorted(audited) == [
            "downtime.reason", "downtime.reason", "parts.report", "standard.set"
        ]  # fmt: skip
