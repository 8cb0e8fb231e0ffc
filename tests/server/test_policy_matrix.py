"""Every role x every action x every machine policy, through the API and through the pages.

Both adapters call one actions layer, so they must give the same answer; and that answer must
be the one the rules below (written out here, independently of the code) give. A case whose
API and page answers differ, or differ from the rules, is listed with both.

Each machine is sent a program of its own family (Klartext to a TNC, G-code to a Haas), so
the program check passes there; the check's own rules have their cases: a program of the
other family is an error that blocks a send and a release, an override needs a programmer
and a reason.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from datetime import timedelta
from pathlib import Path
from typing import Any

import pytest

from opendnc.server.jobs import queue as jobs
from opendnc.server.library import inbox
from opendnc.server.library import versions as library
from opendnc.server.store.models import JobKind, JobState, Role, utcnow
from tests.server.inprocess_app import ROLES, App, running

PROGRAM = "P.H"
TEXT = b"0 BEGIN PGM P MM\n1 L X+0 R0 FMAX\n2 END PGM P MM\n"
HAAS_PROGRAM = "O01000.nc"
HAAS_TEXT = b"%\nO01000\nG00 G90 G54 X0. Y0.\nM30\n%\n"
# the program check's error: a program no control runs (its last block has an unknown G code)
BROKEN_TEXT = b"%\nO01001\nG00 G90 G54 X0. Y0.\nG999\nM30\n%\n"
REASON = "checked on the machine by hand"

# name, configuration, and what the rules know of it
MACHINES: dict[str, dict[str, object]] = {
    "tnc": {"kind": "lsv2", "host": "127.0.0.1", "port": 1},
    "tnc-ro": {"kind": "lsv2", "host": "127.0.0.1", "port": 1, "released_only": True},
    "haas": {"kind": "haas_serial", "serial": "socket://127.0.0.1:1", "dripfeed": True},
    "haas-ro": {
        "kind": "haas_serial",
        "serial": "socket://127.0.0.1:1",
        "dripfeed": True,
        "released_only": True,
    },
    "haas-off": {"kind": "haas_serial", "serial": "socket://127.0.0.1:1"},
    "ngc": {"kind": "haas_ngc", "host": "127.0.0.1", "share": "SHARE"},
}


def _released_only(m: str) -> bool:
    return bool(MACHINES[m].get("released_only"))


def _dripfeed(m: str) -> bool:
    # the opt-in, on a kind that drip-feeds
    return MACHINES[m]["kind"] == "haas_serial" and bool(MACHINES[m].get("dripfeed"))


def _browser(m: str) -> bool:
    return MACHINES[m]["kind"] == "lsv2"


def _program(m: str) -> str:
    # a program of the machine's own family: its check passes there
    return PROGRAM if MACHINES[m]["kind"] == "lsv2" else HAAS_PROGRAM


def _foreign(m: str) -> str:
    # a program of the other family: its check on this machine is an error
    return HAAS_PROGRAM if MACHINES[m]["kind"] == "lsv2" else PROGRAM


@pytest.fixture(scope="module")
def app(tmp_path_factory: pytest.TempPathFactory) -> Iterator[App]:
    tmp = tmp_path_factory.mktemp("matrix")
    (tmp / "share").mkdir()
    machines = []
    for name, table in MACHINES.items():
        table = {**table, "share": str(tmp / "share")} if "share" in table else table
        machines.append({"name": name, "poll_interval": 0.2, **table})
    with running(tmp, machines) as served:
        with served.server.sessions.begin() as s:
            library.add_version(s, PROGRAM, TEXT, author="t")
            library.release(s, PROGRAM, 1, actor="t")
            library.add_version(s, PROGRAM, TEXT.replace(b"X+0", b"X+1"), author="t")  # v2
            library.add_version(s, HAAS_PROGRAM, HAAS_TEXT, author="t")
            library.release(s, HAAS_PROGRAM, 1, actor="t")
            library.add_version(s, HAAS_PROGRAM, HAAS_TEXT.replace(b"X0.", b"X1."), author="t")
        for control in served.controls.values():
            control.files["TNC:/nc_prog/OLD.H"] = b"old"
        yield served


# -- set-ups: each call gets its own rows ---------------------------------------------------

_counter = itertools.count(1)


def _later_job(app: App, machine: str, kind: JobKind, state: JobState) -> int:
    # A job that never runs by itself here (due tomorrow), in the state the case needs.
    with app.server.sessions.begin() as s:
        version = library.get_version(s, _program(machine), 1)
        job = jobs.enqueue(
            s,
            kind,
            machine,
            actor="t",
            version=version if kind in (JobKind.SEND, JobKind.DRIPFEED) else None,
            params={} if kind is not JobKind.RECEIVE else {"path": "TNC:/nc_prog/OLD.H"},
            not_before=utcnow() + timedelta(days=1),
        )
        job.state = state
        return job.id


def _reception(app: App) -> int:
    with app.server.sessions.begin() as s:
        data = b"%%\nO0%d\nM30\n%%\n" % next(_counter)
        return inbox.store(s, "tnc", data, folder=app.server.config.library.inbox).id


def _draft_program(app: App, text: bytes = TEXT) -> str:
    name = f"R{next(_counter)}.H" if text is TEXT else f"O0{next(_counter) + 2000}.nc"
    with app.server.sessions.begin() as s:
        library.add_version(s, name, text, author="t")
    return name


# -- the cases ------------------------------------------------------------------------------

Call = Callable[[App, Role, str], Any]


@dataclass(frozen=True)
class Case:
    """One action: its API request, its page request, and the rules' answer."""

    name: str
    api: Call
    page: Call
    expect: Callable[[Role, str], int | str]  # "ok" or the refusal's status
    per_machine: bool = True


