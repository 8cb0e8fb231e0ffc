"""One DNC server polling N virtual machines: server CPU, status age, missed polls.

For each fleet size, ``opendnc sim fleet`` starts N controls in one process (half virtual
TNCs over LSV2, half virtual Haas NGCs over MDC) and writes the server's configuration; then
``opendnc serve`` polls them every second. After every machine is online the benchmark reads
``/api/machines`` once a second for ``--seconds`` and reports:

- server CPU: user + system time of the server process over the window, in cores;
- status age: how old each machine's last status is when read (p50, p99, max);
- missed polls: readings where a status was older than twice the poll interval;
- the longest stall of the server's event loop in the window, and how much of it the loop's
  thread waited for a CPU (docs/server.md#event-loop-stalls).

Target (the server issue): 500 machines on this 2-core machine, p99 status age under 2 s and
the server under one core. The fleet process runs on the same two cores and costs CPU too.

With ``--servers K`` (K >= 2) the fleet is served by K ``opendnc serve`` processes on one
fresh PostgreSQL database (``--pg``; docs/server.md#several-servers): the figures are per
server (its CPU over ``--quiet`` seconds that nobody reads the API, and then while the
benchmark reads every server's list about once a second; the status age of every machine as
that server shows it, polled there ("own") or read from the others' rows), and then one server
is SIGKILLed: the takeover time is from the
kill until every machine's lease is held by a live server again, and the status time until
every machine shows a fresh status (younger than twice the poll) on a surviving server. The
status age is what a user of that server's API sees: the age of each machine's status as
``/api/machines`` answers it, when the answer has arrived; a machine that server shows offline
or without a status has no age and is counted apart ("not shown"). The PostgreSQL backends
of the benchmark's database are on the same cores (a local database): their CPU is given too.

    .venv/bin/python benchmarks/fleet.py                    # N = 50, 200, 500
    .venv/bin/python benchmarks/fleet.py --sizes 20 --seconds 5
    .venv/bin/python benchmarks/fleet.py --sizes 1000 --servers 2
    .venv/bin/python benchmarks/fleet.py --sizes 100 --mtconnect 100   # agents' devices
    .venv/bin/python benchmarks/fleet.py --mtconnect 200 --opcua 200   # 400, and 400 TNCs

With ``--mtconnect M`` M machines of each fleet are devices of one virtual MTConnect agent
running scripted cycles (the server follows one sample stream per machine); with ``--opcua U``
U machines are machine tools of one virtual OPC UA server (umati objects, scripted cycles; the
server subscribes to each); the rest are TNCs and Haas NGCs as above. Without ``--sizes`` the
size is then M + U, and the same number of TNCs (LSV2) is measured after it: the server's CPU
per machine (millicores) is printed beside the LSV2 figure (``--no-baseline`` skips that run),
with the status age of each kind.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
import uuid
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

TICKS = os.sysconf("SC_CLK_TCK")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS  # utime + stime


def _cli(*args: str, log: Path | None = None, **kwargs: Any) -> subprocess.Popen[bytes]:
    # A long run logs more than a pipe holds: to a file then, or the child blocks writing.
    err: Any = subprocess.PIPE if log is None else log.open("ab")
    try:
        return subprocess.Popen(
            [sys.executable, "-m", "opendnc.cli.main", *args],
            start_new_session=True,
            stdout=subprocess.DEVNULL,
            stderr=err,
            **kwargs,
        )
    finally:
        if log is not None:
            err.close()


def _stop(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def _get(url: str, key: str) -> Any:
    request = urllib.request.Request(url, headers={"Authorization": f"Bearer {key}"})
    with urllib.request.urlopen(request, timeout=30) as reply:
        return json.load(reply)


def stalls(base: str, since: float) -> list[dict[str, Any]]:
    """The server's event-loop stalls (``/api/health/loop``) from ``since`` (a time.time())
    on, longest first: each with ``seconds`` late, ``run`` (its thread ran) and ``wait``
    (waited for a CPU), docs/server.md#event-loop-stalls."""
    with urllib.request.urlopen(base + "/api/health/loop", timeout=30) as reply:
        report = json.load(reply)
    start = datetime.fromtimestamp(since, UTC)
    recent = [s for s in report["recent_stalls"] if datetime.fromisoformat(s["at"]) >= start]
    return sorted(recent, key=lambda s: -s["seconds"])


