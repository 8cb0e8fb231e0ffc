"""The API's and the pages' rules one by one: keys and sessions, logins, the queue's order and
cancel, receive names, bounded ids, query counts, offline controls. In-process, on memory
controls (tests/server/inprocess_app.py)."""

from __future__ import annotations

import hashlib
import threading
import time
from collections.abc import Iterator
from datetime import timedelta
from typing import Any, Literal

import httpx
import pytest
from argon2 import PasswordHasher, extract_parameters
from sqlalchemy import event, select

from opendnc.server.access import auth
from opendnc.server.access.key_use import KeyUse
from opendnc.server.access.refusals import Refusals
from opendnc.server.actions import Services
from opendnc.server.core.errors import Unauthorized
from opendnc.server.jobs import queue as jobs
from opendnc.server.library import versions as library
from opendnc.server.store.models import ApiKey, AuditEntry, Job, JobKind, JobState, Role, utcnow
from opendnc.server.web import session as web_session
from tests.server.harness import wait_for
from tests.server.inprocess_app import App, running
from tests.server.logins import log_in, login_form_token

MACHINES: list[dict[str, object]] = [
    {"name": "tnc", "kind": "lsv2", "host": "127.0.0.1", "port": 1, "poll_interval": 0.2},
    {"name": "tnc-off", "kind": "lsv2", "host": "127.0.0.1", "port": 1},
    {
        "name": "haas",
        "kind": "haas_serial",
        "serial": "socket://127.0.0.1:1",
        "dripfeed": True,
        "poll_interval": 0.2,
    },
]
ADMIN = Role.ADMIN


@pytest.fixture(scope="module")
def app(tmp_path_factory: pytest.TempPathFactory) -> Iterator[App]:
    # check = "warn": the programs here are minimal (a Haas program to a TNC too); the program
    # check's rules have their own tests (test_program_checks, test_policy_matrix)
    with running(
        tmp_path_factory.mktemp("fixes"), MACHINES, offline=("tnc-off",), check="warn"
    ) as served:
        with served.server.sessions.begin() as s:
            library.add_version(s, "O1.nc", b"%\nO1\nM30\n%\n", author="t")
            library.release(s, "O1.nc", 1, actor="t")
        yield served


@pytest.fixture
def fresh_guard(app: App) -> Iterator[None]:
    # the login guard counts per address: every test here comes from 127.0.0.1
    guard = app.server.core.get(Services).guard
    guard.reset()
    # the guard's clock stands still for the test: a wait of 1-2 s that a loaded machine lets
    # pass between two requests would turn an expected 429 into a 401 (seen at load 40)
    clock, now = guard.clock, guard.clock()
    guard.clock = lambda: now
    yield
    guard.clock = clock
    guard.reset()


def _statements(app: App) -> Any:
    seen: list[str] = []

    def note(_conn: Any, _cursor: Any, statement: str, *_args: Any) -> None:
        # the requests' statements (routes run in AnyIO's worker threads); the machines' own
        # work (asyncio.to_thread: status samples, the sweep) goes on meanwhile
        if threading.current_thread().name.startswith("AnyIO"):
            seen.append(statement.strip().upper())

    class Counter:
        def __enter__(self) -> list[str]:
            event.listen(app.server.engine, "before_cursor_execute", note)
            return seen

        def __exit__(self, *_exc: object) -> None:
            event.remove(app.server.engine, "before_cursor_execute", note)

    return Counter()


def _job(app: App, machine: str = "tnc", **body: Any) -> dict[str, Any]:
    reply = app.client.post(
        "/api/jobs", json={"machines": [machine], **body}, headers=app.api(ADMIN)
    )
    assert reply.status_code == 201, reply.text
    job: dict[str, Any] = reply.json()[0]
    return job


def _finished(app: App, job_id: int) -> dict[str, Any]:
    def done() -> dict[str, Any] | None:
        job: dict[str, Any] = app.client.get(f"/api/jobs/{job_id}", headers=app.api(ADMIN)).json()
        return job if job["state"] not in ("queued", "running") else None

    result: dict[str, Any] = wait_for(f"job {job_id}", done, timeout=30)
    return result


