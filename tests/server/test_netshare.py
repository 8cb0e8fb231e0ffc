"""The hybrid net share against real folders and real virtual Haas NGCs (their shares are
their program memory): push to every subscribed machine, collect what the machines made,
archive on the schedule (the clock is injected), and the same in a running server."""

from __future__ import annotations

import asyncio
import json
import logging
import time
from collections.abc import Callable, Iterator
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from opendnc.haas.share import ShareTarget
from opendnc.server.actions.base import Services
from opendnc.server.actions.policy import share_gate
from opendnc.server.config.shop import ConfigError, NetShareConfig, parse_config
from opendnc.server.core.events import EventBus
from opendnc.server.jobs import queue as jobs
from opendnc.server.kinds.base import SharedMachine
from opendnc.server.kinds.registry import connector_for, shares_of
from opendnc.server.library import versions as library
from opendnc.server.machines.state import Machines
from opendnc.server.netshare.share import NetShare, ScanReport, ShareGate
from opendnc.server.store.models import AuditEntry, JobKind, Received
from opendnc.sim.fleet import server_config
from tests.interop.test_haas_share_samba import PASSWORD as SMB_PASSWORD
from tests.interop.test_haas_share_samba import Samba, samba
from tests.server.conftest import on
from tests.server.srvx_support import (
    FleetThread,
    Procs,
    auth,
    create_key,
    httpx,
    serve,
    wait_for,
)

__all__ = ["samba"]  # a fixture shared with other tests

PROGRAM = "%\nO01000 (BRACKET)\nG20\nG00 G90 G54 X0. Y0.\nG01 X1.5 F20.\nM30\n%\n"
EDITED = PROGRAM.replace("X1.5", "X1.25")
MADE_HERE = "%\nO02000 (MADE AT THE MACHINE)\nG00 X0. Y0.\nM30\n%\n"


@pytest.fixture
def ngc(tmp_path: Path) -> Iterator[FleetThread]:
    fleet = FleetThread(tmp_path / "machines", tnc=0, haas=2)
    try:
        yield fleet
    finally:
        fleet.stop()


def open_gate(machine: SharedMachine, name: str, data: bytes) -> str | None:
    """A shop whose policy lets every file into every share: the tests of the copying
    itself, not of the policy (the server always gives the share the policy's gate)."""
    return None


class Clock:
    """The shop's wall clock, moved by the test."""

    def __init__(self, start: datetime) -> None:
        self.now = start

    def __call__(self) -> datetime:
        return self.now


def _make(
    tmp_path: Path,
    ngc: FleetThread,
    sessions: sessionmaker[Session],
    clock: Clock,
    gated: bool = False,
    **overrides: Any,
) -> NetShare:
    text = server_config(ngc.fleet, library=tmp_path / "lib")
    # haas-1 takes released programs only
    text = text.replace('name = "haas-1"\n', 'name = "haas-1"\nreleased_only = true\n')
    shop = parse_config(text, base=tmp_path)
    nas = tmp_path / "nas"
    nas.mkdir(exist_ok=True)
    settings = {
        "path": nas,
        "machines": ("haas-1", "haas-2"),
        "archive": tmp_path / "archive",
        "archive_at": (18, 0),
        "interval": 0.05,
        **overrides,
    }
    config = NetShareConfig(**settings)
    machines = shares_of(shop.machines)
    gate: ShareGate = open_gate
    if gated:  # the server's own gate: the queue's policy, through the actions
        with sessions.begin() as session:
            jobs.sync_machines(session, shop.machines)
        services = Services(sessions, sessions, Machines(shop, EventBus()))
        gate = share_gate(services)
    return NetShare(
        config, machines, tmp_path / "inbox", sessions, EventBus(), clock=clock, gate=gate
    )


