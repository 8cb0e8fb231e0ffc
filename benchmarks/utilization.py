"""Utilization over a year of status samples for 200 machines, on SQLite and PostgreSQL.

Generates a realistic status timeline (docs/dashboard.md#utilization): each machine cuts in
cycles of about 12 minutes with a few minutes of ready between them, holds its feed now and
then, goes into alarm about once a day for 10-40 minutes, drops offline about once a week for
an hour, and every machine shows no record for a few minutes when the server restarts (once a
month). Half the machines count parts (a Haas's M30 counter). A state changes every few
minutes: about 100 000 samples per machine and year.

Then it times :func:`opendnc.server.utilization.report` (what ``GET /api/utilization``
answers), in the server's own database layout:

1. the first question, which sums every finished hour of the year once (``utilization_hours``);
2. the year per week for all machines (the headline), the last 7 days per day, one day per
   shift, and the page's Gantt slices for a week;
3. the year again after one more hour of samples arrived (the steady state: each question
   sums the hours that finished since the last one).

    .venv/bin/python benchmarks/utilization.py                      # 200 machines, a year
    .venv/bin/python benchmarks/utilization.py --machines 20 --days 30 --backend sqlite
    .venv/bin/python benchmarks/utilization.py --json

PostgreSQL is the one at 127.0.0.1:5432 (trust), in a database of its own that is dropped
at the end; SQLite is a file in a temporary folder.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import statistics
import sys
import tempfile
import time
import uuid
from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

from sqlalchemy import create_engine, insert, text
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.shifts import parse_calendar
from opendnc.server.store.db import make_engine, make_sessions, migrate
from opendnc.server.store.models import StatusSample
from opendnc.server.utilization import Group, buckets, equal_periods, report, roll
from opendnc.server.utilization_api import HourSummer

PG_ADMIN = "postgresql+psycopg://postgres@127.0.0.1:5432/postgres"
CAL = parse_calendar(
    {
        "server": {"timezone": "Europe/Berlin"},
        "shifts": [
            {"name": "early", "start": "06:00", "end": "14:00", "days": ["mon-fri"]},
            {"name": "late", "start": "14:00", "end": "22:00", "days": ["mon-fri"]},
            {"name": "night", "start": "22:00", "end": "06:00", "days": ["sun-thu"]},
        ],
    }
)
ALARMS = ["1010 SPINDLE OVERLOAD", "108 SERVO OVERLOAD", "EMERGENCY STOP", "1001 LOW LUBE"]
Row = tuple[str, datetime, str, str, int | None, str]


def timeline(machine: str, start: datetime, end: datetime, rng: random.Random) -> Iterator[Row]:
    """One machine's samples (machine, at, state, execution, part count, alarm) from start
    to end."""
    counts = rng.random() < 0.5
    count = rng.randint(0, 5000) if counts else None
    at = start
    next_alarm = at + timedelta(hours=rng.expovariate(1 / 24))
    next_offline = at + timedelta(hours=rng.expovariate(1 / 168))
    restart = start + timedelta(days=30)
    while at < end:
        if at >= restart:  # the server restarts: a few minutes without a record
            yield machine, at, "none", "", None, ""
            at += timedelta(minutes=rng.uniform(2, 10))
            restart += timedelta(days=30)
            continue
        if at >= next_alarm:
            yield machine, at, "alarm", "STOPPED", count, rng.choice(ALARMS)
            at += timedelta(minutes=rng.uniform(10, 40))
            next_alarm = at + timedelta(hours=rng.expovariate(1 / 24))
            continue
        if at >= next_offline:
            yield machine, at, "offline", "", None, ""
            at += timedelta(minutes=rng.uniform(30, 90))
            next_offline = at + timedelta(hours=rng.expovariate(1 / 168))
            continue
        yield machine, at, "running", "ACTIVE", count, ""
        cycle = rng.expovariate(1 / 12)
        if rng.random() < 0.15:  # a feed hold in the middle of the cycle
            at += timedelta(minutes=cycle / 2)
            yield machine, at, "stopped", "FEED_HOLD", count, ""
            at += timedelta(minutes=rng.uniform(0.5, 6))
            yield machine, at, "running", "ACTIVE", count, ""
            cycle /= 2
        at += timedelta(minutes=cycle)
        if count is not None:
            count += 1
        yield machine, at, "ready", "READY", count, ""
        at += timedelta(minutes=rng.expovariate(1 / 3))


def fill(url: str, machines: list[str], start: datetime, end: datetime, seed: int) -> int:
    """Write the samples of ``machines`` from ``start`` to ``end``; how many."""
    rng = random.Random(seed)
    written = 0
    engine = create_engine(url)
    try:
        if url.startswith("postgresql"):
            raw = engine.raw_connection()
            try:
                cursor = raw.cursor()
                columns = "machine, at, state, mode, execution, program, part_count, alarm"
                with cursor.copy(f"COPY status_samples ({columns}) FROM STDIN") as copy:  # type: ignore[attr-defined]
                    for m in machines:
                        for machine, at, state, execution, count, alarm in timeline(
                            m, start, end, rng
                        ):
                            copy.write_row(
                                (machine, at, state, "", execution, "O1000", count, alarm)
                            )
                            written += 1
                raw.commit()
            finally:
                raw.close()
        else:
            with engine.begin() as conn:
                batch: list[dict[str, Any]] = []
                for m in machines:
                    for machine, at, state, execution, count, alarm in timeline(m, start, end, rng):
                        batch.append(
                            {
                                "machine": machine,
                                "at": at,
                                "state": state,
                                "mode": "",
                                "execution": execution,
                                "program": "O1000",
                                "part_count": count,
                                "alarm": alarm,
                            }
                        )
                        if len(batch) >= 50_000:
                            conn.execute(insert(StatusSample), batch)
                            written += len(batch)
                            batch.clear()
                if batch:
                    conn.execute(insert(StatusSample), batch)
                    written += len(batch)
    finally:
        engine.dispose()
    return written


def _backend_cpu(session: Session) -> float:
    """CPU seconds the PostgreSQL backend serving ``session`` has used (0 on SQLite, which
    runs in this process and counts in its CPU time)."""
    if session.get_bind().dialect.name != "postgresql":
        return 0.0
    pid = session.execute(text("SELECT pg_backend_pid()")).scalar()
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:  # not on this machine, or not Linux
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


CPU: dict[str, list[float]] = {}


def _time(sessions: sessionmaker[Session], work: Any, repeat: int, key: str = "") -> list[float]:
    """Wall seconds of ``repeat`` runs of ``work``; the CPU seconds of each (this process
    and the database server's backend: what the load of the machine does not change) go to
    :data:`CPU` under ``key``."""
    out = []
    for _ in range(repeat):
        with sessions.begin() as session:
            backend = _backend_cpu(session)
            cpu = time.process_time()
            started = time.perf_counter()
            work(session)
            out.append(time.perf_counter() - started)
            cpu = time.process_time() - cpu + _backend_cpu(session) - backend
        CPU.setdefault(key, []).append(cpu)
    return out


def _clone(url: str, names: list[str], copies: list[str], since: datetime | None) -> None:
    """Give every name of ``copies`` the summed hours, stretches and marks of one of ``names``
    (round robin), and its samples from ``since`` on (all with None), in SQL: the database
    then holds as many machines as asked without generating and summing each timeline in
    Python. A question reads samples only for the hour not summed yet (and the one in force
    before it), so the copies' older samples would only make the table bigger."""
    engine = create_engine(url)
    tables = {
        "status_samples": "at, state, mode, execution, program, part_count, alarm",
        "utilization_hours": "hour, running, ready, stopped, alarm, offline, unknown, "
        "no_record, parts, runs, cycles, cycle_seconds",
        "utilization_stretches": 'kind, start, "end", seconds, state, text',
        "utilization_marks": "until, last_id, carry",
    }
    try:
        with engine.begin() as conn:
            for i, copy in enumerate(copies):
                source = names[i % len(names)]
                for table, columns in tables.items():
                    recent = ""
                    if table == "status_samples" and since is not None:
                        recent = " AND at >= :since"
                    conn.execute(
                        text(
                            f"INSERT INTO {table} (machine, {columns}) "
                            f"SELECT :copy, {columns} FROM {table} "
                            f"WHERE machine = :source{recent}"
                        ),
                        {"copy": copy, "source": source, "since": since},
                    )
            # the copies' samples are not late arrivals: the marks have read them
            conn.execute(
                text("UPDATE utilization_marks SET last_id = (SELECT MAX(id) FROM status_samples)")
            )
            conn.execute(text("ANALYZE"))  # the planner sees the real sizes
    finally:
        engine.dispose()


def run(
    url: str, machines: int, distinct: int, days: int, repeat: int, seed: int, copy_days: int
) -> dict[str, Any]:
    """Fill a fresh database at ``url`` and time the questions; the numbers."""
    engine = make_engine(url)
    migrate(engine)
    sessions = make_sessions(engine)
    names = [f"m{i:03d}" for i in range(machines)]
    own = names[: min(distinct, machines)]
    now = datetime(2026, 11, 20, 9, 30, tzinfo=UTC)
    start = now - timedelta(days=days)
    out: dict[str, Any] = {"machines": machines, "distinct_timelines": len(own), "days": days}
    t0 = time.perf_counter()
    samples = fill(url, own, start, now - timedelta(minutes=1), seed)
    out["fill_s"] = round(time.perf_counter() - t0, 1)
    # summing every finished hour once (what the server does in the background as hours end)
    t0 = time.perf_counter()
    with sessions.begin() as session:
        hours = roll(session, own, now)
    took = time.perf_counter() - t0
    out["sum_hours"] = {
        "samples": samples,
        "hours_written": hours,
        "seconds": round(took, 1),
        "samples_per_second": round(samples / took),
    }
    t0 = time.perf_counter()
    since = None if copy_days < 0 else now - timedelta(days=copy_days)
    _clone(url, own, names[len(own) :], since)
    out["copies_keep_samples_of_days"] = None if copy_days < 0 else copy_days
    out["clone_s"] = round(time.perf_counter() - t0, 1)
    # summing the local days from the hours (the server does it in the background too)
    t0 = time.perf_counter()
    HourSummer(sessions, names, CAL).sum_now(now)
    out["sum_days_s"] = round(time.perf_counter() - t0, 1)
    with engine.connect() as conn:
        out["samples"] = conn.execute(text("SELECT COUNT(*) FROM status_samples")).scalar()
        out["hour_rows"] = conn.execute(text("SELECT COUNT(*) FROM utilization_hours")).scalar()
        out["stretch_rows"] = conn.execute(
            text("SELECT COUNT(*) FROM utilization_stretches")
        ).scalar()
    year = (start, now)
    local_now = CAL.local(now)
    midnight = CAL.instant(local_now.date(), datetime.min.time())
    week = (midnight - timedelta(days=6), now)
    day = (midnight - timedelta(days=1), midnight)

    def question(
        span: tuple[datetime, datetime], group: Group, at: datetime, days: bool = True
    ) -> Any:
        return lambda s: report(s, CAL, names, span[0], span[1], group, now=at, use_days=days)

    CPU.clear()
    timings = {
        "year_by_week": _time(sessions, question(year, Group.WEEK, now), repeat, "year_by_week"),
        "year_by_week_from_hours": _time(
            sessions, question(year, Group.WEEK, now, days=False), 1, "year_by_week_from_hours"
        ),
        "year_by_day": _time(sessions, question(year, Group.DAY, now), repeat, "year_by_day"),
        "year_by_shift": _time(sessions, question(year, Group.SHIFT, now), repeat, "year_by_shift"),
        "7_days_by_day": _time(sessions, question(week, Group.DAY, now), repeat, "7_days_by_day"),
        "1_day_by_shift": _time(
            sessions, question(day, Group.SHIFT, now), repeat, "1_day_by_shift"
        ),
        "gantt_7_days": _time(
            sessions,
            lambda s: buckets(s, names, equal_periods(*week, timedelta(hours=1)), now=now),
            repeat,
            "gantt_7_days",
        ),
    }
    # one more hour of samples for every machine, then the year again (it sums that hour)
    later = now + timedelta(hours=1)
    fill(url, names, now, later, seed + 1)
    timings["year_after_1_hour_more"] = _time(
        sessions,
        question((start, later), Group.WEEK, later + timedelta(minutes=3)),
        1,
        "year_after_1_hour_more",
    )
    out["seconds"] = {k: [round(v, 3) for v in vs] for k, vs in timings.items()}
    out["median_s"] = {k: round(statistics.median(vs), 3) for k, vs in timings.items()}
    out["median_cpu_s"] = {k: round(statistics.median(vs), 3) for k, vs in CPU.items()}
    out["load_average"] = [round(x, 1) for x in os.getloadavg()]
    engine.dispose()
    return out


def _sqlite(
    machines: int, distinct: int, days: int, repeat: int, seed: int, copy_days: int
) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="opendnc-util-bench-") as tmp:
        url = f"sqlite:///{Path(tmp) / 'bench.db'}"
        result = run(url, machines, distinct, days, repeat, seed, copy_days)
        result["backend"] = "sqlite"
        return result


