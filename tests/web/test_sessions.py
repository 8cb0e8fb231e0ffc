"""Sessions, CSRF and input checks of the dashboard, over HTTP without a browser.

The server is built in-process around one virtual TNC (started here) and served by uvicorn
on a loopback port; the browser tests cover the same paths through Chromium.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from datetime import timedelta
from pathlib import Path
from typing import Any

import pytest

from tests.peers import require_module

httpx = require_module("httpx")

from opendnc.server.access import auth  # noqa: E402
from opendnc.server.actions import Services  # noqa: E402
from opendnc.server.store.models import ApiKey, Role  # noqa: E402
from opendnc.server.web import session as web_session  # noqa: E402
from tests.server.logins import log_in  # noqa: E402
from tests.web.inprocess import serve_one_tnc  # noqa: E402

Http = Any

PASSWORD = "operator-secret"


@pytest.fixture
def client(tmp_path: Path) -> Iterator[tuple[Http, Any]]:
    with (
        serve_one_tnc(tmp_path, "op", Role.OPERATOR, PASSWORD) as served,
        httpx.Client(base_url=served.url, timeout=30) as http,
    ):
        yield http, served.server


def _login(http: Http, user: str = "op") -> str:
    reply = log_in(http, user, PASSWORD)
    assert reply.status_code == 303, reply.text
    page = http.get("/").text
    token = re.search(r'"X-CSRF-Token": "([0-9a-f]{64})"', page)
    assert token is not None
    return token.group(1)


def test_pages_need_a_session_and_the_login_never_redirects_off_site(
    client: tuple[Http, Any],
) -> None:
    http, _ = client
    reply = http.get("/library?q=O1", follow_redirects=False)
    assert reply.status_code == 303
    assert reply.headers["location"] == "/login?next=/library%3Fq%3DO1"
    htmx = http.get("/machines/tnc-1/jobs", headers={"HX-Request": "true"})
    assert htmx.status_code == 401
    assert htmx.headers["HX-Redirect"].startswith("/login?next=")
    reply = log_in(http, "op", PASSWORD, next="//evil.example/x")
    assert reply.headers["location"] == "/"
    cookie = reply.headers["set-cookie"].lower()
    assert "httponly" in cookie
    assert "samesite=strict" in cookie


def test_writes_need_the_csrf_token_and_this_origin(client: tuple[Http, Any]) -> None:
    http, _ = client
    token = _login(http)
    form = {"index": "0"}
    no_token = http.post("/jobs/1/move", data=form)
    assert no_token.status_code == 403
    assert "CSRF" in no_token.text
    wrong = http.post("/jobs/1/move", data=form, headers={"X-CSRF-Token": "0" * 64})
    assert wrong.status_code == 403
    foreign = http.post(
        "/jobs/1/move",
        data=form,
        headers={"X-CSRF-Token": token, "Origin": "http://evil.example"},
    )
    assert foreign.status_code == 403
    assert "evil.example" in foreign.text
    ok_token = http.post("/jobs/1/move", data=form, headers={"X-CSRF-Token": token})
    assert ok_token.status_code == 404  # past the checks: there is no job 1
    # An API key is no session, and a session cookie is no API key.
    assert http.get("/api/machines").status_code == 401


def test_an_old_session_is_refused_and_logging_out_revokes_it(
    client: tuple[Http, Any],
) -> None:
    http, server = client
    _login(http)
    assert http.get("/", follow_redirects=False).status_code == 200
    with server.sessions.begin() as session:
        row = session.query(ApiKey).filter(ApiKey.label == "web session").one()
        row.created = row.created - timedelta(hours=13)
    # The server takes a key it checked in the last seconds from memory (auth.KeyCache): the
    # edit above stands for thirteen hours passing, and the cache's seconds pass with them.
    server.core.get(Services).keys.forget()
    assert http.get("/", follow_redirects=False).status_code == 303
    token = _login(http)
    assert http.get("/", follow_redirects=False).status_code == 200
    cookie = http.cookies.get(web_session.COOKIE)
    reply = http.post("/logout", headers={"X-CSRF-Token": token}, follow_redirects=False)
    assert reply.status_code == 303
    # Logged out is logged out at once, though the key was checked a moment ago.
    http.cookies.clear()
    again = http.get("/", headers={"Cookie": f"{web_session.COOKIE}={cookie}"})
    assert again.status_code == 303
    with server.sessions() as session:
        revoked = [k.revoked is not None for k in session.query(ApiKey).all()]
    assert revoked == [True, True]


@pytest.mark.parametrize(
    "path", ["TNC:/../etc", "C:/Windows", "TNC:/nc_prog/../../x", "/etc/passwd", "TNC:/a\x00b"]
)
def test_the_file_browser_stays_on_the_control(client: tuple[Http, Any], path: str) -> None:
    http, _ = client
    _login(http)
    reply = http.get("/machines/tnc-1/files", params={"path": path})
    assert reply.status_code == 400, reply.text
    assert "TNC:" in reply.text


def test_the_file_browser_lists_the_control(client: tuple[Http, Any]) -> None:
    http, _ = client
    _login(http)
    reply = http.get("/machines/tnc-1/files", params={"path": "TNC:/"})
    assert reply.status_code == 200, reply.text
    assert "nc_prog/" in reply.text


def test_an_interrupted_drip_feed_restarts_from_a_line(client: tuple[Http, Any]) -> None:
    from opendnc.server.jobs import queue as jobs
    from opendnc.server.library import versions as library
    from opendnc.server.store.models import Job, JobKind, JobState

    http, server = client
    with server.sessions.begin() as session:
        data = b"%\nO05000\nG1 X1.\nM30\n%\n"
        version, _ = library.add_version(session, "O05000.nc", data, author="t")
        job = jobs.enqueue(session, JobKind.DRIPFEED, "tnc-1", actor="t", version=version)
        # What a broken drip-feed ends as (set in the same transaction: it never runs here).
        job.state = JobState.INTERRUPTED
        job_id = job.id
        # A drip-feed runs the machine: programmers restart it, operators do not.
        auth.create_user(session, "prog", Role.PROGRAMMER, password=PASSWORD)
        _, op_key = auth.create_key(session, "op", Role.OPERATOR)
    # The API refuses an operator's key the same way.
    api = http.post(
        f"/api/jobs/{job_id}/retry",
        json={"from_line": 3},
        headers={"Authorization": f"Bearer {op_key}"},
    )
    assert api.status_code == 403, api.text
    assert "programmer" in api.text
    token = _login(http)
    page = http.get("/machines/tnc-1/jobs").text
    assert 'name="from_line"' not in page
    assert f"Retry job {job_id}" not in page
    refused = http.post(
        f"/jobs/{job_id}/retry", data={"from_line": "3"}, headers={"X-CSRF-Token": token}
    )
    assert refused.status_code == 403, refused.text
    token = _login(http, "prog")
    page = http.get("/machines/tnc-1/jobs").text
    assert 'name="from_line"' in page
    # A restart meets the rules a new drip-feed meets: this TNC takes none (only a serial
    # Haas with dripfeed = true does), so a programmer's restart is refused too, and queues
    # nothing (tests/web/test_machine_page.py restarts one on a Haas that allows it).
    reply = http.post(
        f"/jobs/{job_id}/retry", data={"from_line": "3"}, headers={"X-CSRF-Token": token}
    )
    assert reply.status_code == 409, reply.text
    assert "does not allow drip-feed" in reply.text
    with server.sessions() as session:
        assert session.query(Job).filter(Job.id != job_id).count() == 0
        assert session.get(Job, job_id).kind is JobKind.DRIPFEED


def test_the_event_streams_need_a_session_and_a_known_topic(client: tuple[Http, Any]) -> None:
    http, _ = client
    for url in ("/events/lists?topic=inbox", "/machines/tnc-1/dprnt.csv"):
        assert http.get(url, follow_redirects=False).status_code == 303, url
    _login(http)
    assert http.get("/events/lists?topic=jobs").status_code == 400
    assert http.get("/machines/nope/dprnt.csv").status_code == 404
    # A machine without a DPRNT source has an empty file, with its header.
    csv_text = http.get("/machines/tnc-1/dprnt.csv").text
    assert csv_text.splitlines() == ["id,at,machine,line,fields,complete"]
    with http.stream("GET", "/events/lists", params={"topic": "library"}) as stream:
        assert stream.headers["content-type"].startswith("text/event-stream")
        first = next(stream.iter_lines())
        assert first == "event: library"  # once at the start: the page checks its list
