"""While the database is away, what anyone is told says only that it is unavailable: the
driver's words name the database's host, address and user, so only the log has them
(docs/server.md#health-and-database-outages)."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from opendnc.server.access.auth import KEY_PREFIX
from opendnc.server.http.edge import DATABASE_UNAVAILABLE
from opendnc.server.store.models import Role
from tests.server.conftest import _pg_database
from tests.server.db_outage import Outage
from tests.server.harness import wait_for
from tests.server.inprocess_app import running

MACHINES: list[dict[str, object]] = [
    {"name": "tnc", "kind": "lsv2", "host": "127.0.0.1", "port": 1, "poll_interval": 0.2},
]


def test_health_and_refusals_never_repeat_the_driver_s_words(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING)
    for url in _pg_database():
        outage = Outage(url)
        with running(tmp_path, MACHINES, extra="[server]\ncluster = false\n", database=url) as app:
            outage.cut()
            try:
                health = wait_for(
                    "health to say the database is away",
                    lambda: (r := app.client.get("/api/health")).status_code == 503 and r,
                )
                database = health.json()["database"]
                assert database["reason"] == "the database is unavailable", database
                assert health.json()["leases"]["mode"] == "single"
                refused = app.client.get("/api/jobs", headers=app.api(Role.ADMIN))
                assert refused.status_code == 503, refused.text
                assert refused.json() == {"detail": DATABASE_UNAVAILABLE}
                page = app.client.get(
                    "/", headers={"Cookie": f"opendnc_session={KEY_PREFIX}{'x' * 43}"}
                )
                assert page.status_code == 503, page.text
                for text in (health.text, refused.text, page.text):
                    assert "127.0.0.1" not in text
                    assert "5432" not in text
                    assert "postgres" not in text.lower()
            finally:
                outage.close()  # restored, and its admin engine's pooled connection closed
            wait_for("health again", lambda: app.client.get("/api/health").status_code == 200)
        # the log has the driver's words, once for the outage
        said = [r.getMessage() for r in caplog.records if "is unavailable:" in r.getMessage()]
        assert len(said) == 1, said
        assert DATABASE_UNAVAILABLE not in said[0]