def _scan_until(net: NetShare, done: Callable[[ScanReport], bool], what: str) -> ScanReport:
    """Scan until ``done`` holds for the reports so far (merged); fail after a deadline."""
    total = ScanReport()
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline:
        report = net.scan_sync()
        total.pushed += report.pushed
        total.collected += report.collected
        total.archived += report.archived
        total.failed += report.failed
        total.refused += report.refused
        if done(total):
            return total
        time.sleep(0.02)
    raise AssertionError(f"{what} did not happen: {total}")


def _memory(ngc: FleetThread, machine: str, number: int) -> str | None:
    sim = ngc.fleet.sims[machine]
    numbers: list[int] = ngc.call(lambda: sim.control.store.numbers())
    return ngc.call(lambda: sim.control.read_program(number)) if number in numbers else None


def _audit(sessions: sessionmaker[Session], action: str) -> list[AuditEntry]:
    with sessions() as session:
        rows = session.scalars(
            select(AuditEntry).where(AuditEntry.action == action).order_by(AuditEntry.id)
        ).all()
        session.expunge_all()
        return list(rows)


def test_push_collect_archive_and_restart(
    tmp_path: Path, ngc: FleetThread, sessions: sessionmaker[Session]
) -> None:
    clock = Clock(datetime(2026, 11, 23, 9, 0).astimezone())
    net = _make(tmp_path, ngc, sessions, clock)
    # Programs already in a machine's memory are its history, not new work.
    old = "%\nO00100 (OLD JOB)\nM30\n%\n"
    ngc.call(lambda: ngc.fleet.sims["haas-1"].control.save_program(old))
    _scan_until(net, lambda _r: len(net.baselined) == 2, "the first look at the shares")
    (baseline,) = [r for r in _audit(sessions, "netshare.baseline") if r.machine == "haas-1"]
    assert list(baseline.detail["files"]) == ["O00100.nc"]

    # 1. A program dropped on the NAS reaches both machines, byte for byte.
    (tmp_path / "nas" / "O01000.nc").write_text(PROGRAM)
    pushed = _scan_until(net, lambda r: len(r.pushed) == 2, "the push")
    assert sorted(pushed.pushed) == [("haas-1", "O01000.nc"), ("haas-2", "O01000.nc")]
    for machine in ("haas-1", "haas-2"):
        assert _memory(ngc, machine, 1000) == PROGRAM
        share = ngc.fleet.sims[machine].control.store.root
        assert (share / "O01000.nc").read_bytes() == PROGRAM.encode()
    rows = _audit(sessions, "netshare.push")
    assert sorted((r.machine, r.program, r.result, r.bytes) for r in rows) == [
        ("haas-1", "O01000.nc", "ok", len(PROGRAM)),
        ("haas-2", "O01000.nc", "ok", len(PROGRAM)),
    ]
    assert net.scan_sync().pushed == []  # nothing new: nothing pushed, nothing collected

    # 2. A program made at haas-2 comes back into the inbox; ours are not taken back.
    ngc.call(lambda: ngc.fleet.sims["haas-2"].control.save_program(MADE_HERE))
    got = _scan_until(net, lambda r: bool(r.collected), "the collection")
    assert got.collected == [("haas-2", "O02000.nc")]
    assert (tmp_path / "inbox" / "O02000.nc").read_text() == MADE_HERE
    with sessions() as session:
        received = session.scalars(select(Received)).all()
        assert [(r.machine, r.name) for r in received] == [("haas-2", "O02000.nc")]
    assert [r.machine for r in _audit(sessions, "netshare.collect")] == ["haas-2"]

    # The operator edits our copy on haas-1: it is now the machine's work.
    (ngc.fleet.sims["haas-1"].control.store.root / "O01000.nc").write_text(EDITED)
    edited = _scan_until(net, lambda r: bool(r.collected), "the edited copy")
    assert edited.collected == [("haas-1", "O01000.nc")]

    # 3. Archive at 18:00, not before; the unedited copy leaves haas-2, the edit stays.
    clock.now = clock.now.replace(hour=17, minute=59)
    assert net.scan_sync().archived == []
    clock.now = clock.now.replace(hour=18, minute=1)
    assert net.scan_sync().archived == ["O01000.nc"]
    assert list((tmp_path / "nas").iterdir()) == []
    day = tmp_path / "archive" / "2026-11-23"
    assert (day / "O01000.nc").read_text() == PROGRAM
    assert _memory(ngc, "haas-2", 1000) is None
    assert _memory(ngc, "haas-1", 1000) == EDITED
    (archived,) = _audit(sessions, "netshare.archive")
    assert archived.detail["removed_from"] == ["haas-2"]
    clock.now += timedelta(hours=1)
    assert net.scan_sync().archived == []  # once a day

    # 4. A restarted server knows what it did: nothing pushed or collected twice, and the
    # archive missed while it was down (the next evening) runs when it comes back.
    (tmp_path / "nas" / "O01000.nc").write_text(PROGRAM)  # the same program, next morning
    clock.now = datetime(2026, 11, 24, 19, 30).astimezone()
    again = _make(tmp_path, ngc, sessions, clock)
    report = _scan_until(again, lambda r: bool(r.archived), "the missed archive")
    # haas-2's copy was archived away, so it gets the program again (pushed before the
    # archive takes it); haas-1 keeps the operator's edit, which is not overwritten
    assert report.pushed == [("haas-2", "O01000.nc")]
    assert report.collected == []
    assert (tmp_path / "archive" / "2026-11-24" / "O01000.nc").read_text() == PROGRAM
    assert _memory(ngc, "haas-1", 1000) == EDITED
    runs = _audit(sessions, "netshare.archive_run")
    assert [r.detail["files"] for r in runs] == [["O01000.nc"], ["O01000.nc"]]


