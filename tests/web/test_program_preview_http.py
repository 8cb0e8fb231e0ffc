"""The preview's routes over HTTP without a browser: the toolpath binary through the API and
the page session, the facts fragment, and the program text's server-side window."""

from __future__ import annotations

import math
import re
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.peers import require_module

httpx = require_module("httpx")

from opendnc.nccheck.backplot import decode  # noqa: E402
from tests.server.harness import wait_for  # noqa: E402
from tests.server.logins import log_in  # noqa: E402
from tests.web.browser import PASSWORDS  # noqa: E402
from tests.web.preview_shop import PreviewShop, preview_shop  # noqa: E402


@pytest.fixture(scope="module")
def shop(tmp_path_factory: pytest.TempPathFactory) -> Iterator[PreviewShop]:
    with preview_shop(tmp_path_factory.mktemp("preview-http")) as served:
        yield served


@pytest.fixture
def http(shop: PreviewShop) -> Iterator[Any]:
    with httpx.Client(base_url=shop.url, timeout=120) as client:
        yield client


def _login(http: Any, user: str = "viewer") -> None:
    reply = log_in(http, user, PASSWORDS[user])
    assert reply.status_code == 303, reply.text


def test_the_api_gives_the_klartext_toolpath_with_its_stock_and_tools(
    shop: PreviewShop, http: Any
) -> None:
    reply = http.get(
        "/api/programs/BRACKET.H/versions/1/toolpath",
        headers={"Authorization": f"Bearer {shop.key}"},
    )
    assert reply.status_code == 200, reply.text
    assert reply.headers["content-type"] == "application/octet-stream"
    plot = decode(reply.content)
    assert plot.tools == ("5", "7")
    # BLK FORM 0.1 Z X+0 Y+0 Z-20 / 0.2 X+120 Y+80 Z+0
    assert plot.meta["stock"] == {"min": [0, 0, -20], "max": [120, 80, 0], "axis": "Z"}
    points = {
        (round(plot.points[3 * i], 3), round(plot.points[3 * i + 1], 3), plot.points[3 * i + 2])
        for i in range(plot.point_count)
    }
    # the contour's corners at the depth of block 6 (L Z-5)
    for corner in [(-10, -10, -5), (10, 10, -5), (90, 10, -5), (110, 30, -5)]:
        assert corner in points
    # block 10, C X+110 Y+30 DR+ around CC X+90 Y+30 (file line 11): on the 20 mm circle
    on_arc = [i for i in range(plot.point_count) if plot.lines[i] == 11]
    assert len(on_arc) > 3
    for i in on_arc:
        radius = math.hypot(plot.points[3 * i] - 90, plot.points[3 * i + 1] - 30)
        assert radius == pytest.approx(20, abs=1e-4)
    kinds = {(run.rapid, plot.tools[run.tool] if run.tool >= 0 else None) for run in plot.runs}
    assert {(True, "5"), (False, "5"), (False, "7")} <= kinds
    assert reply.headers["X-Toolpath-Points"] == str(plot.point_count)


def test_a_100000_move_program_is_small_to_send(shop: PreviewShop, http: Any) -> None:
    reply = http.get(
        "/api/programs/O02000.nc/versions/1/toolpath",
        headers={"Authorization": f"Bearer {shop.key}"},
    )
    assert reply.status_code == 200, reply.text
    moves = int(reply.headers["X-Toolpath-Moves"])
    assert moves >= 100_000
    # 12 bytes a move would be 1.2 MB of coordinates alone
    assert len(reply.content) < 400_000, len(reply.content)
    plot = decode(reply.content)
    assert plot.moves == moves
    assert plot.tools == ("1", "3", "4", "2")  # in the order the program loads them
    # the raster's surface lies between Z -10.5 and -1.5 (-6 + 3 + 1.5, by its formula)
    zs = [plot.points[3 * i + 2] for i in range(plot.point_count)]
    assert min(zs) == pytest.approx(-12.0)  # the drilled holes go deepest
    assert max(zs) == pytest.approx(25.0)  # the clearance height


def test_the_page_routes_need_a_session_and_give_the_same_bytes(
    shop: PreviewShop, http: Any
) -> None:
    url = "/library/BRACKET.H/versions/1/toolpath"
    refused = http.get(url, follow_redirects=False)
    assert refused.status_code == 303
    assert refused.headers["location"].startswith("/login?next=")
    api = http.get(
        "/api/programs/BRACKET.H/versions/1/toolpath",
        headers={"Authorization": f"Bearer {shop.key}"},
    )
    _login(http)
    page = http.get(url)
    assert page.status_code == 200
    assert page.content == api.content
    assert http.get("/library/BRACKET.H/versions/9/toolpath").status_code == 404
    assert http.get("/library/NOPE.H/versions/1/preview").status_code == 404


