"""Utilization over a year of status samples for 200 machines, on SQLite and PostgreSQL.

Generates a realistic status timeline (docs/dashboard.md#utilization): each machine cuts in
cycles of about 12 minutes with a few minutes of ready between them, holds its feed now and
then, goes into alarm about once a day for 10-40 minutes, drops offline about once a week for
an hour, and every machine shows no record for a few minutes when the server restarts (once a
month). Half the machines count parts (a Haas's M30 counter). A state changes every few
minutes: about 100 000 samples per machine and year.

Then it times :func:`opendnc.server.utilization.collect.report` (what ``GET /api/utilization``
answers), in the server's own database layout:

1. the first question, which sums every finished hour of the year once (``utilization_hours``);
2. the year per week for all machines (the headline), the last 7 days per day, one day per
   shift, and the page's Gantt slices for a week;
3. ``api_year_by_week``: the headline as the API answers it (summing what finished in a
   short write transaction, the report in a read-only one, the JSON body), and
   ``api_first``: the same as the first question this process asks;
4. the year again after one more hour of samples arrived (the steady state: each question
   sums the hours that finished since the last one).

Each question runs ``--repeat`` times; the medians are printed: wall seconds, and CPU
seconds (this process, plus on PostgreSQL the backends serving it; what the load of a
shared machine changes least). On PostgreSQL each question runs once more untimed with
every SELECT explained (``EXPLAIN ANALYZE``): the database's own execution time, including
parallel workers the backend's CPU time does not hold. After the days are summed the tables
are analyzed (and vacuumed on PostgreSQL), as autovacuum does by then on a running server.

    .venv/bin/python benchmarks/utilization.py                      # 200 machines, a year
    .venv/bin/python benchmarks/utilization.py --machines 20 --days 30 --backend sqlite
    .venv/bin/python benchmarks/utilization.py --json

PostgreSQL is the one at 127.0.0.1:5432 (trust), in a database of its own that is dropped
at the end; SQLite is a file in a temporary folder. With both (the default) a table of the
two side by side ends the output. ``--url`` names a database of your own instead (created
and dropped by you): the first run fills it, later runs time the questions on it as it is
(without the hour more of samples, which would change it)::

    psql -h 127.0.0.1 -U postgres -c 'CREATE DATABASE util_bench_1'
    .venv/bin/python benchmarks/utilization.py --url postgresql+psycopg://postgres@127.0.0.1:5432/util_bench_1
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import sqlite3
import statistics
import sys
import tempfile
import time
import uuid
from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

from sqlalchemy import Engine, create_engine, event, insert, text

from opendnc.server.config.downtime import DEFAULT_REASONS
from opendnc.server.core.shifts import parse_calendar
from opendnc.server.store.db import make_engine, make_sessions, migrate, read_only
from opendnc.server.store.models import (
    Blob,
    PartReport,
    Program,
    ProgramState,
    ProgramVersion,
    StandardTime,
    StatusSample,
)
from opendnc.server.utilization.answer import report_response
from opendnc.server.utilization.collect import (
    Group,
    buckets,
    equal_periods,
    report,
    roll,
    sum_safely,
)
from opendnc.server.utilization.component import HourSummer
from opendnc.server.utilization.oee import floor_of

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


def _backend_cpu(engine: Engine) -> float:
    """CPU seconds the PostgreSQL backends connected to ``engine``'s database have used (0 on
    SQLite, which runs in this process and counts in its CPU time). A parallel worker's
    time is not held here (it ends with its query): the EXPLAIN ANALYZE pass shows it."""
    if engine.dialect.name != "postgresql":
        return 0.0
    with engine.connect() as conn:
        pids = conn.execute(
            text(
                "SELECT pid FROM pg_stat_activity WHERE datname = current_database() "
                "AND backend_type = 'client backend'"
            )
        ).scalars()
        total = 0.0
        for pid in pids:
            try:
                fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            except OSError:  # not on this machine, or not Linux
                continue
            total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return total


CPU: dict[str, list[float]] = {}
EXPLAINED: dict[str, float] = {}


def _time(engine: Engine, work: Any, repeat: int, key: str) -> list[float]:
    """Wall seconds of ``repeat`` runs of ``work(engine)``; the CPU seconds of each (this
    process and the database's backends: what the load of the machine does not change) go
    to :data:`CPU` under ``key``."""
    out = []
    for _ in range(repeat):
        backend = _backend_cpu(engine)
        cpu = time.process_time()
        started = time.perf_counter()
        work(engine)
        out.append(time.perf_counter() - started)
        cpu = time.process_time() - cpu + _backend_cpu(engine) - backend
        CPU.setdefault(key, []).append(cpu)
    return out


def _explained(engine: Engine, work: Any) -> float:
    """Run ``work(engine)`` once with every SELECT explained on its own connection (after it
    ran, so the temporary tables it reads are there); the summed execution times in
    seconds. PostgreSQL only."""
    total = [0.0]

    def explain(
        conn: Any, cursor: Any, statement: str, params: Any, context: Any, many: bool
    ) -> None:
        if many or not statement.lstrip().upper().startswith("SELECT"):
            return
        with cursor.connection.cursor() as explaining:
            explaining.execute("EXPLAIN (ANALYZE, FORMAT JSON) " + statement, params)
            total[0] += explaining.fetchone()[0][0]["Execution Time"] / 1000

    event.listen(engine, "after_cursor_execute", explain)
    try:
        work(engine)
    finally:
        event.remove(engine, "after_cursor_execute", explain)
    return total[0]


def _in_transaction(question: Any) -> Any:
    """``question(session)`` in a write transaction of its own, as a work for :func:`_time`."""

    def work(engine: Engine) -> Any:
        with make_sessions(engine).begin() as session:
            return question(session)

    return work


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
        "utilization_program_hours": "hour, program, runs, seconds",
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


RETENTION = timedelta(days=7)  # [server] timeline_retention_days by default


def floor_data(url: str, names: list[str], now: datetime) -> dict[str, int]:
    """What OEE and the downtime reasons read besides the timeline: a standard time for the
    program every machine runs, a reason picked for two stops of three (round the configured
    list), and a report of good and scrapped parts per machine and day of the last month."""
    engine = create_engine(url)
    try:
        with make_sessions(engine).begin() as session:
            session.add(Blob(sha256="0" * 64, size=1, data=b"%"))
            program = Program(name="O1000")
            session.add(program)
            session.flush()
            version = ProgramVersion(
                program_id=program.id,
                number=1,
                sha256="0" * 64,
                size=1,
                state=ProgramState.RELEASED,
                author="bench",
            )
            session.add(version)
            session.flush()
            session.add(StandardTime(version_id=version.id, seconds=600.0, set_by="bench"))
            session.add_all(
                PartReport(
                    machine=m, at=now - timedelta(days=d, hours=3), good=40, scrap=d % 3, by="bench"
                )
                for m in names
                for d in range(30)
            )
        cases = " ".join(f"WHEN {i} THEN '{r}'" for i, r in enumerate(DEFAULT_REASONS))
        with engine.begin() as conn:
            conn.execute(
                text(
                    'INSERT INTO downtime_reasons (machine, start, reason, note, "by", at) '
                    f"SELECT machine, start, CASE id % {len(DEFAULT_REASONS)} {cases} END, '', "
                    "'bench', \"end\" FROM utilization_stretches "
                    "WHERE kind = 'stop' AND id % 3 <> 0"
                )
            )
            reasons = conn.execute(text("SELECT COUNT(*) FROM downtime_reasons")).scalar()
    finally:
        engine.dispose()
    return {"reasons_picked": int(reasons or 0), "part_reports": 30 * len(names)}


def run(
    url: str,
    machines: int,
    distinct: int,
    days: int,
    repeat: int,
    seed: int,
    copy_days: int,
    *,
    prepared: bool = False,
    keep: Path | None = None,
    one_more_hour: bool = True,
) -> dict[str, Any]:
    """Fill a fresh database at ``url`` (unless it is ``prepared``) and time the questions;
    the numbers."""
    engine = make_engine(url)
    migrate(engine)
    names = [f"m{i:03d}" for i in range(machines)]
    own = names[: min(distinct, machines)]
    now = datetime(2026, 11, 20, 9, 30, tzinfo=UTC)
    start = now - timedelta(days=days)
    out: dict[str, Any] = {"machines": machines, "distinct_timelines": len(own), "days": days}
    if not prepared:
        out |= _prepare(url, engine, names, own, start, now, seed, copy_days)
    if keep is not None:  # a copy of the filled database, for another run with --db
        # (on a connection of its own: the engine's begins a transaction, and VACUUM cannot
        # run inside one)
        copier = sqlite3.connect(url.removeprefix("sqlite:///"), isolation_level=None)
        try:
            copier.execute("VACUUM INTO ?", (str(keep),))
        finally:
            copier.close()
    with engine.connect() as conn:
        out["samples"] = conn.execute(text("SELECT COUNT(*) FROM status_samples")).scalar()
        out["hour_rows"] = conn.execute(text("SELECT COUNT(*) FROM utilization_hours")).scalar()
        out["stretch_rows"] = conn.execute(
            text("SELECT COUNT(*) FROM utilization_stretches")
        ).scalar()
    return _questions(url, engine, names, start, now, repeat, seed, out, one_more_hour)


def _prepare(
    url: str,
    engine: Engine,
    names: list[str],
    own: list[str],
    start: datetime,
    now: datetime,
    seed: int,
    copy_days: int,
) -> dict[str, Any]:
    """Fill the database and sum it as a running server has by ``now``; what it took."""
    out: dict[str, Any] = {}
    sessions = make_sessions(engine)
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
    out |= floor_data(url, names, now)
    # what autovacuum has done by then on a server: the planner knows the sizes, and on
    # PostgreSQL the summed tables are marked all-visible (an index alone answers)
    with engine.connect().execution_options(isolation_level="AUTOCOMMIT") as conn:
        conn.execute(text("VACUUM ANALYZE" if engine.dialect.name == "postgresql" else "ANALYZE"))
    return out


def _questions(
    url: str,
    engine: Engine,
    names: list[str],
    start: datetime,
    now: datetime,
    repeat: int,
    seed: int,
    out: dict[str, Any],
    one_more_hour: bool = True,
) -> dict[str, Any]:
    """Time the questions on the filled database (and, with ``one_more_hour``, the year
    after an hour more of samples: written to it)."""
    year = (start, now)
    local_now = CAL.local(now)
    midnight = CAL.instant(local_now.date(), datetime.min.time())
    week = (midnight - timedelta(days=6), now)
    day = (midnight - timedelta(days=1), midnight)

    def question(
        span: tuple[datetime, datetime], group: Group, at: datetime, days: bool = True
    ) -> Any:
        return _in_transaction(
            lambda s: report(s, CAL, names, span[0], span[1], group, now=at, use_days=days)
        )

    def api(span: tuple[datetime, datetime], group: Group, at: datetime) -> Any:
        """What ``GET /api/utilization`` does (utilization.answer.run_report and the route)."""

        def work(engine: Engine) -> bytes:
            factory = make_sessions(engine)
            with factory.begin() as session:
                sum_safely(session, names, at, CAL)
            with read_only(factory)() as session:
                r = report(session, CAL, names, *span, group, now=at, sum_first=False)
            return bytes(report_response(r).body)

        return work

    def api_oee(span: tuple[datetime, datetime], group: Group, at: datetime) -> Any:
        """The same with OEE and the downtime reasons (utilization.answer.full_report)."""

        def work(engine: Engine) -> bytes:
            factory = make_sessions(engine)
            with factory.begin() as session:
                sum_safely(session, names, at, CAL)
            with read_only(factory)() as session:
                r = report(session, CAL, names, *span, group, now=at, sum_first=False)
                r.floor = floor_of(session, r, RETENTION, DEFAULT_REASONS, at)
            return bytes(report_response(r).body)

        return work

    gantt = _in_transaction(
        lambda s: buckets(s, names, equal_periods(*week, timedelta(hours=1)), now=now)
    )
    questions: dict[str, tuple[Any, int]] = {
        "year_by_week": (question(year, Group.WEEK, now), repeat),
        "api_year_by_week": (api(year, Group.WEEK, now), repeat),
        "api_year_by_week_oee": (api_oee(year, Group.WEEK, now), repeat),
        "api_7_days_by_day_oee": (api_oee(week, Group.DAY, now), repeat),
        "year_by_week_from_hours": (question(year, Group.WEEK, now, days=False), 1),
        "year_by_day": (question(year, Group.DAY, now), repeat),
        "year_by_shift": (question(year, Group.SHIFT, now), repeat),
        "7_days_by_day": (question(week, Group.DAY, now), repeat),
        "1_day_by_shift": (question(day, Group.SHIFT, now), repeat),
        "gantt_7_days": (gantt, repeat),
    }
    CPU.clear()
    EXPLAINED.clear()
    # the first question this process asks (its statements not compiled yet), once
    body: list[bytes] = []
    first = _time(engine, lambda e: body.append(api(year, Group.WEEK, now)(e)), 1, "api_first")
    out["json_bytes_year_by_week"] = len(body[0])
    timings = {"api_first": first}
    timings |= {key: _time(engine, work, n, key) for key, (work, n) in questions.items()}
    if engine.dialect.name == "postgresql":
        for key, (work, _n) in questions.items():
            EXPLAINED[key] = _explained(engine, work)
    if one_more_hour:
        # one more hour of samples for every machine, then the year again (it sums that hour)
        later = now + timedelta(hours=1)
        fill(url, names, now, later, seed + 1)
        key = "year_after_1_hour_more"
        timings[key] = _time(
            engine, question((start, later), Group.WEEK, later + timedelta(minutes=3)), 1, key
        )
    out["seconds"] = {k: [round(v, 3) for v in vs] for k, vs in timings.items()}
    out["median_s"] = {k: round(statistics.median(vs), 3) for k, vs in timings.items()}
    out["median_cpu_s"] = {k: round(statistics.median(vs), 3) for k, vs in CPU.items()}
    out["explain_analyze_s"] = {k: round(v, 3) for k, v in EXPLAINED.items()}
    out["load_average"] = [round(x, 1) for x in os.getloadavg()]
    engine.dispose()
    return out


def _sqlite(
    machines: int,
    distinct: int,
    days: int,
    repeat: int,
    seed: int,
    copy_days: int,
    db: Path | None = None,
) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="opendnc-util-bench-") as tmp:
        path = Path(tmp) / "bench.db"
        prepared = db is not None and db.exists()
        if prepared:
            assert db is not None
            shutil.copyfile(db, path)  # (the questions add an hour: the kept one stays)
        url = f"sqlite:///{path}"
        keep = db if db is not None and not prepared else None
        result = run(
            url, machines, distinct, days, repeat, seed, copy_days, prepared=prepared, keep=keep
        )
        result["backend"] = "sqlite"
        result["reused_db"] = prepared
        return result


def _given(
    url: str, machines: int, distinct: int, days: int, repeat: int, seed: int, copy_days: int
) -> dict[str, Any]:
    """The questions on the database at ``url``: filled first if it holds no samples."""
    engine = make_engine(url)
    try:
        migrate(engine)
        with engine.connect() as conn:
            filled = bool(conn.execute(text("SELECT COUNT(*) FROM utilization_marks")).scalar())
    finally:
        engine.dispose()
    # (no hour more of samples: the database stays as filled, for the next run)
    result = run(
        url, machines, distinct, days, repeat, seed, copy_days, prepared=filled, one_more_hour=False
    )
    result["backend"] = engine.dialect.name
    result["reused_db"] = filled
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
        default=8,
        help="days of samples the copied machines keep (-1: all of them; a server keeps 7)",
    )
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--seed", type=int, default=23)
    parser.add_argument("--json", action="store_true", help="one JSON line per backend")
    parser.add_argument(
        "--db",
        type=Path,
        help="SQLite: a filled database kept here and reused by the next run with the same "
        "path (the same --machines, --days and --seed)",
    )
    parser.add_argument(
        "--url",
        help="a database of your own (sqlite:///... or postgresql+psycopg://...) instead of "
        "--backend: filled if it holds no samples, else reused as it is (the same --machines, "
        "--days and --seed); never dropped, and left as filled (no hour more of samples)",
    )
    args = parser.parse_args(argv)
    backends = ["sqlite", "postgresql"] if args.backend == "both" else [args.backend]
    if args.url:
        backends = ["url"]
    results = []
    for backend in backends:
        common = (args.machines, args.distinct, args.days, args.repeat, args.seed, args.copy_days)
        if backend == "url":
            result = _given(args.url, *common)
        elif backend == "sqlite":
            result = _sqlite(*common, db=args.db)
        else:
            result = _postgresql(*common)
        results.append(result)
        if args.json:
            print(json.dumps(result), flush=True)
            continue
        print(
            f"{result['backend']}: {result['machines']} machines ({result['distinct_timelines']} "
            f"distinct timelines), {result['days']} days, {result['samples']} samples, "
            f"{result['hour_rows']} summed hours, {result['stretch_rows']} stops and alarms"
            + ("" if "sum_hours" in result else " (a database filled before)")
        )
        if "sum_hours" in result:
            summed = result["sum_hours"]
            print(
                f"  summing {summed['samples']} samples took {summed['seconds']} s "
                f"({summed['samples_per_second']} samples/s); "
                f"summing the days took {result['sum_days_s']} s"
            )
        print(
            f"  load average {result['load_average']}; "
            f"the year by week is {result['json_bytes_year_by_week']} bytes of JSON"
        )
        for key, seconds in result["seconds"].items():
            explained = result["explain_analyze_s"].get(key)
            print(
                f"  {key}: median {result['median_s'][key]} s, CPU "
                f"{result['median_cpu_s'][key]} s"
                + ("" if explained is None else f", EXPLAIN ANALYZE {explained} s")
                + f"  (runs: {seconds})"
            )
        sys.stdout.flush()
    if len(results) > 1 and not args.json:
        _side_by_side(results)


def _side_by_side(results: list[dict[str, Any]]) -> None:
    """The medians of every backend in one table (Markdown, as docs/dashboard.md has it)."""
    names = [r["backend"] for r in results]
    head = ["question"]
    for name in names:
        head += [f"{name} wall", f"{name} CPU"]
        if name == "postgresql":
            head.append("EXPLAIN ANALYZE")
    print()
    print("| " + " | ".join(head) + " |")
    print("| " + " | ".join("---" for _ in head) + " |")
    for key in results[0]["median_s"]:
        row = [key]
        for r in results:
            row += [f"{r['median_s'][key]:.3f}", f"{r['median_cpu_s'][key]:.3f}"]
            if r["backend"] == "postgresql":
                explained = r["explain_analyze_s"].get(key)
                row.append("" if explained is None else f"{explained:.3f}")
        print("| " + " | ".join(row) + " |")
    print(f"(seconds, medians; load average at the end {[r['load_average'] for r in results]})")


if __name__ == "__main__":
    main()