def _jobs(app: App, role: Role, body: dict[str, object]) -> Any:
    return app.client.post("/api/jobs", json=body, headers=app.api(role))


def _form(app: App, role: Role, url: str, data: dict[str, Any] | None = None, **kw: Any) -> Any:
    return app.client.post(
        url, data=data or {}, headers=app.page(role), follow_redirects=False, **kw
    )


def _role(role: Role, needed: Role, then: int | str = "ok") -> int | str:
    return then if role >= needed else 403


def _job_case(name: str, kind: JobKind, state: JobState, needed: Role, verb: str) -> Case:
    def api(app: App, role: Role, m: str) -> Any:
        job = _later_job(app, m, kind, state)
        body = {"index": 0} if verb == "move" else None
        return app.client.post(f"/api/jobs/{job}/{verb}", json=body, headers=app.api(role))

    def page(app: App, role: Role, m: str) -> Any:
        job = _later_job(app, m, kind, state)
        return _form(app, role, f"/jobs/{job}/{verb}", {"index": "0"} if verb == "move" else {})

    def expect(role: Role, m: str) -> int | str:
        if kind is JobKind.DRIPFEED and role >= needed and not _dripfeed(m):
            return 409  # a restart meets the rules a new drip-feed meets
        return _role(role, needed)

    return Case(name, api, page, expect)