def _percentile(values: list[float], p: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(p / 100 * len(ordered)))]


def _counts(n: int, mtconnect: int, opcua: int = 0, tnc_only: bool = False) -> list[str]:
    """The fleet's arguments for ``n`` machines, ``mtconnect`` of them behind a virtual agent,
    ``opcua`` of them on a virtual OPC UA server and the rest half virtual TNCs, half virtual
    Haas NGCs (all TNCs with ``tnc_only``)."""
    agent = min(n, mtconnect)
    served = min(n - agent, opcua)
    rest = n - agent - served
    tnc = rest if tnc_only else rest // 2
    return [
        "--tnc", str(tnc), "--haas", str(rest - tnc),
        "--mtconnect", str(agent), "--opcua", str(served),
    ]  # fmt: skip


def _kind(name: str) -> str:
    """The kind of a fleet machine by its name (``opc-3``: opcua; ``mtc-3``: mtconnect)."""
    return {"opc": "opcua", "mtc": "mtconnect", "tnc": "lsv2"}.get(name.split("-")[0], "other")


def run_size(
    n: int,
    seconds: float,
    poll: float,
    folder: Path,
    mtconnect: int = 0,
    opcua: int = 0,
    tnc_only: bool = False,
    opcua_servers: int = 1,
) -> dict[str, Any]:
    """Measure one fleet size; returns the figures."""
    config = folder / f"fleet-{n}-{mtconnect}-{opcua}-{int(tnc_only)}.toml"
    fleet = _cli(
        "sim",
        "fleet",
        *_counts(n, mtconnect, opcua, tnc_only),
        *(["--opcua-servers", str(opcua_servers)] if opcua and not tnc_only else []),
        "--config-out",
        str(config),
        "--poll",
        str(poll),
        "--root",
        str(folder / f"machines-{config.stem}"),
    )
    server = None
    try:
        deadline = time.monotonic() + 120
        while not config.exists():
            if fleet.poll() is not None or time.monotonic() > deadline:
                raise SystemExit(f"fleet did not start: {fleet.stderr.read().decode()}")  # type: ignore[union-attr]
            time.sleep(0.1)
        db = f"sqlite:///{folder / f'{config.stem}.db'}"
        deadline = time.monotonic() + 600  # the server's start and every machine online
        key = _viewer_key(config, db)
        # The server's port is picked once the fleet holds all of its ports (picked before,
        # a virtual TNC could take it, and the benchmark would read LSV2 as HTTP).
        port = _free_port()
        server = _cli("serve", "--config", str(config), "--db", db, "--bind", f"127.0.0.1:{port}")
        url = f"http://127.0.0.1:{port}/api/machines"
        started = time.monotonic()
        while True:
            try:
                machines = _get(url, key)
                if len(machines) == n and all(m["online"] and m["status"] for m in machines):
                    break
            except OSError:
                pass
            if server.poll() is not None or time.monotonic() > deadline:
                raise SystemExit(f"machines did not come online for N={n}")
            time.sleep(0.5)
        online_after = time.monotonic() - started
        cpu0, t0, wall0 = _cpu_seconds(server.pid), time.monotonic(), time.time()
        ages: list[float] = []
        by_kind: dict[str, list[float]] = {}
        missed = readings = 0
        errors: dict[str, int] = {}
        while time.monotonic() - t0 < seconds:
            tick = time.monotonic()
            listed = _get(url, key)
            now = datetime.now(UTC)  # after the answer: no status is younger than this
            for m in listed:
                readings += 1
                if m["status"] is None or not m["online"]:
                    missed += 1
                    error = m["last_error"] or "not polled yet"
                    errors[error] = errors.get(error, 0) + 1
                    continue
                age = (now - datetime.fromisoformat(m["status"]["at"])).total_seconds()
                ages.append(age)
                by_kind.setdefault(_kind(m["name"]), []).append(age)
                missed += age > 2 * poll
            # A random phase: sampling in step with the polls would always see the same age.
            time.sleep(max(0.0, random.uniform(0.5, 1.5) - (time.monotonic() - tick)))
        cpu = (_cpu_seconds(server.pid) - cpu0) / (time.monotonic() - t0)
        longest = (stalls(f"http://127.0.0.1:{port}", wall0) or [None])[0]
        return {
            "n": n,
            "online_s": online_after,
            "cpu_cores": cpu,
            "age_p50": _percentile(ages, 50),
            "age_p99": _percentile(ages, 99),
            "age_max": max(ages),
            "p99_by_kind": {k: _percentile(a, 99) for k, a in sorted(by_kind.items())},
            "missed": missed,
            "readings": readings,
            "errors": errors,
            "stall": longest,
        }
    finally:
        if server is not None:
            _stop(server)
        _stop(fleet)


