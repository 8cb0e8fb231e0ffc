"""The overview's live stream keeps going while the database's write lock is held.

Two hundred transfers starting together claim, report and audit in one SQLite file; the card
stream only reads, so it must not queue behind them (docs/server.md#event-loop-stalls). Here
another connection holds the write lock (``BEGIN IMMEDIATE``) while the virtual TNC goes away:
its card must still arrive, offline, before the lock is released.
"""

from __future__ import annotations

import sqlite3
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.peers import require_module

httpx = require_module("httpx")

from opendnc.server.store.models import Role  # noqa: E402
from tests.server.harness import wait_for  # noqa: E402
from tests.server.logins import log_in  # noqa: E402
from tests.web.inprocess import Served, serve_one_tnc  # noqa: E402

PASSWORD = "viewer-secret"


@pytest.fixture
def shop(tmp_path: Path) -> Iterator[Served]:
    with serve_one_tnc(tmp_path, "viewer", Role.VIEWER, PASSWORD) as served:
        yield served


def test_cards_arrive_while_another_connection_holds_the_write_lock(
    shop: Served,
) -> None:
    server = shop.server
    name = next(iter(server.machines.machines))
    wait_for("the machine online", lambda: server.machines.machines[name].online)
    messages: list[str] = []
    with httpx.Client(base_url=shop.url, timeout=30) as http:
        reply = log_in(http, "viewer", PASSWORD)
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
        holder = sqlite3.connect(shop.database, isolation_level=None, timeout=30)
        try:
            holder.execute("BEGIN IMMEDIATE")  # what a long claim or audit write holds
            shown = len(messages)
            shop.fleet.run(shop.fleet.fleet.close)  # the machine goes away
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
