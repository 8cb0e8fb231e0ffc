"""Machine leases on the real databases: even spread, failover after expiry, hand-over
without two owners, pinned machines, and the rendezvous assignment's properties."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path

from hypothesis import given
from hypothesis import strategies as st
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.machines.leases import Leases, assign
from tests.server.harness import Procs, serve

MACHINES = {f"m{i:02d}": frozenset[str]() for i in range(20)}


def settle(servers: list[Leases], rounds: int = 3) -> None:
    """Renew every server a few times, checking that no machine ever has two holders."""
    for _ in range(rounds):
        for server in servers:
            server.renew()
            held = Counter(m for s in servers for m in s.serving())
            assert all(n == 1 for n in held.values()), held


def until(condition: Callable[[], bool], timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "condition not met in time"
        time.sleep(0.05)


def test_two_servers_split_twenty_machines_evenly(sessions: sessionmaker[Session]) -> None:
    a = Leases(sessions, "dnc-1", MACHINES, ttl=5)
    b = Leases(sessions, "dnc-2", MACHINES, ttl=5)
    a.renew()  # the first server alone takes everything at once
    assert len(a.held) == 20
    settle([a, b])  # the second comes: the first hands half over, no live lease is taken
    assert len(a.held) == len(b.held) == 10
    assert a.held | b.held == set(MACHINES)


def test_a_dead_server_loses_its_machines_after_the_lease(sessions: sessionmaker[Session]) -> None:
    a = Leases(sessions, "dnc-1", MACHINES, ttl=1.0)
    b = Leases(sessions, "dnc-2", MACHINES, ttl=1.0)
    settle([a, b])
    theirs = set(a.held)
    epochs = b.view()
    before = {row.machine: row.epoch for row in epochs.leases}
    started = time.monotonic()
    # dnc-1 stops renewing (killed); dnc-2 keeps going and takes them once they expire
    until(lambda: len(b.renew().held) == 20)
    took = time.monotonic() - started
    assert took < 1.0 + 1.0  # the lease plus the grace a free machine waits for its assignee
    after = {row.machine: row.epoch for row in b.view().leases}
    assert all(after[m] == before[m] + 1 for m in theirs)  # a new owner, a new epoch
    # the dead server, back from a pause, finds nothing to renew
    holding = a.renew()
    assert holding.lost == theirs
    assert not (a.held & b.held)


def test_a_third_server_takes_its_share_by_hand_over(sessions: sessionmaker[Session]) -> None:
    servers = [Leases(sessions, f"dnc-{i}", MACHINES, ttl=5) for i in (1, 2)]
    settle(servers)
    servers.append(Leases(sessions, "dnc-3", MACHINES, ttl=5))
    settle(servers, rounds=3)
    assert sorted(len(s.held) for s in servers) == [6, 7, 7]
    # with nothing changing, another round moves nothing
    before = [set(s.held) for s in servers]
    settle(servers, rounds=2)
    assert [set(s.held) for s in servers] == before


def test_a_busy_machine_is_not_handed_over(sessions: sessionmaker[Session]) -> None:
    a = Leases(sessions, "dnc-1", MACHINES, ttl=5)
    b = Leases(sessions, "dnc-2", MACHINES, ttl=5)
    a.renew()
    for _ in range(3):
        a.renew(can_hand_over=lambda m: m != "m00")  # m00 runs a job on dnc-1
        b.renew()
    assert "m00" in a.held
    assert not (a.held & b.held)


def test_a_pinned_machine_never_moves(sessions: sessionmaker[Session]) -> None:
    machines = {**MACHINES, "serial-haas": frozenset({"dnc-1"})}
    a = Leases(sessions, "dnc-1", machines, ttl=1.0)
    b = Leases(sessions, "dnc-2", machines, ttl=1.0)
    settle([a, b])
    assert "serial-haas" in a.held
    deadline = time.monotonic() + 2.5  # dnc-1 is dead for longer than a lease
    while time.monotonic() < deadline:
        b.renew()
        time.sleep(0.1)
    assert "serial-haas" not in b.held
    assert len(b.held) == 20


def test_a_clean_stop_frees_the_machines_at_once(sessions: sessionmaker[Session]) -> None:
    a = Leases(sessions, "dnc-1", MACHINES, ttl=30)
    b = Leases(sessions, "dnc-2", MACHINES, ttl=30)
    settle([a, b])
    a.release_all()
    b.renew()  # no 30 s wait: the rows are free and dnc-1 has left
    assert len(b.held) == 20
    assert [s.name for s in b.view().servers] == ["dnc-2"]


names = st.lists(st.text("abcdefgh", min_size=1, max_size=4), min_size=1, max_size=5, unique=True)


@given(servers=names, count=st.integers(0, 60), pinned=st.lists(st.integers(0, 59), max_size=10))
def test_assignment_is_even_deterministic_and_respects_pins(
    servers: list[str], count: int, pinned: list[int]
) -> None:
    live = frozenset(servers)
    first = servers[0]
    machines = {
        f"m{i}": frozenset({first}) if i in pinned else frozenset[str]() for i in range(count)
    }
    out = assign(machines, live)
    assert out == assign(dict(reversed(machines.items())), live)  # order does not matter
    assert set(out) == set(machines)
    assert all(out[m] == first for m, pins in machines.items() if pins)
    if not any(machines.values()):
        loads = Counter(out.values())
        spread = [loads.get(s, 0) for s in servers]
        assert max(spread) - min(spread) <= 1


def test_a_second_server_on_one_sqlite_file_is_one_line(tmp_path: Path, procs: Procs) -> None:
    config = tmp_path / "shop.toml"
    config.write_text(f'[library]\npath = "{tmp_path / "lib"}"\n')
    db = f"sqlite:///{tmp_path / 'shop.db'}"
    serve(procs, config, db)
    second = subprocess.run(
        [
            sys.executable,
            "-m",
            "opendnc.cli.main",
            "serve",
            "--config",
            str(config),
            "--db",
            db,
            "--bind",
            "127.0.0.1:0",
        ],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert second.returncode == 1
    lines = second.stderr.strip().splitlines()
    assert len(lines) == 1, second.stderr
    assert "SQLite serves one server: use PostgreSQL for several" in lines[0]
    assert f"pid {procs.procs['server'].pid}" in lines[0]
    # killed, it leaves no lock behind: the next server starts
    procs.stop("server", signal.SIGKILL)
    serve(procs, config, db, name="again")


def test_cluster_status_shows_servers_and_their_machines(
    tmp_path: Path, sessions: sessionmaker[Session], db_url: str
) -> None:
    # a long lease: two CLI starts on a loaded machine take seconds
    a = Leases(sessions, "dnc-1", MACHINES, ttl=120, url="http://127.0.0.1:8001/")
    b = Leases(sessions, "dnc-2", MACHINES, ttl=120)
    settle([a, b])
    config = tmp_path / "shop.toml"
    config.write_text(f'[library]\npath = "{tmp_path / "lib"}"\n')
    args = [sys.executable, "-m", "opendnc.cli.main", "cluster", "status"]
    args += ["--config", str(config), "--db", db_url]
    shown = subprocess.run([*args, "--json"], capture_output=True, text=True, timeout=60)
    assert shown.returncode == 0, shown.stderr
    view = json.loads(shown.stdout)
    assert [(s["name"], s["machines"], s["alive"]) for s in view["servers"]] == [
        ("dnc-1", 10, True),
        ("dnc-2", 10, True),
    ]
    assert sorted(row["machine"] for row in view["leases"] if row["live"]) == sorted(MACHINES)
    table = subprocess.run(args, capture_output=True, text=True, timeout=60)
    assert table.returncode == 0, table.stderr
    (row,) = [line for line in table.stdout.splitlines() if line.strip().startswith("dnc-1")]
    assert "http://127.0.0.1:8001/" in row
    assert row.split()[-1] == "10", table.stdout