CASES = [
    Case(
        "send the released version",
        lambda app, role, m: _jobs(app, role, {"program": _program(m), "machines": [m]}),
        lambda app, role, m: _form(app, role, f"/library/{_program(m)}/send", {"machines": m}),
        lambda role, m: _role(role, Role.OPERATOR),
    ),
    Case(
        "send a draft",
        lambda app, role, m: _jobs(
            app, role, {"program": _program(m), "version": 2, "machines": [m]}
        ),
        lambda app, role, m: _form(
            app, role, f"/library/{_program(m)}/send", {"machines": m, "version": "2"}
        ),
        lambda role, m: _role(role, Role.OPERATOR, 409 if _released_only(m) else "ok"),
    ),
    Case(
        "drip-feed (no version: the released one)",
        lambda app, role, m: _jobs(
            app, role, {"kind": "dripfeed", "program": _program(m), "machines": [m]}
        ),
        lambda app, role, m: _form(app, role, f"/machines/{m}/dripfeed", {"program": _program(m)}),
        lambda role, m: _role(role, Role.PROGRAMMER, "ok" if _dripfeed(m) else 409),
    ),
    Case(
        "send a program the check refuses (another family)",
        lambda app, role, m: _jobs(app, role, {"program": _foreign(m), "machines": [m]}),
        lambda app, role, m: _form(app, role, f"/library/{_foreign(m)}/send", {"machines": m}),
        lambda role, m: _role(role, Role.OPERATOR, 409),
    ),
    Case(
        "override the check with a reason",
        lambda app, role, m: _jobs(
            app, role, {"program": _foreign(m), "machines": [m], "override": REASON}
        ),
        lambda app, role, m: _form(
            app,
            role,
            f"/library/{_foreign(m)}/send",
            {"machines": m, "override": "on", "reason": REASON},
        ),
        # an operator may send, but not past the check
        lambda role, m: _role(role, Role.PROGRAMMER),
    ),
    Case(
        "override the check without a reason",
        lambda app, role, m: _jobs(
            app, role, {"program": _foreign(m), "machines": [m], "override": " "}
        ),
        lambda app, role, m: _form(
            app, role, f"/library/{_foreign(m)}/send", {"machines": m, "override": "on"}
        ),
        lambda role, m: _role(role, Role.PROGRAMMER, 400),
    ),
    _job_case("cancel a queued job", JobKind.SEND, JobState.QUEUED, Role.OPERATOR, "cancel"),
    _job_case("move a queued job", JobKind.SEND, JobState.QUEUED, Role.OPERATOR, "move"),
    _job_case("retry a failed send", JobKind.SEND, JobState.FAILED, Role.OPERATOR, "retry"),
    _job_case(
        "restart a drip-feed", JobKind.DRIPFEED, JobState.INTERRUPTED, Role.PROGRAMMER, "retry"
    ),
    Case(
        "delete a file on the control",
        lambda app, role, m: _jobs(
            app, role, {"kind": "delete", "path": "TNC:/nc_prog/OLD.H", "machines": [m]}
        ),
        lambda app, role, m: _form(
            app, role, f"/machines/{m}/files/delete", {"path": "TNC:/nc_prog/OLD.H"}
        ),
        lambda role, m: _role(role, Role.PROGRAMMER),
    ),
    Case(
        "receive a file from the control",
        lambda app, role, m: _jobs(
            app, role, {"kind": "receive", "path": "TNC:/nc_prog/OLD.H", "machines": [m]}
        ),
        lambda app, role, m: _form(
            app, role, f"/machines/{m}/files/receive", {"path": "TNC:/nc_prog/OLD.H"}
        ),
        lambda role, m: _role(role, Role.OPERATOR),
    ),
    Case(
        "take a file of the control back into the library",
        lambda app, role, m: app.client.post(
            f"/api/machines/{m}/files/take-back",
            params={"path": "TNC:/nc_prog/OLD.H"},
            headers=app.api(role),
        ),
        lambda app, role, m: _form(
            app, role, f"/machines/{m}/files/take-back", {"path": "TNC:/nc_prog/OLD.H"}
        ),
        # a new version of a program: the programmer's, on a control with a file browser
        lambda role, m: _role(role, Role.PROGRAMMER, "ok" if _browser(m) else 409),
    ),
    Case(
        "put a draft on the control",
        lambda app, role, m: _jobs(
            app,
            role,
            {
                "kind": "put_file",
                "program": PROGRAM,
                "version": 2,
                "path": "TNC:/nc_prog/P.H",
                "machines": [m],
            },
        ),
        lambda app, role, m: _form(
            app,
            role,
            f"/machines/{m}/files/upload",
            {"folder": "TNC:/nc_prog"},
            files={"file": ("UP.H", b"%d\n" % next(_counter))},
        ),
        lambda role, m: _role(
            role, Role.PROGRAMMER, "ok" if _browser(m) and not _released_only(m) else 409
        ),
    ),
    Case(
        "list the control's files",
        lambda app, role, m: app.client.get(f"/api/machines/{m}/files", headers=app.api(role)),
        lambda app, role, m: app.client.get(f"/machines/{m}/files", headers=app.page(role)),
        lambda role, m: "ok" if _browser(m) else 409,
    ),
    Case(
        "release a version",
        lambda app, role, _m: app.client.post(
            f"/api/programs/{_draft_program(app)}/versions/1/release", headers=app.api(role)
        ),
        lambda app, role, _m: _form(
            app, role, f"/library/{_draft_program(app)}/versions/1/release"
        ),
        lambda role, _m: _role(role, Role.APPROVER),
        per_machine=False,
    ),
    Case(
        "release a version the check refuses",
        lambda app, role, _m: app.client.post(
            f"/api/programs/{_draft_program(app, BROKEN_TEXT)}/versions/1/release",
            headers=app.api(role),
        ),
        lambda app, role, _m: _form(
            app, role, f"/library/{_draft_program(app, BROKEN_TEXT)}/versions/1/release"
        ),
        lambda role, _m: _role(role, Role.APPROVER, 409),
        per_machine=False,
    ),
    Case(
        "release a version the check refuses, with an override",
        lambda app, role, _m: app.client.post(
            f"/api/programs/{_draft_program(app, BROKEN_TEXT)}/versions/1/release",
            json={"override": REASON},
            headers=app.api(role),
        ),
        lambda app, role, _m: _form(
            app,
            role,
            f"/library/{_draft_program(app, BROKEN_TEXT)}/versions/1/release",
            {"override": "on", "reason": REASON},
        ),
        lambda role, _m: _role(role, Role.APPROVER),
        per_machine=False,
    ),
    Case(
        "lock a program",
        lambda app, role, _m: app.client.post(
            f"/api/programs/{_draft_program(app)}/lock", headers=app.api(role)
        ),
        lambda app, role, _m: _form(
            app, role, f"/library/{_draft_program(app)}/lock", {"locked": "true"}
        ),
        lambda role, _m: _role(role, Role.APPROVER),
        per_machine=False,
    ),
    Case(
        "upload a program",
        lambda app, role, _m: app.client.put(
            f"/api/programs/U{next(_counter)}.H", content=TEXT, headers=app.api(role)
        ),
        lambda app, role, _m: _form(
            app, role, "/library", files={"file": (f"U{next(_counter)}.H", TEXT)}
        ),
        lambda role, _m: _role(role, Role.PROGRAMMER),
        per_machine=False,
    ),
    Case(
        "accept a reception",
        lambda app, role, _m: app.client.post(
            f"/api/inbox/{_reception(app)}/accept", headers=app.api(role)
        ),
        lambda app, role, _m: _form(app, role, f"/inbox/{_reception(app)}/accept"),
        lambda role, _m: _role(role, Role.PROGRAMMER),
        per_machine=False,
    ),
    Case(
        "discard a reception",
        lambda app, role, _m: app.client.post(
            f"/api/inbox/{_reception(app)}/discard", headers=app.api(role)
        ),
        lambda app, role, _m: _form(app, role, f"/inbox/{_reception(app)}/discard"),
        lambda role, _m: _role(role, Role.PROGRAMMER),
        per_machine=False,
    ),
]