# -- keys and sessions ----------------------------------------------------------------------


def test_a_session_key_is_only_a_cookie_and_an_api_key_only_a_bearer(app: App) -> None:
    session_key = app.session_keys[ADMIN]
    as_bearer = app.client.get("/api/machines", headers={"Authorization": f"Bearer {session_key}"})
    assert as_bearer.status_code == 401
    assert "web session" in as_bearer.json()["detail"]
    api_key = app.api_keys[ADMIN]
    as_cookie = app.client.get(
        "/", headers={"Cookie": f"{web_session.COOKIE}={api_key}"}, follow_redirects=False
    )
    assert as_cookie.status_code == 303  # to the login
    assert app.client.get("/", headers=app.page(ADMIN)).status_code == 200


def test_requests_never_write_for_their_key_and_its_last_use_is_written_by_the_flush(
    app: App,
) -> None:
    key = app.api_keys[Role.VIEWER]
    uses = app.server.core.get(KeyUse)
    with app.server.sessions.begin() as s:
        s.execute(ApiKey.__table__.update().values(last_used=None))
    before = utcnow()
    with _statements(app) as seen:
        for _ in range(10):
            assert app.client.get("/api/jobs", headers=app.api(Role.VIEWER)).status_code == 200
            assert app.client.get("/library", headers=app.page(Role.VIEWER)).status_code == 200
    writes = [s for s in seen if s.split()[0] in ("UPDATE", "INSERT", "DELETE")]
    assert writes == [], writes
    with app.server.sessions() as s:
        row = s.scalar(select(ApiKey).where(ApiKey.key_hash == auth.key_hash(key)))
        assert row is not None
        key_id = row.id
    assert uses.pending()[key_id] >= before
    # The component's write (once a minute; here at once): both keys in one statement.
    assert uses.flush() >= 2
    assert uses.pending() == {}
    with app.server.sessions() as s:
        row = s.get(ApiKey, key_id)
        assert row is not None
        assert row.last_used is not None
        first = row.last_used
        assert first >= before
    # An older time noted later never moves it back.
    uses.note(key_id, first - timedelta(minutes=5))
    uses.flush()
    with app.server.sessions() as s:
        row = s.get(ApiKey, key_id)
        assert row is not None
        assert row.last_used == first
    app.client.get("/api/jobs", headers=app.api(Role.VIEWER))
    uses.flush()
    with app.server.sessions() as s:
        row = s.get(ApiKey, key_id)
        assert row is not None
        assert row.last_used is not None
        assert row.last_used > first


def test_a_key_revoked_through_the_api_is_refused_at_once_though_checked_a_moment_ago(
    app: App,
) -> None:
    made = app.client.post(
        "/api/keys", json={"user": "viewer-x", "role": "viewer"}, headers=app.api(ADMIN)
    )
    assert made.status_code == 201, made.text
    key = made.json()["key"]
    bearer = {"Authorization": f"Bearer {key}"}
    assert app.client.get("/api/machines", headers=bearer).status_code == 200
    revoked = app.client.delete(f"/api/keys/{made.json()['id']}", headers=app.api(ADMIN))
    assert revoked.status_code == 200, revoked.text
    refused = app.client.get("/api/machines", headers=bearer)
    assert refused.status_code == 401
    assert "revoked" in refused.json()["detail"]


def _login(app: App, user: str, password: str) -> Any:
    return log_in(app.client, user, password)


def _refusals(app: App, before: int, actor: str) -> list[AuditEntry]:
    app.server.core.get(Refusals).flush(everything=True)
    with app.server.sessions() as s:
        return list(
            s.scalars(
                select(AuditEntry).where(
                    AuditEntry.action == "login",
                    AuditEntry.result == "refused",
                    AuditEntry.actor == actor,
                    AuditEntry.id > before,
                )
            ).all()
        )


def _last_audit_id(app: App) -> int:
    with app.server.sessions() as s:
        return s.scalar(select(AuditEntry.id).order_by(AuditEntry.id.desc()).limit(1)) or 0


