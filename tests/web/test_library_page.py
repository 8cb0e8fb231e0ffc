"""The library page in Debian's Chromium at 1280×800 and 768 wide: each program's title and
size in the list, the search by name or title and the search in the programs' text (the
matching line shown under the name), typed as a person types; nothing overflows its box and
no name, size or date wraps inside a word. Screenshots go to ``tests/artifacts/screenshots``
(gitignored) for a person to look at."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.peers import require_module

require_module("playwright.sync_api")

from opendnc.server.library import versions as library  # noqa: E402
from opendnc.server.store.models import Role  # noqa: E402
from tests.web.browser import ARTIFACTS, chromium, watched_context, watched_page  # noqa: E402
from tests.web.inprocess import Served, serve_one_tnc  # noqa: E402
from tests.web.test_utilization_pages import OVERFLOW_JS, WRAPS_JS  # noqa: E402

PASSWORD = "programmer-secret-1"
PROGRAMS = {
    "O1000.nc": b"%\nO1000 (BRACKET OP1)\nT12 M6\nG84 Z-10. R2. F1.25\nM30\n%\n",
    "POCKET.H": b"0 BEGIN PGM POCKET MM\r\n1 ; POCKET 40X20 FOR THE SIDE PLATE\r\n"
    b"2 TOOL CALL 5 Z S4000\r\n3 END PGM POCKET MM\r\n",
    "HOUSING_BACK_PLATE_OP20_FINAL_REWORK.nc": b"%\nO2020 (HOUSING BACK PLATE OP20 FINAL "
    b"REWORK AFTER THE FIXTURE CHANGE)\n" + b"G1 X10. Y10. F800\n" * 5000 + b"M30\n%\n",
    "O3000.nc": b"G0 X0\nM30\n",
}


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    tmp = tmp_path_factory.mktemp("library-page")
    with serve_one_tnc(tmp, "programmer", Role.PROGRAMMER, PASSWORD) as s:
        with s.server.sessions.begin() as session:
            for name, data in PROGRAMS.items():
                library.add_version(session, name, data, author="programmer")
        yield s


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    with chromium() as b:
        yield b


def _open(browser: Any, url: str, size: tuple[int, int]) -> tuple[Any, list[str]]:
    problems: list[str] = []
    page = watched_page(watched_context(browser, url, problems, size), problems)
    page.goto(url + "/library")
    page.get_by_label("User name").fill("programmer")
    page.get_by_label("Password").fill(PASSWORD)
    page.get_by_role("button", name="Log in").click()
    page.wait_for_url(url + "/library")
    return page, problems


def _shoot(page: Any, name: str) -> None:
    for folder in (ARTIFACTS, Path("/work/shots/util")):
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError:  # (the shots folder exists only on the project's machine)
            continue
        page.screenshot(path=str(folder / name), full_page=True)


@pytest.mark.parametrize("size", [(1280, 800), (768, 1024)], ids=lambda s: f"{s[0]}")
def test_titles_sizes_and_the_text_search(
    browser: Any, served: Served, size: tuple[int, int]
) -> None:
    page, problems = _open(browser, served.url, size)
    row = page.locator("table.programs tbody tr").filter(has_text="POCKET.H")
    assert row.locator("td.title").inner_text() == "POCKET 40X20 FOR THE SIDE PLATE"
    assert row.locator("td.num").inner_text() == f"{len(PROGRAMS['POCKET.H'])} B"
    big = page.locator("table.programs tbody tr").filter(has_text="HOUSING_BACK")
    assert "kB" in big.locator("td.num").inner_text()
    _shoot(page, f"library-{size[0]}.png")
    assert page.evaluate(OVERFLOW_JS) == []
    assert page.evaluate(WRAPS_JS, "table.programs td.name a, table.programs td.num") == []
    # by name or title, as typed
    page.get_by_label("Name or title").fill("bracket")
    page.wait_for_function(
        "() => document.querySelectorAll('table.programs tbody tr').length === 1"
    )
    assert "O1000.nc" in page.locator("table.programs tbody").inner_text()
    page.get_by_label("Name or title").fill("")
    page.wait_for_function(
        f"() => document.querySelectorAll('table.programs tbody tr').length === {len(PROGRAMS)}"
    )
    # in the programs' text: the first matching line under each name
    page.get_by_label("In the program text").fill("tool call")
    page.wait_for_function(
        "() => [...document.querySelectorAll('table.programs tbody tr')]"
        ".map(r => r.querySelector('td.name a').textContent).join() === 'POCKET.H'"
    )
    hit = page.locator("table.programs tbody tr")
    assert "POCKET.H" in hit.inner_text()
    assert hit.locator(".match").inner_text() == "line 3: 2 TOOL CALL 5 Z S4000"
    assert "text=tool" in page.url  # the search is in the address, to share or reload
    _shoot(page, f"library-text-search-{size[0]}.png")
    assert page.evaluate(OVERFLOW_JS) == []
    page.get_by_label("In the program text").fill("NOWHERE IN ANY PROGRAM")
    page.get_by_text("No program matches").wait_for()
    assert "holds “NOWHERE IN ANY PROGRAM” in its text" in page.locator("#programs").inner_text()
    assert problems == []
