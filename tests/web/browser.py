"""Helpers of the browser tests: Debian's Chromium under Playwright, watched for console errors
and for requests that leave the machine (the dashboard must work offline)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tests.peers import missing_peer, require_module

sync_api = require_module("playwright.sync_api")

from benchmarks.headless_chromium import CHROMIUM, CHROMIUM_ARGS  # noqa: E402

from tests.server.harness import Procs  # noqa: E402
from tests.server.test_from_the_control import FleetThread  # noqa: E402

__all__ = [
    "ARTIFACTS",
    "PASSWORDS",
    "TIMEOUT_MS",
    "Shop",
    "chromium",
    "sync_api",
    "unnamed_controls",
]

ARTIFACTS = Path(__file__).resolve().parent.parent / "artifacts" / "screenshots"
PASSWORDS = {
    "admin": "admin-secret-1",
    "viewer": "viewer-secret-1",
    "operator": "operator-secret-1",
    "programmer": "programmer-secret-1",
}
TIMEOUT_MS = 30_000
sync_api.expect.set_options(timeout=TIMEOUT_MS)  # the machine is shared: be patient


@contextmanager
def chromium() -> Iterator[Any]:
    """A headless Chromium (a missing one is a missing peer)."""
    if not Path(CHROMIUM).exists():
        missing_peer(f"Chromium at {CHROMIUM} (apt-get install chromium)")
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            yield browser
        finally:
            browser.close()


def watched_context(browser: Any, url: str, problems: list[str], viewport: tuple[int, int]) -> Any:
    """A fresh context of ``browser`` that refuses, and notes in ``problems``, any request
    that does not go to ``url`` (the pages ship everything they need)."""
    ctx = browser.new_context(viewport={"width": viewport[0], "height": viewport[1]})
    ctx.set_default_timeout(TIMEOUT_MS)

    def route(r: Any) -> None:
        if r.request.url.startswith(url):
            r.continue_()
        else:
            problems.append(f"request left the machine: {r.request.url}")
            r.abort()

    ctx.route("**/*", route)
    return ctx


def watched_page(ctx: Any, problems: list[str]) -> Any:
    """A new page of ``ctx`` whose console errors and page errors go to ``problems``."""
    page = ctx.new_page()
    page.on(
        "console",
        lambda m: problems.append(f"console {m.type}: {m.text}") if m.type == "error" else None,
    )
    page.on("pageerror", lambda e: problems.append(f"page error: {e}"))
    return page


@dataclass
class Shop:
    """The running shop and browser."""

    url: str
    fleet: FleetThread
    procs: Procs
    browser: Any
    problems: list[str] = field(default_factory=list)

    def context(self, viewport: tuple[int, int] = (1280, 800)) -> Any:
        """A fresh browser context that records foreign requests."""
        return watched_context(self.browser, self.url, self.problems, viewport)

    def page(self, ctx: Any) -> Any:
        return watched_page(ctx, self.problems)

    def login(self, user: str, viewport: tuple[int, int] = (1280, 800)) -> Any:
        page = self.page(self.context(viewport))
        page.goto(self.url + "/")
        page.get_by_label("User name").fill(user)
        page.get_by_label("Password").fill(PASSWORDS[user])
        page.get_by_role("button", name="Log in").click()
        page.wait_for_url(self.url + "/")
        return page


def unnamed_controls(page: Any) -> list[str]:
    """The links, buttons and fields of the page that have no accessible name."""
    found: list[str] = page.evaluate(
        """() => [...document.querySelectorAll('a, button, input, select, [tabindex]')]
            .filter(e => e.type !== 'hidden')
            .filter(e => !(e.labels && e.labels.length) && !e.getAttribute('aria-label')
                         && !e.getAttribute('aria-labelledby')
                         && !e.textContent.trim() && !e.getAttribute('title'))
            .map(e => e.outerHTML)"""
    )
    return found