@pytest.fixture
def browser(app: App) -> Iterator[Any]:
    # another browser at the same address (127.0.0.1): its own cookies
    with httpx.Client(base_url=app.client.base_url, timeout=30) as client:
        yield client


def test_logins_are_audited_as_logins_and_failures_slow_down(app: App, fresh_guard: None) -> None:
    with app.server.sessions.begin() as s:
        auth.create_user(s, "ann", Role.OPERATOR, password="ann-secret-1")
    before = _last_audit_id(app)
    ok = _login(app, "ann", "ann-secret-1")
    assert ok.status_code == 303
    for _ in range(6):
        assert _login(app, "ann", "wrong-password").status_code == 401
    slowed = _login(app, "ann", "wrong-password")
    assert slowed.status_code == 429
    assert 1 <= int(slowed.headers["Retry-After"]) <= 2
    # while this browser must wait, even the right password waits (a guesser learns nothing)
    assert _login(app, "ann", "ann-secret-1").status_code == 429
    with app.server.sessions() as s:
        rows = s.scalars(
            select(AuditEntry).where(AuditEntry.actor == "ann", AuditEntry.id > before)
        ).all()
    assert [(r.action, r.result) for r in rows] == [("login", "ok")]
    assert rows[0].detail["key_id"] is not None
    assert rows[0].detail["via"] == "web"
    # the eight refusals: counted, summed into a row a minute (two if a minute ended between)
    refused = _refusals(app, before, "ann")
    assert 1 <= len(refused) <= 2
    assert sum(r.detail["count"] for r in refused) == 8
    assert sum(r.detail["throttled"] for r in refused) == 2
    assert {r.detail["address"] for r in refused} == {"127.0.0.1"}


def test_a_valid_key_and_a_login_work_after_100_wrong_keys_from_the_same_address(
    app: App, fresh_guard: None, browser: Any
) -> None:
    with app.server.sessions.begin() as s:
        auth.create_user(s, "cleo", Role.VIEWER, password="cleo-secret-1")
    before = _last_audit_id(app)
    # a script sending a new wrong key each time (another prefix each time): past the
    # address's allowance (100 free; the 101st starts the wait) it is slowed
    started = time.monotonic()
    answers = [
        app.client.get("/api/jobs", headers={"Authorization": f"Bearer odk_{n:06d}x"})
        for n in range(110)
    ]
    minutes = (time.monotonic() - started) / 60
    assert [a.status_code for a in answers] == [401] * 101 + [429] * 9
    assert 1 <= int(answers[-1].headers["Retry-After"]) <= 1024
    # neither the valid key nor a login at that address is refused for what the script did
    assert app.client.get("/api/jobs", headers=app.api(ADMIN)).status_code == 200
    assert log_in(browser, "cleo", "cleo-secret-1").status_code == 303
    refused = _refusals(app, before, "api")
    # a row a minute: one, or one more for each minute the 110 tries took (a loaded machine)
    assert 1 <= len(refused) <= 2 + int(minutes)
    assert sum(r.detail["count"] for r in refused) == 110
    assert sum(r.detail["throttled"] for r in refused) == 9
    assert len(refused[0].detail["names"]) == 10  # the first prefixes tried, then a count
    assert sum(len(r.detail["names"]) + r.detail["more_names"] for r in refused) >= 110


def test_a_key_s_prefix_waits_after_five_wrong_tries_other_keys_do_not(
    app: App, fresh_guard: None
) -> None:
    bad = {"Authorization": "Bearer odk_not-a-key"}
    answers = [app.client.get("/api/jobs", headers=bad).status_code for _ in range(7)]
    assert answers == [401] * 6 + [429]
    other = {"Authorization": "Bearer odk_other-key"}
    assert app.client.get("/api/jobs", headers=other).status_code == 401
    assert app.client.get("/api/jobs", headers=app.api(ADMIN)).status_code == 200