def test_a_share_that_is_away_is_audited_and_retried(
    tmp_path: Path, ngc: FleetThread, sessions: sessionmaker[Session]
) -> None:
    clock = Clock(datetime(2026, 11, 23, 9, 0).astimezone())
    net = _make(tmp_path, ngc, sessions, clock)
    share = ngc.fleet.sims["haas-2"].control.store.root
    away = share.with_name("haas-2-unmounted")
    share.rename(away)  # the machine's share is not mounted
    (tmp_path / "nas" / "O01000.nc").write_text(PROGRAM)
    report = _scan_until(net, lambda r: bool(r.failed) and bool(r.pushed), "the push")
    assert report.pushed == [("haas-1", "O01000.nc")]
    assert report.failed[0][:2] == ("haas-2", "O01000.nc")
    failed = [r for r in _audit(sessions, "netshare.push") if r.result == "failed"]
    assert len(failed) == 1
    assert "does not exist" in failed[0].detail["error"]
    away.rename(share)
    _scan_until(net, lambda r: r.pushed == [("haas-2", "O01000.nc")], "the retry")
    assert (share / "O01000.nc").read_text() == PROGRAM


@pytest.mark.parametrize(
    ("table", "key"),
    [
        ('archive_at = "18:00"', "netshare.path"),
        ('path = "ftp://nas/programs"', "netshare.path"),
        ('path = "smb://nas"', "netshare.path"),
        ('path = "nas"\nusername = "dnc"', "netshare.username"),
        ('path = "smb://dnc@nas/cnc"\nusername = "dnc"', "netshare.username"),
        ('path = "smb://dnc:pw@nas/cnc"\npassword = "pw"', "netshare.password"),
        ('path = "smb://nas/cnc"\npassword = 1234', "netshare.password"),
        ('path = "nas"\nmachines = ["haas-9"]', "netshare.machines[0]"),
        ('path = "nas"\nmachines = ["haas-1", "mill"]', "netshare.machines[1]"),
        ('path = "nas"\narchive_at = "25:00"', "netshare.archive_at"),
        ('path = "nas"\narchive_at = "18:00"\narchive_every = 60', "netshare.archive_every"),
        ('path = "nas"\narchive_every = 0', "netshare.archive_every"),
        ('path = "nas"\ncollect = "yes"', "netshare.collect"),
        ('path = "nas"\nschedule = "daily"', "netshare.schedule"),
    ],
)
def test_netshare_config_errors_name_the_key(tmp_path: Path, table: str, key: str) -> None:
    machines = (
        '[[machines]]\nname = "haas-1"\nkind = "haas_ngc"\nhost = "10.0.0.5"\nshare = "s1"\n'
        '[[machines]]\nname = "mill"\nkind = "lsv2"\nhost = "10.0.0.6"\n'
    )
    with pytest.raises(ConfigError) as caught:
        parse_config(f"{machines}\n[netshare]\n{table}\n", base=tmp_path)
    assert caught.value.key == key


