"""The net share audits an outcome once, not once a scan: a name no share can take is skipped
with one row per machine and content, a share that stays away is one failed row, and a
restart remembers both (docs/server.md#hybrid-net-share). Plain folders stand in for the
machines' shares: the push does not talk to the control."""

from __future__ import annotations

import json
from collections.abc import Iterator
from datetime import datetime
from pathlib import Path

import pytest
from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.config.shop import NetShareConfig, parse_config
from opendnc.server.kinds.haas_ngc import HaasNgcMachine
from opendnc.server.netshare.share import MAX_PUSH_NAME, NetShare, ScanReport
from opendnc.server.store.db import make_engine, make_sessions, migrate
from opendnc.server.store.models import AuditEntry

PROGRAM = b"%\nO01000 (BRACKET)\nG00 X0. Y0.\nM30\n%\n"
LONG = "L" * 251 + ".nc"  # 254 bytes: a NAS holds it, a share's temporary copy cannot


def open_gate(machine: HaasNgcMachine, name: str, data: bytes) -> str | None:
    """Every file may go everywhere: these tests are of names, not of the policy."""
    return None


@pytest.fixture
def sessions(tmp_path: Path) -> Iterator[sessionmaker[Session]]:
    engine = make_engine(f"sqlite:///{tmp_path / 'db.sqlite'}")
    migrate(engine)
    yield make_sessions(engine)
    engine.dispose()


def _net(tmp_path: Path, sessions: sessionmaker[Session], *, restart: bool = False) -> NetShare:
    lines = [
        "[library]",
        f"path = {json.dumps(str(tmp_path / 'lib'))}",
        f"inbox = {json.dumps(str(tmp_path / 'inbox'))}",
    ]
    for n in (1, 2):
        share = tmp_path / f"share-{n}"
        if not restart:
            share.mkdir()
        lines += [
            "[[machines]]",
            f'name = "haas-{n}"',
            'kind = "haas_ngc"',
            'host = "127.0.0.1"',
            f"share = {json.dumps(str(share))}",
        ]
    shop = parse_config("\n".join(lines) + "\n", base=tmp_path)
    (tmp_path / "nas").mkdir(exist_ok=True)
    config = NetShareConfig(
        path=tmp_path / "nas",
        machines=("haas-1", "haas-2"),
        archive=tmp_path / "archive",
        archive_at=(18, 0),
        interval=0.05,
    )
    machines = {m.name: m for m in shop.machines}
    clock = datetime(2026, 11, 23, 9, 0).astimezone  # never 18:00: no archive here
    return NetShare(
        config, machines, tmp_path / "inbox", sessions, clock=lambda: clock(), gate=open_gate
    )


def _pushes(sessions: sessionmaker[Session]) -> list[tuple[str | None, str | None, str]]:
    with sessions() as session:
        rows = session.scalars(
            select(AuditEntry).where(AuditEntry.action == "netshare.push").order_by(AuditEntry.id)
        ).all()
        return [(r.machine, r.program, r.result) for r in rows]


def _scans(net: NetShare, count: int) -> ScanReport:
    total = ScanReport()
    for _ in range(count):
        report = net.scan_sync()
        total.pushed += report.pushed
        total.failed += report.failed
    return total


def test_a_name_too_long_to_push_is_skipped_once_per_machine_not_once_a_scan(
    tmp_path: Path, sessions: sessionmaker[Session]
) -> None:
    assert MAX_PUSH_NAME < len(LONG.encode()) <= 255
    net = _net(tmp_path, sessions)
    (tmp_path / "nas" / LONG).write_bytes(PROGRAM)
    (tmp_path / "nas" / "O01000.nc").write_bytes(PROGRAM)
    report = _scans(net, 8)  # the first scan only sees the files; seven push or skip
    assert sorted(report.pushed) == [("haas-1", "O01000.nc"), ("haas-2", "O01000.nc")]
    assert len(report.failed) == 14  # each scan says so, the trail once
    assert "longer than 240 bytes" in report.failed[0][2]
    assert sorted(_pushes(sessions)) == [
        ("haas-1", LONG, "skipped"),
        ("haas-1", "O01000.nc", "ok"),
        ("haas-2", LONG, "skipped"),
        ("haas-2", "O01000.nc", "ok"),
    ]
    assert not (tmp_path / "share-1" / LONG).exists()
    # a restart reads the trail: still skipped, no new row
    _scans(_net(tmp_path, sessions, restart=True), 4)
    assert len(_pushes(sessions)) == 4
    # new content under the name is a new outcome: one row per machine again
    (tmp_path / "nas" / LONG).write_bytes(PROGRAM + b"(EDITED)\n")
    _scans(net, 4)
    assert [p for p in _pushes(sessions)[4:]] == [
        ("haas-1", LONG, "skipped"),
        ("haas-2", LONG, "skipped"),
    ]


def test_a_share_that_stays_away_is_one_failed_row_then_one_ok_row(
    tmp_path: Path, sessions: sessionmaker[Session]
) -> None:
    net = _net(tmp_path, sessions)
    away = tmp_path / "share-2-unmounted"
    (tmp_path / "share-2").rename(away)
    (tmp_path / "nas" / "O01000.nc").write_bytes(PROGRAM)
    report = _scans(net, 6)
    assert len(report.failed) == 5  # tried at every scan after the first
    assert _pushes(sessions) == [
        ("haas-1", "O01000.nc", "ok"),
        ("haas-2", "O01000.nc", "failed"),
    ]
    _scans(_net(tmp_path, sessions, restart=True), 3)  # a restart: the same failure, no new row
    assert len(_pushes(sessions)) == 2
    away.rename(tmp_path / "share-2")
    assert _scans(net, 1).pushed == [("haas-2", "O01000.nc")]
    assert _pushes(sessions)[2:] == [("haas-2", "O01000.nc", "ok")]
    assert (tmp_path / "share-2" / "O01000.nc").read_bytes() == PROGRAM