def test_a_guesser_slows_new_browsers_for_the_name_never_the_user_s_own(
    app: App, fresh_guard: None, browser: Any
) -> None:
    with app.server.sessions.begin() as s:
        auth.create_user(s, "dora", Role.OPERATOR, password="dora-secret-1")
        auth.create_user(s, "emil", Role.OPERATOR, password="emil-secret-1")
    assert log_in(browser, "dora", "dora-secret-1").status_code == 303  # dora's own browser
    # someone else (app.client: no device cookie for dora) guesses dora's password
    guesses = [_login(app, "dora", f"guess-{n}").status_code for n in range(7)]
    assert guesses == [401] * 6 + [429]
    assert _login(app, "dora", "dora-secret-1").status_code == 429  # a new browser waits
    # dora's browser is not slowed by the guesser, nor is another user at the same address
    assert log_in(browser, "dora", "dora-secret-1").status_code == 303
    assert _login(app, "emil", "emil-secret-1").status_code == 303


def test_a_login_needs_the_login_form_s_token_and_this_origin(app: App, browser: Any) -> None:
    with app.server.sessions.begin() as s:
        auth.create_user(s, "fritz", Role.VIEWER, password="fritz-secret-1")
    form = {"username": "fritz", "password": "fritz-secret-1", "next": "/"}
    before = _last_audit_id(app)
    # another site's form: no token, or a token of its own without this browser's cookie
    bare = browser.post("/login", data=form, follow_redirects=False)
    assert bare.status_code == 403
    assert "login page" in bare.text
    token = login_form_token(app.client)
    foreign = browser.post("/login", data={**form, "csrf": token}, follow_redirects=False)
    assert foreign.status_code == 403
    assert web_session.COOKIE not in foreign.cookies
    odd = browser.post("/login", data={**form, "csrf": "é" * 43}, follow_redirects=False)
    assert odd.status_code == 403  # any text is a refusal, never an error
    evil = {"Origin": "http://evil.example"}
    assert log_in(browser, "fritz", "fritz-secret-1", headers=evil).status_code == 403
    assert log_in(browser, "fritz", "fritz-secret-1").status_code == 303
    refused = _refusals(app, before, "fritz")
    assert sum(r.detail["count"] for r in refused) == 4  # each refusal audited
    assert refused[-1].detail["error"] == "a login from http://evil.example is refused"


def test_an_unknown_name_costs_a_password_check_like_a_known_one(
    app: App, monkeypatch: pytest.MonkeyPatch
) -> None:
    checked: list[str] = []

    class Counting(PasswordHasher):
        def verify(self, hash: str | bytes, password: str | bytes) -> Literal[True]:
            checked.append(hash if isinstance(hash, str) else hash.decode())
            return super().verify(hash, password)

    counting = Counting.from_parameters(extract_parameters(auth.dummy_hash()))
    monkeypatch.setattr(auth, "_hasher", counting)
    with app.server.sessions.begin() as s:
        known = auth.create_user(s, "gus", Role.VIEWER, password="gus-secret-1")
        auth.create_user(s, "hal", Role.VIEWER)  # a service user: no password
        stored = known.password_hash
    for name in ["gus", "nobody-by-this-name", "hal"]:
        with app.server.sessions() as s, pytest.raises(Unauthorized):
            auth.check_password(s, name, "wrong-password")
    assert len(checked) == 3  # one verification each, whether the name exists or not
    assert checked[0] == stored
    assert checked[1] == checked[2] == auth.dummy_hash()
    assert stored is not None
    assert extract_parameters(auth.dummy_hash()) == extract_parameters(stored)


# -- the queue ------------------------------------------------------------------------------


def test_history_is_newest_first_and_fifty_jobs_take_as_many_queries_as_five(app: App) -> None:
    with app.server.sessions.begin() as s:
        version = library.get_version(s, "O1.nc", 1)
        made = []
        for n in range(50):
            job = jobs.enqueue(s, JobKind.SEND, "tnc", actor="t", version=version)
            job.state = JobState.DONE
            job.position = float(50 - n)  # positions that disagree with the ids
            made.append(job.id)
    counts = []
    for limit in (5, 50):
        app.server.core.get(Services).keys.forget()  # each request reads its key
        with _statements(app) as seen:
            reply = app.client.get(
                "/api/jobs", params={"machine": "tnc", "limit": limit}, headers=app.api(ADMIN)
            )
        counts.append(sum(1 for s in seen if s.startswith("SELECT")))
        ids = [j["id"] for j in reply.json()]
        assert ids == sorted(ids, reverse=True)
        assert ids[0] >= made[-1]
    assert counts[0] == counts[1] >= 3, counts  # the key, the jobs, their versions, programs