def _stall(stall: dict[str, Any] | None) -> str:
    if stall is None:
        return "none of 50 ms"
    wait = "?" if stall["wait"] is None else f"{stall['wait'] * 1000:.0f}"
    return f"{stall['seconds'] * 1000:.0f} ms ({wait} ms)"


def _viewer_key(config: Path, db: str) -> str:
    """A viewer API key made with the CLI against the fleet's config and database."""
    argv = ["keys", "create", "--role", "viewer", "--config", str(config), "--db", db]
    cmd = [sys.executable, "-m", "opendnc.cli.main", *argv]
    done = subprocess.run(cmd, capture_output=True, text=True, check=True)
    return done.stdout.strip()


def _start_fleet(
    n: int, poll: float, folder: Path, mtconnect: int = 0
) -> tuple[subprocess.Popen[bytes], Path]:
    config = folder / f"fleet-{n}.toml"
    fleet = _cli(
        "sim",
        "fleet",
        *_counts(n, mtconnect),
        "--config-out",
        str(config),
        "--poll",
        str(poll),
        "--root",
        str(folder / f"machines-{n}"),
    )
    deadline = time.monotonic() + 180
    while not config.exists():
        if fleet.poll() is not None or time.monotonic() > deadline:
            raise SystemExit(f"fleet did not start: {fleet.stderr.read().decode()}")  # type: ignore[union-attr]
        time.sleep(0.1)
    return fleet, config


def _database(pg: str, create: bool, name: str) -> None:
    from sqlalchemy import create_engine, text

    admin = create_engine(pg, isolation_level="AUTOCOMMIT")
    try:
        with admin.connect() as conn:
            if create:
                conn.execute(text(f'CREATE DATABASE "{name}"'))
            else:
                conn.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
    finally:
        admin.dispose()


def _backends(pg: str, name: str) -> list[int]:
    """The process ids of the PostgreSQL backends connected to database ``name`` now."""
    from sqlalchemy import create_engine, text

    admin = create_engine(pg)
    try:
        with admin.connect() as conn:
            query = text("SELECT pid FROM pg_stat_activity WHERE datname = :name")
            return [int(pid) for pid in conn.execute(query, {"name": name}).scalars()]
    finally:
        admin.dispose()


def _cpu_total(pids: list[int]) -> float | None:
    """The CPU seconds of ``pids`` together (those still running); None if the database
    runs elsewhere (its processes are not this machine's)."""
    total, seen = 0.0, 0
    for pid in pids:
        try:
            total += _cpu_seconds(pid)
            seen += 1
        except OSError:
            continue
    return total if seen else None


def _ages(base: str, key: str, poll: float) -> tuple[dict[str, float], int]:
    """Each machine's status age as the server at ``base`` shows it now (machine -> seconds),
    and how many it shows offline or without a status."""
    listed = _get(base + "/api/machines", key)
    now = datetime.now(UTC)  # after the answer: the age the reader has in hand
    ages, missing = {}, 0
    for m in listed:
        if m["status"] is None or not m["online"]:
            missing += 1
            continue
        ages[m["name"]] = (now - datetime.fromisoformat(m["status"]["at"])).total_seconds()
    return ages, missing


def _cpus(procs: dict[str, subprocess.Popen[bytes]], fleet: int, pg: list[int]) -> dict[str, Any]:
    """CPU seconds so far of each server, the fleet's process and the database backends."""
    return {
        "servers": {s: _cpu_seconds(p.pid) for s, p in procs.items()},
        "fleet": _cpu_seconds(fleet),
        "pg": _cpu_total(pg),
        "at": time.monotonic(),
    }