def test_the_facts_fragment_names_time_tools_extents_and_stock(http: Any) -> None:
    _login(http)
    html = http.get("/library/BRACKET.H/versions/1/preview").text
    assert re.search(r"<strong>0:\d\d:\d\d</strong>", html)  # under an hour
    assert "T5" in html
    assert "T7" in html
    assert 'href="#L4"' in html  # TOOL CALL 5 is block 3, file line 4
    # Z from the drilling depth -15 to the retract +100: a size of 115
    assert re.search(r"<th scope=\"row\">Z</th><td>-15.000</td><td>100.000</td><td>115.000", html)
    assert "120 × 80 × 20 mm" in html  # the stock, 0.1 X+0 Y+0 Z-20 to 0.2 X+120 Y+80 Z+0


def test_the_text_is_a_window_around_the_line_asked_for(http: Any) -> None:
    _login(http)
    html = http.get("/library/O04000.nc", params={"line": 50_000}).text
    rows = re.findall(r'<tr id="L(\d+)"', html)
    assert len(rows) == 100
    assert rows[0] == "49980"
    assert rows[-1] == "50079"
    assert '<tr id="L50000" class="hl">' in html
    assert "(LINE 50000)" in html
    assert 'data-total="100000"' in html
    assert "line=49900" in html
    assert "line=50100" in html
    first = http.get("/library/O04000.nc").text
    assert re.findall(r'<tr id="L(\d+)"', first)[:2] == ["1", "2"]
    assert "previous lines" not in first
    # a line beyond the end shows the last window
    last = http.get("/library/O04000.nc", params={"line": 10**9}).text
    assert '<tr id="L100000" class="hl">' in last
    assert "next lines" not in last


def test_the_preview_cache_runs_each_version_once(tmp_path: Path) -> None:
    from opendnc.server.actions.preview import Preview, PreviewCache

    cache = PreviewCache(limit=15_000)
    made: list[str] = []

    def make(name: str) -> Preview:
        made.append(name)
        return Preview(name, "0" * 64, {}, b"x" * 3000, 0, 0)

    a = cache.get(("A", "1"), lambda: make("A"))
    assert cache.get(("A", "1"), lambda: make("again")) is a
    cache.get(("B", "1"), lambda: make("B"))
    # 7096 bytes each (3000 and a fixed 4096): a third one drops the least recently used
    # (B, as A was read last)
    cache.get(("A", "1"), lambda: make("again"))
    cache.get(("C", "1"), lambda: make("C"))
    cache.get(("B", "1"), lambda: make("B"))
    assert made == ["A", "B", "C", "B"]


def test_requests_for_a_preview_being_made_wait_for_it() -> None:
    from opendnc.server.actions.preview import Preview, PreviewCache

    cache = PreviewCache()
    started, release = threading.Event(), threading.Event()
    made: list[int] = []

    def slow() -> Preview:
        made.append(1)
        started.set()
        assert release.wait(60)
        return Preview("A", "0" * 64, {}, b"", 0, 0)

    results: list[Preview] = []
    first = threading.Thread(target=lambda: results.append(cache.get(("A", "1"), slow)))
    first.start()
    assert started.wait(60)
    second = threading.Thread(target=lambda: results.append(cache.get(("A", "1"), slow)))
    second.start()
    wait_for("the second request to wait", lambda: cache.waited == 1)
    release.set()
    first.join(60)
    second.join(60)
    assert made == [1]
    assert len(results) == 2
    assert results[0] is results[1]


def test_a_dry_run_made_elsewhere_is_kept_for_the_preview() -> None:
    from opendnc.nccheck import check_text
    from opendnc.server.actions.preview import PreviewCache, of_result

    text = "%\nO1\nT1 M06\nG00 X0 Y0 Z5\nG01 Z-1 F100\nX10\nM30\n%\n"
    cache = PreviewCache()
    kept = of_result("O1.nc", "a" * 64, check_text(text, name="O1.nc"))
    cache.put(("O1.nc", "a" * 64), kept)

    def never() -> Any:
        raise AssertionError("the kept preview is made again")

    assert cache.get(("O1.nc", "a" * 64), never) is kept
    assert decode(kept.toolpath).tools == ("1",)
    assert kept.facts["tools"][0]["tool"] == "1"
    assert "moves" not in kept.facts
