"""A database that goes silent (a frozen link: packets go nowhere, nothing is reset) costs a
request at most the database watch's interval and timeout: once the watch has declared the
outage, every database-backed route and page answers 503 at once, a request that was already
waiting is let go with the same answer, and both answer 200 again as soon as the link flows.

PostgreSQL behind the test's proxy (tests/server/db_proxy.py); the server in this process on
memory controls (tests/server/inprocess_app.py)."""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from opendnc.server.http.edge import DATABASE_UNAVAILABLE
from opendnc.server.store.health import WATCH_INTERVAL, WATCH_TIMEOUT
from opendnc.server.store.models import Role
from tests.server.conftest import _pg_database
from tests.server.db_proxy import DbProxy
from tests.server.harness import wait_for
from tests.server.inprocess_app import running

MACHINES: list[dict[str, object]] = [
    {"name": "tnc", "kind": "lsv2", "host": "127.0.0.1", "port": 1, "poll_interval": 0.5},
]
# The first request after the freeze may wait for the watch to notice (an interval and a
# probe's timeout), then its answer must come; one made after that must come at once.
NOTICED = WATCH_INTERVAL + WATCH_TIMEOUT + 1.5
AT_ONCE = 1.0


@pytest.fixture
def pg_url() -> Iterator[str]:
    yield from _pg_database()


def _timed(call: object) -> tuple[float, object]:
    began = time.monotonic()
    result = call()  # type: ignore[operator]
    return time.monotonic() - began, result


def test_a_frozen_database_gets_503_at_once_and_200_when_it_flows_again(
    tmp_path: Path, pg_url: str, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING)
    proxy = DbProxy(pg_url)
    try:
        with running(
            tmp_path, MACHINES, extra="[server]\ncluster = false\n", database=proxy.url_for(pg_url)
        ) as app:
            headers = app.api(Role.ADMIN)
            page = {"Cookie": app.page(Role.VIEWER)["Cookie"]}
            assert app.client.get("/api/jobs", headers=headers).status_code == 200
            assert app.client.get("/", headers=page).status_code == 200

            proxy.freeze()
            # this request is made before the server can know: it waits on the silent link
            # until the watch declares the outage, and is answered then
            took, first = _timed(lambda: app.client.get("/api/jobs", headers=headers))
            assert first.status_code == 503, first.text  # type: ignore[attr-defined]
            assert first.json() == {"detail": DATABASE_UNAVAILABLE}  # type: ignore[attr-defined]
            assert took < NOTICED, f"the first request after the freeze took {took:.1f} s"
            for path, with_headers, kind in (
                ("/api/jobs", headers, "application/json"),
                ("/api/programs", headers, "application/json"),
                ("/", page, "text/html"),
                ("/library", page, "text/html"),
            ):
                took, answer = _timed(lambda: app.client.get(path, headers=with_headers))  # noqa: B023
                assert answer.status_code == 503, (path, answer.text)  # type: ignore[attr-defined]
                assert answer.headers["content-type"].startswith(kind), path  # type: ignore[attr-defined]
                assert took < AT_ONCE, f"{path} took {took:.2f} s during a known outage"

            proxy.restore()
            wait_for(
                "the API to answer again",
                lambda: app.client.get("/api/jobs", headers=headers).status_code == 200,
                timeout=5,
            )
            assert app.client.get("/", headers=page).status_code == 200
    finally:
        proxy.close()
    said = [r.getMessage() for r in caplog.records if "is unavailable:" in r.getMessage()]
    assert len(said) == 1, said  # one line for the outage, not one per request