def _cores(before: dict[str, Any], after: dict[str, Any]) -> dict[str, Any]:
    """The cores used between two :func:`_cpus`."""
    span = after["at"] - before["at"]
    return {
        "servers": {s: (after["servers"][s] - c) / span for s, c in before["servers"].items()},
        "fleet": (after["fleet"] - before["fleet"]) / span,
        "pg": None if before["pg"] is None else ((after["pg"] or 0.0) - before["pg"]) / span,
    }


def run_cluster(
    n: int,
    servers: int,
    seconds: float,
    poll: float,
    folder: Path,
    pg: str,
    lease: float,
    logs: Path,
    quiet: float = 10.0,
) -> dict[str, Any]:
    """One fleet of ``n`` machines served by ``servers`` servers on one PostgreSQL database:
    ``quiet`` seconds nobody reads the API (what serving and sharing cost), then ``seconds``
    of reading every server's ``/api/machines`` about once a second."""
    name = f"lease_bench_{uuid.uuid4().hex[:10]}"
    _database(pg, True, name)
    db = pg.rsplit("/", 1)[0] + f"/{name}"
    fleet, config = _start_fleet(n, poll, folder)
    procs: dict[str, subprocess.Popen[bytes]] = {}
    try:
        text = config.read_text().replace("[server]\n", f"[server]\nlease_seconds = {lease}\n", 1)
        config.write_text(text)
        key = _viewer_key(config, db)
        bases = {}
        for i in range(1, servers + 1):
            port = _free_port()
            procs[f"dnc-{i}"] = _cli(
                "serve", "--config", str(config), "--db", db, "--name", f"dnc-{i}",
                "--bind", f"127.0.0.1:{port}", log=logs / f"dnc-{i}.log",
            )  # fmt: skip
            bases[f"dnc-{i}"] = f"http://127.0.0.1:{port}"
        started = time.monotonic()
        deadline = started + 600
        missing: dict[str, int | str] = {}
        while True:
            for s, b in bases.items():
                try:
                    missing[s] = _ages(b, key, poll)[1]
                except OSError as exc:
                    missing[s] = str(exc)
            if all(m == 0 for m in missing.values()):
                break
            if any(p.poll() is not None for p in procs.values()) or time.monotonic() > deadline:
                raise SystemExit(f"N={n}: machines not online (per server: {missing})")
            time.sleep(1.0)
        online_after = time.monotonic() - started
        view = _get(bases["dnc-1"] + "/api/cluster", key)
        spread = {s["name"]: s["machines"] for s in view["servers"]}
        owners = {r["machine"]: r["owner"] for r in view["leases"]}
        backends = _backends(pg, name)
        c0 = _cpus(procs, fleet.pid, backends)
        time.sleep(quiet)
        c1 = _cpus(procs, fleet.pid, backends)
        load_quiet = os.getloadavg()[0]
        ages: dict[str, list[float]] = {s: [] for s in procs}
        own: dict[str, list[float]] = {s: [] for s in procs}  # machines that server polls
        others: dict[str, list[float]] = {s: [] for s in procs}  # read from the database
        unshown = dict.fromkeys(procs, 0)
        while time.monotonic() - c1["at"] < seconds:
            tick = time.monotonic()
            for s, base in bases.items():
                found, missing_now = _ages(base, key, poll)
                ages[s] += found.values()
                own[s] += [a for m, a in found.items() if owners.get(m) == s]
                others[s] += [a for m, a in found.items() if owners.get(m) != s]
                unshown[s] += missing_now
            time.sleep(max(0.0, random.uniform(0.5, 1.5) - (time.monotonic() - tick)))
        c2 = _cpus(procs, fleet.pid, backends)
        load = os.getloadavg()[0]  # at the end of the window, before the kill
        cores_quiet, cores = _cores(c0, c1), _cores(c1, c2)
        moved = sum(
            r["owner"] != owners.get(r["machine"])
            for r in _get(bases["dnc-1"] + "/api/cluster", key)["leases"]
        )
        # the failover: SIGKILL the last server
        victim = f"dnc-{servers}"
        os.killpg(procs[victim].pid, signal.SIGKILL)
        procs[victim].wait()
        killed = time.monotonic()
        survivor = bases["dnc-1"]
        takeover = status_back = None
        while time.monotonic() - killed < 120 and (takeover is None or status_back is None):
            if takeover is None:
                leases = _get(survivor + "/api/cluster", key)["leases"]
                held = [r for r in leases if r["live"] and not r["machine"].startswith("@")]
                if len(held) == n and all(r["owner"] != victim for r in held):
                    takeover = time.monotonic() - killed
            if takeover is not None and status_back is None:
                # (right after the kill the dead server's rows are still young: not news)
                fresh, missing = _ages(survivor, key, poll)
                if not missing and max(fresh.values()) < 2 * poll:
                    status_back = time.monotonic() - killed
            time.sleep(0.1)
        return {
            "n": n,
            "servers": servers,
            "online_s": online_after,
            "spread": spread,
            "cpu": cores["servers"],
            "cpu_quiet": cores_quiet["servers"],
            "quiet": quiet,
            "load_quiet": load_quiet,
            "moved": moved,
            "own_p99": {s: _percentile(a, 99) if a else None for s, a in own.items()},
            "others_p99": {s: _percentile(a, 99) if a else None for s, a in others.items()},
            "p50": {s: _percentile(a, 50) for s, a in ages.items()},
            "p99": {s: _percentile(a, 99) for s, a in ages.items()},
            "max": {s: max(a) for s, a in ages.items()},
            "readings": {s: len(a) + unshown[s] for s, a in ages.items()},
            "unshown": unshown,
            "pg_cpu": cores["pg"],
            "pg_cpu_quiet": cores_quiet["pg"],
            "takeover": takeover,
            "status_back": status_back,
            "lease": lease,
            "fleet_cpu": cores["fleet"],
            "fleet_cpu_quiet": cores_quiet["fleet"],
            "load": load,
        }
    finally:
        for proc in procs.values():
            _stop(proc)
        _stop(fleet)
        _database(pg, False, name)