def test_the_library_list_and_a_programs_page_of_versions_stay_bounded(app: App) -> None:
    for n in range(1, 4):
        put = app.client.put(
            "/api/programs/LIM.nc", content=f"G0 X{n}\n".encode(), headers=app.api(ADMIN)
        )
        assert put.status_code == 201, put.text
    listed = app.client.get("/api/programs", params={"q": "LIM"}, headers=app.api(ADMIN)).json()
    assert [(p["name"], p["version_count"], p["newest"]["number"]) for p in listed] == [
        ("LIM.nc", 3, 3)
    ]
    assert listed[0]["released"] is None
    page = app.client.get(
        "/api/programs/LIM.nc", params={"limit": 2}, headers=app.api(ADMIN)
    ).json()
    assert page["version_count"] == 3
    assert [v["number"] for v in page["versions"]] == [2, 3]
    whole = app.client.get("/api/programs/LIM.nc", headers=app.api(ADMIN)).json()
    assert [v["number"] for v in whole["versions"]] == [1, 2, 3]


@pytest.mark.parametrize(
    "url",
    [
        "/api/jobs/9223372036854775808",
        "/api/jobs/2147483648",
        "/api/jobs/0",
        "/api/inbox/99999999999999999999",
        "/api/audit?before=9223372036854775808",
        "/api/jobs?limit=0",
        "/api/jobs?limit=-1",
        "/api/audit?limit=0",
        "/api/programs/O1.nc/diff?a=1&b=9223372036854775808",
    ],
)
def test_numbers_out_of_range_are_refused_with_422(app: App, url: str) -> None:
    reply = app.client.get(url, headers=app.api(ADMIN))
    assert reply.status_code == 422, reply.text


def test_bodies_that_are_not_json_or_not_text_are_refused_with_422(app: App) -> None:
    odd = app.client.post(
        "/api/keys",
        content=b"\xff\xfe\x00garbage",
        headers={**app.api(ADMIN), "Content-Type": "application/octet-stream"},
    )
    assert odd.status_code == 422, odd.text
    huge = app.client.post(
        "/api/jobs",
        content=b'{"program": "O1.nc", "version": 1e400, "machines": ["tnc"]}',
        headers={**app.api(ADMIN), "Content-Type": "application/json"},
    )
    assert huge.status_code == 422, huge.text
    long_search = app.client.get(
        "/api/programs", params={"q": "x" * 60_000}, headers=app.api(ADMIN)
    )
    assert long_search.status_code == 422


def test_a_retry_needs_no_body_and_a_folder_in_a_name_is_a_clear_4xx(app: App) -> None:
    job = _job(app, program="O1.nc", path=None)
    with app.server.sessions.begin() as s:
        row = s.get(Job, job["id"])
        assert row is not None
        row.state = JobState.FAILED  # whatever it did, it is finished now
    reply = app.client.post(f"/api/jobs/{job['id']}/retry", headers=app.api(ADMIN))
    assert reply.status_code == 201, reply.text
    assert reply.json()["params"]["retry_of"] == job["id"]
    folder = app.client.put("/api/programs/a%2Fb", content=b"x", headers=app.api(ADMIN))
    assert folder.status_code == 404
    assert "folders" in folder.json()["detail"]
    # no catch-all PUT route answers the POST routes
    lock = app.client.post("/api/programs/O1.nc/lock", headers=app.api(Role.APPROVER))
    assert lock.status_code == 200, lock.text


