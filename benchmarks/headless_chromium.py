"""How the dashboard benchmark and the browser tests (tests/web/browser.py) start Chromium:
Debian's build, headless, with nothing that reaches out of the machine on its own."""

from __future__ import annotations

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