def _cluster_report(r: dict[str, Any]) -> None:
    def cores(value: float | None) -> str:
        return "?" if value is None else f"{value:.2f} c"

    print(
        f"N={r['n']} over {r['servers']} servers (lease {r['lease']:g} s), every machine online "
        f"on every server after {r['online_s']:.1f} s; {r['moved']} leases moved in the windows"
    )
    print(
        f"  nobody reading ({r['quiet']:g} s, load average {r['load_quiet']:.1f}): the fleet's "
        f"process {cores(r['fleet_cpu_quiet'])}, the database's backends "
        f"{cores(r['pg_cpu_quiet'])}"
    )
    print(
        f"  each server's /api/machines read about once a second (load average "
        f"{r['load']:.1f}): the fleet's process {cores(r['fleet_cpu'])}, the database's "
        f"backends {cores(r['pg_cpu'])}"
    )
    print(
        f"{'server':>8} {'machines':>9} {'CPU quiet':>10} {'CPU read':>9} {'age p50':>8} "
        f"{'age p99':>8} {'age max':>8} {'p99 own':>8} {'others':>7} {'not shown':>14}"
    )
    for s in r["cpu"]:
        own, others = r["own_p99"][s], r["others_p99"][s]
        print(
            f"{s:>8} {r['spread'].get(s, 0):>9} {r['cpu_quiet'][s]:>8.2f} c "
            f"{r['cpu'][s]:>7.2f} c {r['p50'][s]:>7.2f}s {r['p99'][s]:>7.2f}s "
            f"{r['max'][s]:>7.2f}s {'-' if own is None else f'{own:.2f}s':>8} "
            f"{'-' if others is None else f'{others:.2f}s':>7} "
            f"{r['unshown'][s]:>6}/{r['readings'][s]:<7}"
        )
    take = "not within 120 s" if r["takeover"] is None else f"{r['takeover']:.1f} s"
    back = "not within 120 s" if r["status_back"] is None else f"{r['status_back']:.1f} s"
    print(
        f"SIGKILL of dnc-{r['servers']}: leases taken over after {take}, fresh status after {back}"
    )