def test_a_cancel_reaches_a_running_drip_feed_through_the_database(app: App) -> None:
    app.controls["haas"].line_time = 0.05
    data = b"%\nO2\n" + b"G1 X1.\n" * 400 + b"M30\n%\n"
    with app.server.sessions.begin() as s:
        library.add_version(s, "O2.nc", data, author="t")
        library.release(s, "O2.nc", 1, actor="t")
    job = _job(app, "haas", kind="dripfeed", program="O2.nc")
    wait_for(
        "the feed running",
        lambda: (
            app.client.get(f"/api/jobs/{job['id']}", headers=app.api(ADMIN)).json()["state"]
            == "running"
        ),
        timeout=20,
    )
    # as another server sharing the database would: a row, no call into this process
    with app.server.sessions.begin() as s:
        row = s.get(Job, job["id"])
        assert row is not None
        row.cancel_requested = True
    ended = _finished(app, job["id"])
    assert ended["state"] == "interrupted"
    assert "cancelled at line" in ended["error"]
    assert 2 < ended["line"] < 400


def test_a_load_cancelled_midway_keeps_the_bytes_its_message_says(app: App) -> None:
    """ "cancelled after 7424 bytes" in the error, 0 B in the Bytes column: one number."""
    app.controls["tnc"].chunk_time = 0.2
    data = b"%\nO3\n" + b"G1 X1.\n" * 1000 + b"M30\n%\n"
    try:
        with app.server.sessions.begin() as s:
            library.add_version(s, "O3.nc", data, author="t")
            library.release(s, "O3.nc", 1, actor="t")
        job = _job(app, "tnc", program="O3.nc")
        wait_for(
            "the load under way",
            lambda: (
                app.client.get(f"/api/jobs/{job['id']}", headers=app.api(ADMIN)).json()[
                    "bytes_done"
                ]
                > 0
            ),
            timeout=20,
        )
        with app.server.sessions.begin() as s:
            row = s.get(Job, job["id"])
            assert row is not None
            row.cancel_requested = True
        ended = _finished(app, job["id"])
    finally:
        app.controls["tnc"].chunk_time = 0.0
    assert ended["state"] == "cancelled"
    said = int(ended["error"].split("cancelled after ")[1].split(" bytes")[0])
    assert 0 < said < len(data)
    assert ended["bytes_done"] == said
    rows = app.client.get("/api/audit", params={"action": "job.send"}, headers=app.api(ADMIN))
    (row,) = [r for r in rows.json() if r["job_id"] == job["id"]]
    assert row["bytes"] == said


def test_a_received_file_keeps_its_name_and_meets_its_library_program(app: App) -> None:
    text = b"0 BEGIN PGM 1001 MM\n1 L X+1 R0 FMAX\n2 END PGM 1001 MM\n"
    with app.server.sessions.begin() as s:
        library.add_version(s, "1001.I", text, author="t")
        library.release(s, "1001.I", 1, actor="t")
    changed = text.replace(b"X+1", b"X+2")
    app.controls["tnc"].files["TNC:/nc_prog/1001.I"] = changed
    names = []
    for _ in range(2):
        job = _job(app, kind="receive", path="TNC:/nc_prog/1001.I")
        ended = _finished(app, job["id"])
        assert ended["state"] == "done", ended
        with app.server.sessions() as s:
            row = s.scalar(
                select(AuditEntry).where(
                    AuditEntry.job_id == job["id"], AuditEntry.action == "job.receive"
                )
            )
            assert row is not None
            received_id = row.detail["received_id"]
        item = app.client.get(f"/api/inbox/{received_id}", headers=app.api(ADMIN)).json()
        names.append(item["name"])
        assert item["base"]["program"] == "1001.I"
        assert item["base"]["number"] == 1
        assert "-1 L X+1 R0 FMAX" in item["diff"]
        assert "+1 L X+2 R0 FMAX" in item["diff"]
        assert item["sha256"] == hashlib.sha256(changed).hexdigest()
    assert names == ["1001.I", "1001.I"]
    inbox = app.server.config.library.inbox
    assert sorted(p.name for p in inbox.glob("1001*")) == ["1001.2.I", "1001.I"]