def test_a_nas_over_smb_in_the_config_keeps_its_password_out_of_sight(tmp_path: Path) -> None:
    machines = '[[machines]]\nname = "haas-1"\nkind = "haas_ngc"\nhost = "h"\nshare = "s1"\n'
    text = (
        f"{machines}[netshare]\n"
        'path = "smb://nas.local:4450/cnc/programs/new"\nusername = "dnc"\npassword = "s3cret-pw"\n'
    )
    config = parse_config(text, base=tmp_path).netshare
    assert config is not None
    assert config.path == ShareTarget(
        host="nas.local",
        port=4450,
        share="cnc",
        folder="programs/new",
        username="dnc",
        password="s3cret-pw",
    )
    assert "s3cret-pw" not in repr(config)
    in_url = parse_config(
        f'{machines}[netshare]\npath = "smb://dnc:s3cret%2Dpw@nas.local/cnc"\n', base=tmp_path
    ).netshare
    assert in_url is not None
    assert isinstance(in_url.path, ShareTarget)
    assert (in_url.path.username, in_url.path.password) == ("dnc", "s3cret-pw")
    with pytest.raises(ConfigError) as caught:  # a malformed URL is not repeated
        parse_config(f'{machines}[netshare]\npath = "smb://dnc:s3cret-pw@nas"\n', base=tmp_path)
    assert caught.value.key == "netshare.path"
    assert "s3cret-pw" not in str(caught.value)
    with pytest.raises(ConfigError) as caught:
        parse_config(f'{machines}[netshare]\npath = "smb://nas/c"\npassword = 12345', base=tmp_path)
    assert "12345" not in str(caught.value)


def test_netshare_config_defaults(tmp_path: Path) -> None:
    text = (
        '[[machines]]\nname = "haas-1"\nkind = "haas_ngc"\nhost = "h"\nshare = "s1"\n'
        '[[machines]]\nname = "haas-2"\nkind = "haas_ngc"\nhost = "h"\n'
        '[netshare]\npath = "nas"\narchive_every = 3600\n'
    )
    config = parse_config(text, base=tmp_path).netshare
    assert config is not None
    assert config.machines == ("haas-1",)  # every machine that has a share
    assert (config.archive_at, config.archive_every, config.collect) == (None, 3600.0, True)
    assert config.archive == (tmp_path / "archive" / "netshare").resolve()


