"""The overview's live stream keeps going while the database's write lock is held.

Two hundred transfers starting together claim, report and audit in one SQLite file; the card
stream only reads, so it must not queue behind them (docs/server.md#event-loop-stalls). Here
another connection holds the write lock (``BEGIN IMMEDIATE``) while the virtual TNC goes away:
its card must still arrive, offline, before the lock is released.
"""

from __future__ import annotations

import asyncio
import sqlite3
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.peers import require_module

require_module("jinja2")
httpx = require_module("httpx")
uvicorn = require_module("uvicorn")

from opendnc.cli.serve import listen_socket  # noqa: E402
from opendnc.server import auth  # noqa: E402
from opendnc.server.app import build  # noqa: E402
from opendnc.server.config import parse_config  # noqa: E402
from opendnc.server.store.models import Role  # noqa: E402
from opendnc.sim.fleet import server_config, start_fleet  # noqa: E402
from tests.server.harness import wait_for  # noqa: E402

PASSWORD = "viewer-secret"


@pytest.fixture
def shop(tmp_path: Path) -> Iterator[dict[str, Any]]:
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    fleet = asyncio.run_coroutine_threadsafe(
        start_fleet(tmp_path / "machines", tnc=1, haas=0), loop
    ).result(30)
    database = tmp_path / "db.sqlite"
    try:
        text = server_config(fleet, poll_interval=0.5, library=tmp_path / "lib")
        server = build(parse_config(text, base=tmp_path), database=f"sqlite:///{database}")
        with server.sessions.begin() as session:
            auth.create_user(session, "viewer", Role.VIEWER, password=PASSWORD)
        listener = listen_socket("127.0.0.1", 0)
        port = listener.getsockname()[1]
        web = uvicorn.Server(uvicorn.Config(server.app, log_level="warning", loop="asyncio"))
        serving = threading.Thread(target=web.run, kwargs={"sockets": [listener]}, daemon=True)
        serving.start()
        wait_for("the server", lambda: web.started)

        def stop_machines() -> None:
            asyncio.run_coroutine_threadsafe(fleet.close(), loop).result(30)

        try:
            yield {
                "url": f"http://127.0.0.1:{port}",
                "database": database,
                "server": server,
                "stop_machines": stop_machines,
            }
        finally:
            web.should_exit = True
            serving.join(30)
            listener.close()
            server.engine.dispose()
    finally:
        asyncio.run_coroutine_threadsafe(fleet.close(), loop).result(30)
        loop.call_soon_threadsafe(loop.stop)
        thread.join(10)
        loop.close()


def test_cards_arrive_while_another_connection_holds_the_write_lock(
    shop: dict[str, Any],
) -> None:
    server = shop["server"]
    name = next(iter(server.supervisor.machines))
    wait_for("the machine online", lambda: server.supervisor.machines[name].online)
    messages: list[str] = []
    with httpx.Client(base_url=shop["url"], timeout=30) as http:
        reply = http.post(
            "/login",
            data={"username": "viewer", "password": PASSWORD, "next": "/"},
            follow_redirects=False,
        )
        assert reply.status_code == 303, reply.text

        def read() -> None:
            try:
                with http.stream("GET", "/events/cards") as stream:
                    for line in stream.iter_lines():
                        messages.append(line)
                        if "offline" in line:
                            return
            except httpx.TransportError:
                pass  # the client closed under a failed test: its assertion says why

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        wait_for("the first cards", lambda: any(m == "event: cards" for m in messages))
        holder = sqlite3.connect(shop["database"], isolation_level=None, timeout=30)
        try:
            holder.execute("BEGIN IMMEDIATE")  # what a long claim or audit write holds
            shown = len(messages)
            shop["stop_machines"]()
            wait_for(
                "the card of the machine gone offline, with the lock still held",
                lambda: any("offline" in m for m in messages[shown:]),
                timeout=15,
                describe=lambda: messages[shown:],
            )
            assert holder.in_transaction  # the card came while the lock was held
        finally:
            holder.rollback()
            holder.close()
        reader.join(30)