def _answer(response: Any) -> int | str:
    return "ok" if response.status_code < 400 else int(response.status_code)


@pytest.mark.parametrize("role", ROLES, ids=lambda r: r.name.lower())
def test_the_api_and_the_pages_answer_alike_and_by_the_rules(app: App, role: Role) -> None:
    wrong = []
    checked = 0
    for case in CASES:
        for machine in MACHINES if case.per_machine else ["-"]:
            api = app_answer = case.api(app, role, machine)
            page = case.page(app, role, machine)
            expected = case.expect(role, machine)
            app_answer, page_answer = _answer(api), _answer(page)
            checked += 1
            if not (app_answer == page_answer == expected):
                wrong.append(
                    f"{case.name} on {machine}: rules {expected}, api {app_answer} "
                    f"({api.text[:120]}), page {page_answer} ({page.text[-200:]!r})"
                )
    assert checked == 15 * len(MACHINES) + 7
    assert not wrong, "\n".join(wrong)


def test_a_draft_put_on_a_released_only_control_stores_nothing(app: App, tmp_path: Path) -> None:
    # the refusal rolls the draft back: the library holds no version of the upload
    with app.server.sessions() as s:
        before = len(library.list_programs(s, "NEW"))
    reply = _form(
        app,
        Role.ADMIN,
        "/machines/tnc-ro/files/upload",
        {"folder": "TNC:/nc_prog"},
        files={"file": ("NEW.H", b"1 L X+1\n")},
    )
    assert reply.status_code == 409, reply.text
    assert "released programs only" in reply.text
    with app.server.sessions() as s:
        assert len(library.list_programs(s, "NEW")) == before == 0