def test_the_server_runs_the_net_share(
    tmp_path: Path, ngc: FleetThread, procs: Procs, db_url: str
) -> None:
    nas = tmp_path / "nas"
    nas.mkdir()
    text = server_config(ngc.fleet, poll_interval=0.5, library=tmp_path / "lib")
    text += f'\n[netshare]\npath = "{nas}"\narchive_every = 4\ninterval = 0.2\n'
    config = tmp_path / "shop.toml"
    config.write_text(text)
    key = create_key(config, db_url)
    base = serve(procs, config, db_url)
    shares = [ngc.fleet.sims[m].control.store.root for m in ("haas-1", "haas-2")]
    with httpx.Client(base_url=base, timeout=30) as client:

        def audit(action: str) -> list[dict[str, Any]]:
            params = {"action": action}
            rows: list[dict[str, Any]] = client.get(
                "/api/audit", headers=auth(key), params=params
            ).json()
            return rows

        wait_for("the baseline", lambda: len(audit("netshare.baseline")) == 2)
        (nas / "O01000.nc").write_text(PROGRAM)
        wait_for(
            "the program on both machines",
            lambda: all((s / "O01000.nc").is_file() for s in shares),
            describe=lambda: procs.log("server"),
        )
        assert [(s / "O01000.nc").read_text() for s in shares] == [PROGRAM, PROGRAM]
        ngc.call(lambda: ngc.fleet.sims["haas-1"].control.save_program(MADE_HERE))
        items = wait_for(
            "the machine's program in the inbox",
            lambda: client.get("/api/inbox", headers=auth(key)).json(),
            describe=lambda: procs.log("server"),
        )
        assert [(i["name"], i["machine"]) for i in items] == [("O02000.nc", "haas-1")]
        wait_for("the archive", lambda: not (nas / "O01000.nc").exists())
        assert [p.name for p in (tmp_path / "lib" / "archive" / "netshare").glob("*/*")] == [
            "O01000.nc"
        ]
        wait_for("the copies removed", lambda: not any((s / "O01000.nc").exists() for s in shares))
        pushes = audit("netshare.push")
        assert sorted((r["machine"], r["program"], r["result"]) for r in pushes) == [
            ("haas-1", "O01000.nc", "ok"),
            ("haas-2", "O01000.nc", "ok"),
        ]
        assert audit("netshare.archive")[0]["detail"]["removed_from"] == ["haas-1", "haas-2"]


@pytest.mark.interop
def test_a_machine_share_over_smb(
    tmp_path: Path, samba: Samba, sessions: sessionmaker[Session]
) -> None:
    """The same cycle when the machine's share is its Local Net Share over SMB (real Samba)."""
    folder = samba.folder / tmp_path.name  # the Samba server is shared by the module's tests
    folder.mkdir()
    (folder / "O00100.nc").write_text("%\nO00100 (OLD JOB)\nM30\n%\n")  # the machine's history
    url = f"smb://{samba.user}:{SMB_PASSWORD}@127.0.0.1:{samba.port}/UserData/{tmp_path.name}"
    text = f'[[machines]]\nname = "vf2"\nkind = "haas_ngc"\nhost = "127.0.0.1"\nshare = "{url}"\n'
    shop = parse_config(text, base=tmp_path)
    nas = tmp_path / "nas"
    nas.mkdir()
    clock = Clock(datetime(2026, 11, 23, 9, 0).astimezone())
    config = NetShareConfig(path=nas, machines=("vf2",), archive=tmp_path / "archive")
    machines = shares_of(shop.machines)
    net = NetShare(config, machines, tmp_path / "inbox", sessions, clock=clock, gate=open_gate)
    _scan_until(net, lambda _r: "vf2" in net.baselined, "the first look at the share")

    (nas / "O01000.nc").write_text(PROGRAM)
    _scan_until(net, lambda r: r.pushed == [("vf2", "O01000.nc")], "the push over SMB")
    assert (folder / "O01000.nc").read_text() == PROGRAM

    (folder / "O02000.nc").write_text(MADE_HERE)  # written at the control
    got = _scan_until(net, lambda r: bool(r.collected), "the collection over SMB")
    assert got.collected == [("vf2", "O02000.nc")]
    assert (tmp_path / "inbox" / "O02000.nc").read_text() == MADE_HERE

    clock.now = clock.now.replace(hour=18, minute=5)
    assert net.scan_sync().archived == ["O01000.nc"]
    assert sorted(p.name for p in folder.iterdir()) == ["O00100.nc", "O02000.nc"]
    (archived,) = _audit(sessions, "netshare.archive")
    assert archived.detail["removed_from"] == ["vf2"]


