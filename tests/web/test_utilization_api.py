"""``GET /api/utilization`` and the page's CSV over HTTP, against the timeline of
``utilization_shop`` (the figures there are worked out by hand)."""

from __future__ import annotations

import csv
import io
from collections.abc import Iterator
from datetime import datetime
from typing import Any

import pytest

from tests.peers import require_module

httpx = require_module("httpx")

from tests.web.utilization_shop import EXPECTED, UtilShop, serve_util_shop  # noqa: E402


@pytest.fixture(scope="module")
def shop(tmp_path_factory: pytest.TempPathFactory) -> Iterator[UtilShop]:
    with serve_util_shop(tmp_path_factory.mktemp("util-api")) as served:
        yield served


def _get(shop: UtilShop, **params: Any) -> httpx.Response:
    return httpx.get(
        shop.url + "/api/utilization",
        params=params,
        headers={"Authorization": f"Bearer {shop.key}"},
        timeout=30,
    )


def test_per_shift_json_with_local_offsets(shop: UtilShop) -> None:
    r = _get(shop, **{"from": "2026-01-05", "to": "2026-01-06", "group": "shift"})
    assert r.status_code == 200, r.text
    data = r.json()
    assert data["timezone"] == "Europe/Berlin"
    assert data["from"] == "2026-01-05T00:00:00+01:00"
    assert data["to"] == "2026-01-06T00:00:00+01:00"
    assert [p["key"] for p in data["periods"]] == [
        "2026-01-05 early",
        "2026-01-05 late",
        "2026-01-05 night",
    ]
    assert data["periods"][0]["start"] == "2026-01-05T06:00:00+01:00"
    machines = {m["machine"]: m for m in data["machines"]}
    assert list(machines) == ["mill-1", "vf2-long-name-1", "lathe-3"]
    for name, expected in EXPECTED.items():
        m = machines[name]
        early = m["periods"][0]
        assert early["utilization"] == pytest.approx(expected["early"], abs=0.01)
        assert m["totals"]["utilization"] == pytest.approx(expected["day"], abs=0.01)
        if expected["recorded"] is None:
            assert m["totals"]["utilization_recorded"] is None
        else:
            assert m["totals"]["utilization_recorded"] == pytest.approx(
                expected["recorded"], abs=0.01
            )
    mill = machines["mill-1"]
    assert mill["totals"]["seconds"]["running"] == 4.5 * 3600
    assert mill["totals"]["runs"] == 2
    assert mill["totals"]["parts"] is None
    assert mill["alarms"] == [
        {"text": "1010 SPINDLE OVERLOAD", "count": 1, "seconds": 1800.0, "longest_seconds": 1800.0}
    ]
    assert mill["stops"][0]["start"] == "2026-01-05T13:00:00+01:00"
    assert mill["stops"][0]["state"] == "offline"
    vf2 = machines["vf2-long-name-1"]
    assert vf2["totals"]["parts"] == 12
    assert vf2["totals"]["runs"] == 12
    assert vf2["totals"]["cycle_mean_seconds"] == 1200.0
    lathe = machines["lathe-3"]
    assert lathe["totals"]["seconds"]["no_record"] == 24 * 3600


def test_instants_with_offsets_and_one_machine(shop: UtilShop) -> None:
    r = _get(
        shop,
        **{"from": "2026-01-05T05:00:00Z", "to": "2026-01-05T13:00:00Z", "group": "day"},
        machines="mill-1",
    )
    assert r.status_code == 200, r.text
    data = r.json()
    assert data["from"] == "2026-01-05T06:00:00+01:00"
    (m,) = data["machines"]
    assert m["machine"] == "mill-1"
    assert m["totals"]["utilization"] == pytest.approx(56.25)  # exactly the early shift


def test_csv_has_a_row_per_period_and_a_total(shop: UtilShop) -> None:
    r = _get(shop, **{"from": "2026-01-05", "to": "2026-01-06", "group": "shift"}, format="csv")
    assert r.status_code == 200
    assert r.headers["content-type"].startswith("text/csv")
    assert "utilization-20260105-20260106.csv" in r.headers["content-disposition"]
    rows = list(csv.DictReader(io.StringIO(r.text)))
    mill = [row for row in rows if row["machine"] == "mill-1"]
    assert [row["period"] for row in mill] == [
        "2026-01-05 early",
        "2026-01-05 late",
        "2026-01-05 night",
        "total",
    ]
    early = mill[0]
    assert early["start"] == "2026-01-05T06:00:00+01:00"
    assert early["running_h"] == "4.500"
    assert early["utilization_pct"] == "56.25"
    assert mill[-1]["utilization_pct"] == "25.00"
    assert mill[-1]["utilization_recorded_pct"] == "50.00"


@pytest.mark.parametrize(
    ("params", "status", "words"),
    [
        ({"group": "month"}, 400, "group"),
        ({"machines": "nope"}, 404, "no machine named 'nope'"),
        ({"from": "2026-01-05T06:00:00"}, 400, "no utc offset"),
        ({"from": "yesterday"}, 400, "from"),
        ({"from": "2026-01-06", "to": "2026-01-05"}, 400, "after"),
        ({"from": "2024-01-01", "to": "2026-01-05"}, 400, "at most"),
        ({"format": "xml"}, 400, "format"),
    ],
)
def test_bad_parameters_are_refused_with_a_reason(
    shop: UtilShop, params: dict[str, str], status: int, words: str
) -> None:
    r = _get(shop, **params)
    assert r.status_code == status
    assert words in r.json()["detail"].lower()


def test_the_api_needs_a_key(shop: UtilShop) -> None:
    assert httpx.get(shop.url + "/api/utilization", timeout=30).status_code == 401


def test_the_default_span_is_the_last_seven_days(shop: UtilShop) -> None:
    r = _get(shop)
    assert r.status_code == 200
    data = r.json()
    start = datetime.fromisoformat(data["from"])
    end = datetime.fromisoformat(data["to"])
    assert (end.date() - start.date()).days == 7
    assert start.hour == end.hour == 0  # the shop's midnights
    assert len(data["periods"]) == 7


def test_the_page_csv_needs_a_login(shop: UtilShop) -> None:
    r = httpx.get(shop.url + "/utilization.csv", timeout=30, follow_redirects=False)
    assert r.status_code == 303
    assert r.headers["location"].startswith("/login")