def test_an_offline_control_answers_503_in_one_line(app: App) -> None:
    reply = app.client.get("/api/machines/tnc-off/files", headers=app.api(ADMIN))
    assert reply.status_code == 503
    detail = reply.json()["detail"]
    assert detail.startswith("tnc-off is offline")
    assert "\n" not in detail
    page = app.client.get("/machines/tnc-off/files", headers=app.page(ADMIN))
    assert page.status_code == 503


def test_the_file_browser_reads_on_the_machine_s_own_link(app: App) -> None:
    control = app.controls["tnc"]
    control.files["TNC:/nc_prog/sub/A.H"] = b"1 END PGM A MM\n"
    links = control.connects
    listing = app.client.get(
        "/api/machines/tnc/files", params={"path": "TNC:/nc_prog"}, headers=app.api(Role.VIEWER)
    ).json()
    names = [(e["name"], e["is_dir"]) for e in listing["entries"]]
    assert names[0] == ("sub", True)  # folders first
    content = app.client.get(
        "/api/machines/tnc/files/content",
        params={"path": "TNC:/nc_prog/sub/A.H"},
        headers=app.api(Role.VIEWER),
    )
    assert content.content == b"1 END PGM A MM\n"
    assert content.headers["content-type"] == "application/octet-stream"
    page = app.client.get("/machines/tnc/files", headers=app.page(Role.VIEWER))
    assert "sub/" in page.text
    assert control.connects == links  # no second link: the machine's task did the reading
    # a control without a file browser has none, whoever asks
    haas = app.client.get("/api/machines/haas/files", headers=app.api(ADMIN))
    assert haas.status_code == 409


def test_the_file_browser_puts_and_deletes_through_jobs(app: App) -> None:
    control = app.controls["tnc"]
    control.files["TNC:/nc_prog/GONE.H"] = b"1 END PGM GONE MM\n"
    # a delete from the page is a job, run by the machine's own connector; the answer lists
    # the folder once the machine's queue ran
    reply = app.client.post(
        "/machines/tnc/files/delete",
        data={"path": "TNC:/nc_prog/GONE.H"},
        headers=app.page(Role.PROGRAMMER),
    )
    assert reply.status_code == 200, reply.text
    assert "delete TNC:/nc_prog/GONE.H queued" in reply.text
    assert "TNC:/nc_prog/GONE.H" not in control.files
    with app.server.sessions() as s:
        (job,) = s.scalars(
            select(Job).where(Job.kind == JobKind.DELETE, Job.machine == "tnc")
        ).all()
        assert job.state is JobState.DONE
        assert job.created_by == "programmer"
    # an upload is a library draft first, then a put_file job of that version
    reply = app.client.post(
        "/machines/tnc/files/upload",
        data={"folder": "TNC:/nc_prog/sub"},
        files={"file": ("NEW.H", b"1 END PGM NEW MM\n")},
        headers=app.page(Role.PROGRAMMER),
    )
    assert reply.status_code == 200, reply.text
    assert control.files["TNC:/nc_prog/sub/NEW.H"] == b"1 END PGM NEW MM\n"
    program = app.client.get("/api/programs/NEW.H", headers=app.api(ADMIN)).json()
    assert [v["state"] for v in program["versions"]] == ["draft"]
    # an operator may not delete (a page that hides the button is not the guard)
    refused = app.client.post(
        "/machines/tnc/files/delete",
        data={"path": "TNC:/nc_prog/sub/NEW.H"},
        headers=app.page(Role.OPERATOR),
    )
    assert refused.status_code == 403
    assert "TNC:/nc_prog/sub/NEW.H" in control.files


def test_jobs_stay_queued_for_a_later_time(app: App) -> None:
    # a row due tomorrow is never claimed: the runner reads the database, not this process
    with app.server.sessions.begin() as s:
        version = library.get_version(s, "O1.nc", 1)
        job = jobs.enqueue(
            s, JobKind.SEND, "tnc", actor="t", version=version, not_before=utcnow() + timedelta(1)
        )
        job_id = job.id
    app.server.machines.wake("tnc")
    reply = app.client.post(f"/api/jobs/{job_id}/cancel", headers=app.api(Role.OPERATOR))
    assert reply.json()["state"] == "cancelled"