@pytest.mark.interop
def test_a_nas_over_smb(
    tmp_path: Path, samba: Samba, sessions: sessionmaker[Session], caplog: pytest.LogCaptureFixture
) -> None:
    """The NAS itself on a real Samba server, its login from the configuration's keys: polled,
    pushed from, archived (into the server's local archive) and emptied over SMB; the
    password is in no audit row and no log line."""
    caplog.set_level(logging.DEBUG)
    nas = samba.folder / f"nas-{tmp_path.name}"  # the Samba server is shared by the module
    nas.mkdir()
    machine_share = tmp_path / "vf2-share"
    machine_share.mkdir()
    url = f"smb://127.0.0.1:{samba.port}/UserData/{nas.name}"

    def make(password: str) -> NetShare:
        text = (
            f'[[machines]]\nname = "vf2"\nkind = "haas_ngc"\nhost = "127.0.0.1"\n'
            f'share = "{machine_share}"\n'
            f'[netshare]\npath = "{url}"\nusername = "{samba.user}"\npassword = "{password}"\n'
            f'archive = "{tmp_path / "archive"}"\n'
        )
        shop = parse_config(text, base=tmp_path)
        assert shop.netshare is not None
        machines = shares_of(shop.machines)
        return NetShare(
            shop.netshare, machines, tmp_path / "inbox", sessions, clock=clock, gate=open_gate
        )

    clock = Clock(datetime(2026, 11, 23, 9, 0).astimezone())
    wrong = make("not-the-password")
    assert wrong.scan_sync().pushed == []  # a NAS that refuses the login is away, no crash
    away = [r.getMessage() for r in caplog.records if "NAS is away" in r.getMessage()]
    (message,) = away
    assert url in message

    net = make(SMB_PASSWORD)
    _scan_until(net, lambda _r: "vf2" in net.baselined, "the first look at the share")
    (nas / "O01000.nc").write_text(PROGRAM)  # someone drops a program on the NAS
    _scan_until(net, lambda r: r.pushed == [("vf2", "O01000.nc")], "the push from the SMB NAS")
    assert (machine_share / "O01000.nc").read_text() == PROGRAM
    (push,) = _audit(sessions, "netshare.push")
    assert push.detail["source"] == f"{url}/O01000.nc"

    clock.now = clock.now.replace(hour=18, minute=5)
    assert net.scan_sync().archived == ["O01000.nc"]
    assert list(nas.iterdir()) == []  # emptied over SMB
    assert (tmp_path / "archive" / "2026-11-23" / "O01000.nc").read_text() == PROGRAM
    assert not (machine_share / "O01000.nc").exists()  # the unedited copy left the share
    (archived,) = _audit(sessions, "netshare.archive")
    assert (archived.result, archived.detail["removed_from"]) == ("ok", ["vf2"])

    with sessions() as session:
        rows = session.scalars(select(AuditEntry)).all()
        trail = json.dumps([(r.action, r.detail) for r in rows])
    assert SMB_PASSWORD not in trail
    assert all(SMB_PASSWORD not in r.getMessage() for r in caplog.records)


