"""The dashboard served in this process around one virtual TNC, for the tests that talk HTTP
without a browser: the server is built here and served by uvicorn on a loopback port."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tests.peers import require_module

require_module("jinja2")
uvicorn = require_module("uvicorn")

from opendnc.cli.serve import listen_socket  # noqa: E402
from opendnc.server import auth  # noqa: E402
from opendnc.server.app import build  # noqa: E402
from opendnc.server.config import parse_config  # noqa: E402
from opendnc.server.store.models import Role  # noqa: E402
from opendnc.sim.fleet import server_config  # noqa: E402
from tests.server.harness import wait_for  # noqa: E402
from tests.server.test_from_the_control import FleetThread  # noqa: E402


@dataclass
class Served:
    """The running server, its SQLite file and the fleet of one TNC it polls."""

    url: str
    server: Any
    database: Path
    fleet: FleetThread


@contextmanager
def serving(server: Any) -> Iterator[str]:
    """Serve a built server (``opendnc.server.app.build``) with uvicorn on a loopback port in a
    thread of this process; its base URL. The engine is disposed of at the end."""
    # a port the system picks, bound here: one chosen beforehand could be taken meanwhile
    listener = listen_socket("127.0.0.1", 0)
    port = listener.getsockname()[1]
    web = uvicorn.Server(uvicorn.Config(server.app, log_level="warning", loop="asyncio"))
    thread = threading.Thread(target=web.run, kwargs={"sockets": [listener]}, daemon=True)
    thread.start()
    wait_for("the server", lambda: web.started)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        web.should_exit = True
        thread.join(30)
        listener.close()
        server.engine.dispose()


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
