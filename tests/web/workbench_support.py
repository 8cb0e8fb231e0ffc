"""What the workbench's and the editor's browser tests share: the programs they store (with
their defects on known lines) and a logged-in tab that records console errors and requests
that leave the machine."""

from __future__ import annotations

from typing import Any

from tests.peers import require_module

require_module("playwright.sync_api")

from opendnc.server.store.models import Role  # noqa: E402
from opendnc.server.web import session as web_session  # noqa: E402
from tests.server.inprocess_app import App  # noqa: E402
from tests.web.browser import ARTIFACTS, TIMEOUT_MS  # noqa: E402

__all__ = ["BROKEN", "KLARTEXT", "MACHINES", "Tab", "haas_program"]

MACHINES: list[dict[str, object]] = [
    {"name": "tnc-1", "kind": "lsv2", "host": "127.0.0.1", "port": 1},
    {"name": "haas-1", "kind": "haas_serial", "serial": "socket://127.0.0.1:1"},
]


def haas_program(lines: int) -> bytes:
    """A clean Haas program of about ``lines`` lines: a tool, a macro variable, a pocket of
    feed moves (line k holds ``X{k}.``), then the end."""
    head = [
        "%",
        "O02000 (POCKET)",
        "(T1 10MM END MILL)",
        "T1 M06",
        "#100 = 2.5",
        "G00 G90 G54 X0. Y0.",
        "S2000 M03",
        "G43 H01 Z5.",
        "G01 Z-#100 F100.",
    ]
    body = [f"G01 X{k}. Y{k % 7}. F100." for k in range(len(head) + 1, lines - 3)]
    tail = ["G00 Z50.", "M30", "%"]
    return ("\n".join(head + body + tail) + "\n").encode()


KLARTEXT = (
    b"0 BEGIN PGM K MM\n"
    b"1 BLK FORM 0.1 Z X+0 Y+0 Z-20\n"
    b"2 BLK FORM 0.2 X+100 Y+100 Z+0\n"
    b"3 TOOL CALL 5 Z S3000\n"
    b"4 FN 0: Q1 = +10 ; depth\n"
    b"5 L X+10 Y-5 R0 FMAX M3\n"
    b"6 L Z-Q1 F200\n"
    b"7 END PGM K MM\n"
)
# two defects on known lines: an unknown G code on line 5, a word without a value on line 7
BROKEN = (
    b"%\nO02001 (BROKEN)\nT1 M06\nG00 G90 G54 X0. Y0.\nG999 X1.\nS1000 M03\nG01 X F100.\nM30\n%\n"
)


class Tab:
    """A logged-in browser page, with the console errors it saw."""

    def __init__(self, app: App, browser: Any, role: Role, width: int, height: int) -> None:
        self.base = str(app.client.base_url).rstrip("/")
        self.ctx = browser.new_context(viewport={"width": width, "height": height})
        self.ctx.set_default_timeout(TIMEOUT_MS)
        self.ctx.add_cookies(
            [{"name": web_session.COOKIE, "value": app.session_keys[role], "url": self.base}]
        )
        self.problems: list[str] = []

        def route(r: Any) -> None:
            if r.request.url.startswith(self.base):
                r.continue_()
            else:
                self.problems.append(f"request left the machine: {r.request.url}")
                r.abort()

        self.ctx.route("**/*", route)
        self.page = self.ctx.new_page()
        self.page.on("console", self._console)
        self.page.on("pageerror", lambda e: self.problems.append(f"page error: {e}"))

    def _console(self, message: Any) -> None:
        # a refusal (409, 400) is the browser's own console line, not a script's error
        if message.type == "error" and "status of 4" not in message.text:
            self.problems.append(f"console: {message.text}")

    def goto(self, path: str, timeout: float = 30_000) -> Any:
        self.page.goto(self.base + path, timeout=timeout)
        return self.page

    def shot(self, name: str) -> None:
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        self.page.screenshot(path=str(ARTIFACTS / f"wbcheck-{name}.png"), full_page=True)

    def close(self) -> None:
        self.ctx.close()
        assert not self.problems, self.problems