@on("sqlite")
def test_our_own_send_never_comes_back_as_a_reception(
    tmp_path: Path, ngc: FleetThread, sessions: sessionmaker[Session]
) -> None:
    """A send to a Haas NGC writes the program into its share, which the net share collects
    from: it came back as a new inbox item, audited as a receive by the machine. What a job of
    ours wrote (name and content) is ours; the same name with the operator's edit is not."""
    net = _make(tmp_path, ngc, sessions, Clock(datetime(2026, 11, 23, 9, 0).astimezone()))
    _scan_until(net, lambda _r: len(net.baselined) == 2, "the first look at the shares")
    shop = parse_config(server_config(ngc.fleet, library=tmp_path / "lib"), base=tmp_path)
    with sessions.begin() as session:
        jobs.sync_machines(session, shop.machines)
        version, _new = library.add_version(session, "O01000.nc", PROGRAM.encode(), author="ann")
        jobs.enqueue(session, JobKind.SEND, "haas-1", actor="ann", version=version)
    # the send itself, as the machine's task runs it: into the control's share
    connector = connector_for(next(m for m in shop.machines if m.name == "haas-1"))
    asyncio.run(connector.send("O01000.nc", PROGRAM.encode(), lambda _d, _t: None))
    root = ngc.fleet.sims["haas-1"].control.store.root
    assert (root / "O01000.nc").read_bytes() == PROGRAM.encode()
    for _ in range(3):  # a file is taken once it is the same in two scans
        assert net.scan_sync().collected == []
    with sessions() as session:
        assert session.scalars(select(Received)).all() == []
    assert _audit(sessions, "program.receive") == []
    # the operator edits it at the control: now it is the machine's work
    (root / "O01000.nc").write_text(EDITED)
    got = _scan_until(net, lambda r: bool(r.collected), "the edited copy")
    assert got.collected == [("haas-1", "O01000.nc")]


@on("sqlite")
def test_a_draft_never_reaches_a_released_only_machines_share(
    tmp_path: Path, ngc: FleetThread, sessions: sessionmaker[Session]
) -> None:
    """The net share copied a draft, an edit after release and a file the library never saw
    to every machine: what reaches a share now gets the decision a send gets (policy.authorize)."""
    net = _make(tmp_path, ngc, sessions, Clock(datetime(2026, 11, 23, 9).astimezone()), True)
    _scan_until(net, lambda _r: len(net.baselined) == 2, "the first look at the shares")
    with sessions.begin() as session:
        library.add_version(session, "O01000.nc", PROGRAM.encode(), author="ann")  # a draft
    (tmp_path / "nas" / "O01000.nc").write_text(PROGRAM)
    (tmp_path / "nas" / "O05000.nc").write_text(MADE_HERE.replace("O02000", "O05000"))
    got = _scan_until(net, lambda r: len(r.pushed) == 2, "the pushes to haas-2")
    assert sorted(got.pushed) == [("haas-2", "O01000.nc"), ("haas-2", "O05000.nc")]
    assert sorted({(m, n) for m, n, _why in got.refused}) == [
        ("haas-1", "O01000.nc"),
        ("haas-1", "O05000.nc"),
    ]
    root = ngc.fleet.sims["haas-1"].control.store.root
    assert not (root / "O01000.nc").exists()
    assert not (root / "O05000.nc").exists()
    refused = [r for r in _audit(sessions, "netshare.push") if r.result == "refused"]
    reasons = {r.program: r.detail["error"] for r in refused}
    assert "version 1 is draft" in reasons["O01000.nc"], reasons
    assert "no version of O05000.nc" in reasons["O05000.nc"], reasons
    assert net.scan_sync().pushed == []  # asked again, audited once
    assert len([r for r in _audit(sessions, "netshare.push") if r.result == "refused"]) == 2
    # released: now it goes
    with sessions.begin() as session:
        library.release(session, "O01000.nc", 1, actor="ann")
    released = _scan_until(net, lambda r: bool(r.pushed), "the released version")
    assert released.pushed == [("haas-1", "O01000.nc")]
    assert (root / "O01000.nc").read_bytes() == PROGRAM.encode()
    # an edit of the released program on the NAS is no version: refused again
    (tmp_path / "nas" / "O01000.nc").write_text(EDITED)
    edited = _scan_until(net, lambda r: bool(r.pushed), "the edit to haas-2")
    assert edited.pushed == [("haas-2", "O01000.nc")]
    assert (root / "O01000.nc").read_bytes() == PROGRAM.encode()