def _postgresql(
    machines: int, distinct: int, days: int, repeat: int, seed: int, copy_days: int
) -> dict[str, Any]:
    admin = create_engine(PG_ADMIN, isolation_level="AUTOCOMMIT")
    name = f"opendnc_util_bench_{uuid.uuid4().hex[:8]}"
    with admin.connect() as conn:
        conn.execute(text(f'CREATE DATABASE "{name}"'))
    try:
        url = PG_ADMIN.rsplit("/", 1)[0] + f"/{name}"
        result = run(url, machines, distinct, days, repeat, seed, copy_days)
        result["backend"] = "postgresql"
        return result
    finally:
        with admin.connect() as conn:
            conn.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        admin.dispose()


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--machines", type=int, default=200)
    parser.add_argument("--days", type=int, default=365)
    parser.add_argument(
        "--distinct",
        type=int,
        default=20,
        help="timelines generated and summed in Python; the other machines copy them in SQL",
    )
    parser.add_argument("--backend", choices=["sqlite", "postgresql", "both"], default="both")
    parser.add_argument(
        "--copy-days",
        type=int,
        default=2,
        help="days of samples the copied machines keep (-1: all of them)",
    )
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--seed", type=int, default=23)
    parser.add_argument("--json", action="store_true", help="one JSON line per backend")
    args = parser.parse_args(argv)
    backends = ["sqlite", "postgresql"] if args.backend == "both" else [args.backend]
    for backend in backends:
        go = _sqlite if backend == "sqlite" else _postgresql
        result = go(args.machines, args.distinct, args.days, args.repeat, args.seed, args.copy_days)
        if args.json:
            print(json.dumps(result), flush=True)
            continue
        summed = result["sum_hours"]
        print(
            f"{backend}: {result['machines']} machines ({result['distinct_timelines']} distinct "
            f"timelines), {result['days']} days, {result['samples']} samples, "
            f"{result['hour_rows']} summed hours, {result['stretch_rows']} stops and alarms; "
            f"summing {summed['samples']} samples took {summed['seconds']} s "
            f"({summed['samples_per_second']} samples/s)"
        )
        print(
            f"  load average {result['load_average']}; "
            f"summing the days took {result['sum_days_s']} s"
        )
        for key, seconds in result["seconds"].items():
            print(
                f"  {key}: median {result['median_s'][key]} s, CPU "
                f"{result['median_cpu_s'][key]} s  (runs: {seconds})"
            )
        sys.stdout.flush()


if __name__ == "__main__":
    main()
