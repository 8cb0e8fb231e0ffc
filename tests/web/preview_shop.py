"""A served library without machines, for the program page's preview and text: the server is
built in this process and served by uvicorn on a loopback port; the programs are written for
these tests (benchmarks/preview_programs.py)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tests.peers import require_module

require_module("jinja2")
require_module("uvicorn")

from benchmarks.preview_programs import klartext_part, milling_program  # noqa: E402

from opendnc.server.access import auth  # noqa: E402
from opendnc.server.app import build  # noqa: E402
from opendnc.server.config.shop import parse_config  # noqa: E402
from opendnc.server.library import versions as library  # noqa: E402
from opendnc.server.store.models import Role  # noqa: E402
from tests.server.serving import serving  # noqa: E402
from tests.web.browser import PASSWORDS  # noqa: E402

__all__ = ["BIG_MOVES", "PROGRAMS", "PreviewShop", "long_program", "preview_shop"]

BIG_MOVES = 100_000


def long_program(lines: int) -> bytes:
    """A G-code program of exactly ``lines`` lines, each naming its own number (``N<line>``
    words are not used: the text is what a person searches)."""
    body = [f"G01 X{i % 500 / 10:.1f} Y{i // 500 / 10:.1f} (LINE {i})" for i in range(3, lines - 1)]
    return ("\n".join(["%", "O04000 (LONG)", *body, "M30", "%"]) + "\n").encode()


PROGRAMS: dict[str, bytes] = {
    "O02000.nc": milling_program(BIG_MOVES).encode(),
    "BRACKET.H": klartext_part().encode(),
    "O04000.nc": long_program(100_000),
    "O05000.nc": b"%\nO05000 (NOTHING TO CUT)\nM30\n%\n",
}


@dataclass
class PreviewShop:
    """The running server, its base URL and a viewer's API key."""

    url: str
    server: Any
    key: str


def _config(tmp: Path) -> str:
    q = json.dumps
    return "\n".join(
        [
            "[server]",
            'bind = "127.0.0.1:0"',
            "",
            "[library]",
            f"path = {q(str(tmp / 'programs'))}",
            f"inbox = {q(str(tmp / 'inbox'))}",
            f"archive = {q(str(tmp / 'archive'))}",
        ]
    )


@contextmanager
def preview_shop(tmp: Path, programs: dict[str, bytes] | None = None) -> Iterator[PreviewShop]:
    """Serve a library holding ``programs`` (default :data:`PROGRAMS`), users ``admin`` and
    ``viewer`` (passwords of tests/web/browser.py) and a viewer's API key."""
    server = build(parse_config(_config(tmp), base=tmp), database=f"sqlite:///{tmp / 'db.sqlite'}")
    with server.sessions.begin() as session:
        for user, role in (("admin", Role.ADMIN), ("viewer", Role.VIEWER)):
            auth.create_user(session, user, role, password=PASSWORDS[user])
        _row, key = auth.create_key(session, "viewer", Role.VIEWER, actor="test")
        for name, data in (PROGRAMS if programs is None else programs).items():
            library.add_version(session, name, data, author="test")
    with serving(server) as url:
        yield PreviewShop(url, server, key)