def main() -> None:
    """Run the sizes and print one line each."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--sizes",
        default="",
        help="fleet sizes, comma-separated (default 50,200,500; with --mtconnect or --opcua "
        "their sum)",
    )
    parser.add_argument("--seconds", type=float, default=20.0, help="measuring window per size")
    parser.add_argument("--poll", type=float, default=1.0, help="status poll interval (s)")
    parser.add_argument("--servers", type=int, default=1, help="servers on one PostgreSQL")
    parser.add_argument(
        "--pg",
        default="postgresql+psycopg://postgres@127.0.0.1:5432/postgres",
        help="PostgreSQL admin URL (--servers 2 or more: a database is made and dropped)",
    )
    parser.add_argument("--lease", type=float, default=10.0, help="lease seconds (--servers)")
    parser.add_argument(
        "--quiet",
        type=float,
        default=10.0,
        help="seconds of CPU measured with nobody reading the API, before the reading window "
        "(--servers)",
    )
    parser.add_argument("--logs", type=Path, default=None, help="keep the servers' logs here")
    parser.add_argument(
        "--mtconnect",
        type=int,
        default=0,
        help="of each fleet, this many machines behind one virtual MTConnect agent",
    )
    parser.add_argument(
        "--opcua",
        type=int,
        default=0,
        help="of each fleet, this many machine tools of one virtual OPC UA server",
    )
    parser.add_argument(
        "--opcua-servers",
        type=int,
        default=1,
        help="virtual OPC UA servers the --opcua machines are spread over (1: a gateway; "
        "as many as --opcua: one per control, one session each)",
    )
    parser.add_argument(
        "--no-baseline",
        action="store_true",
        help="with --mtconnect or --opcua: skip the run of as many TNCs (LSV2) after it",
    )
    args = parser.parse_args()
    connected = args.mtconnect + args.opcua
    if not args.sizes:
        args.sizes = str(connected) if connected else "50,200,500"
    if args.servers > 1:
        with tempfile.TemporaryDirectory(prefix="opendnc-cluster-bench-") as tmp:
            for n in (int(x) for x in args.sizes.split(",")):
                folder = Path(tmp) / str(n)
                folder.mkdir()
                logs = args.logs or folder
                logs.mkdir(parents=True, exist_ok=True)
                found = run_cluster(
                    n,
                    args.servers,
                    args.seconds,
                    args.poll,
                    folder,
                    args.pg,
                    args.lease,
                    logs,
                    quiet=args.quiet,
                )
                _cluster_report(found)
        return
    print(
        f"{'N':>5} {'online':>8} {'server CPU':>11} {'age p50':>8} {'age p99':>8} "
        f"{'age max':>8} {'missed':>12}  longest loop stall (CPU wait)"
    )
    with tempfile.TemporaryDirectory(prefix="opendnc-fleet-bench-") as tmp:
        for n in (int(x) for x in args.sizes.split(",")):
            r = run_size(
                n, args.seconds, args.poll, Path(tmp), args.mtconnect, args.opcua,
                opcua_servers=args.opcua_servers,
            )  # fmt: skip
            _line(r)
            if connected and not args.no_baseline:
                base = run_size(n, args.seconds, args.poll, Path(tmp), tnc_only=True)
                _line(base, "(LSV2)")
                per, lsv2 = 1000 * r["cpu_cores"] / n, 1000 * base["cpu_cores"] / n
                print(
                    f"      server CPU per machine: {per:.2f} millicores "
                    f"(mtconnect {args.mtconnect}, opcua {args.opcua}) beside {lsv2:.2f} "
                    f"for {n} LSV2 machines",
                    flush=True,
                )


def _line(r: dict[str, Any], label: str = "") -> None:
    """One size's line, the p99 status age of each kind and the commonest offline errors."""
    print(
        f"{r['n']:>5} {r['online_s']:>7.1f}s {r['cpu_cores']:>9.2f} c "
        f"{r['age_p50']:>7.2f}s {r['age_p99']:>7.2f}s {r['age_max']:>7.2f}s "
        f"{int(r['missed']):>5}/{int(r['readings']):<6} {_stall(r['stall'])} {label}".rstrip(),
        flush=True,
    )
    kinds = ", ".join(f"{k} {p:.2f}s" for k, p in r["p99_by_kind"].items())
    print(f"      age p99 by kind: {kinds}; {1000 * r['cpu_cores'] / r['n']:.2f} mc per machine")
    for error, count in sorted(r["errors"].items(), key=lambda kv: -kv[1])[:3]:
        print(f"      {count} readings offline: {error}", flush=True)


if __name__ == "__main__":
    main()
