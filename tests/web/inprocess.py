"""The dashboard served in this process around one virtual TNC, for the tests that talk HTTP
without a browser: the server is built here and served by uvicorn on a loopback port."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tests.peers import require_module

require_module("jinja2")

from opendnc.server.access import auth  # noqa: E402
from opendnc.server.app import build  # noqa: E402
from opendnc.server.config.shop import parse_config  # noqa: E402
from opendnc.server.store.models import Role  # noqa: E402
from opendnc.sim.fleet import server_config  # noqa: E402
from tests.server.serving import serving  # noqa: E402
from tests.server.test_from_the_control import FleetThread  # noqa: E402


@dataclass
class Served:
    """The running server, its SQLite file and the fleet of one TNC it polls."""

    url: str
    server: Any
    database: Path
    fleet: FleetThread


@contextmanager
def serve_one_tnc(tmp_path: Path, user: str, role: Role, password: str) -> Iterator[Served]:
    """Serve the dashboard for one virtual TNC, with ``user`` of ``role`` able to log in."""
    fleet = FleetThread(tmp_path / "machines", tnc=1, haas=0)
    database = tmp_path / "db.sqlite"
    try:
        text = server_config(fleet.fleet, poll_interval=0.5, library=tmp_path / "lib", check="warn")
        server = build(parse_config(text, base=tmp_path), database=f"sqlite:///{database}")
        with server.sessions.begin() as session:
            auth.create_user(session, user, role, password=password)
        with serving(server) as url:
            yield Served(url, server, database, fleet)
    finally:
        fleet.stop()
