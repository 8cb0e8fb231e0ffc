"""Several ``opendnc serve`` processes on one real PostgreSQL database, around one
``opendnc sim fleet`` of virtual controls: what the cluster tests share."""

from __future__ import annotations

import hashlib
import json
import signal
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tests.peers import require_module
from tests.server.harness import Procs, auth, create_key, serve, wait_for

httpx = require_module("httpx")

LEASE = 3.0  # seconds: short, so a failover happens within a test's patience
TAKEOVER_LIMIT = 15.0  # what the issue asks of a takeover (the default lease is 10 s)


def program(k: int, size: int) -> bytes:
    """A TNC program ``P<k>.H`` of about ``size`` bytes, different for every ``k``."""
    moves = []
    n = length = 0
    while length < size:
        n += 1
        moves.append(b"%d L X+%d.%03d Y+%d R0 F%d\r\n" % (n, k, n % 1000, n, 100 + k))
        length += len(moves[-1])
    head = b"0 BEGIN PGM P%02d MM\r\n" % k
    return head + b"".join(moves) + b"%d END PGM P%02d MM\r\n" % (n + 1, k)


@dataclass
class Cluster:
    """The fleet, the shared configuration, the servers by name and an admin key."""

    procs: Procs
    root: Path
    db: str
    config: Path
    receipts: Path
    tncs: list[str]
    serial: list[str]
    key: str = ""
    urls: dict[str, str] = field(default_factory=dict)
    clients: dict[str, httpx.Client] = field(default_factory=dict)
    owners_seen: dict[str, set[str]] = field(default_factory=dict)

    def start(self, *names: str) -> None:
        """``opendnc serve --name NAME`` for each name at once (again, after a kill: the
        log goes on); returns once each says where it listens."""
        with ThreadPoolExecutor(len(names)) as pool:
            urls = pool.map(
                lambda name: serve(self.procs, self.config, self.db, "--name", name, name=name),
                names,
            )
            for name, url in zip(names, urls, strict=True):
                self.urls[name] = url
                old = self.clients.pop(name, None)
                if old is not None:
                    old.close()
                headers = auth(self.key)
                self.clients[name] = httpx.Client(base_url=url, timeout=30, headers=headers)

    def kill(self, name: str) -> None:
        """SIGKILL: no clean stop, the leases stay until they expire."""
        self.procs.stop(name, signal.SIGKILL)
        self.clients.pop(name).close()

    def status(self, via: str) -> dict[str, Any]:
        """``GET /api/cluster`` from server ``via``; notes every lease owner seen."""
        view: dict[str, Any] = self.clients[via].get("/api/cluster").json()
        for row in view["leases"]:
            if row["live"]:
                self.owners_seen.setdefault(row["machine"], set()).add(row["owner"])
        return view

    def owners(self, via: str) -> dict[str, str]:
        """Each machine's live owner (the duties' ``@library`` left out)."""
        return {
            row["machine"]: row["owner"]
            for row in self.status(via)["leases"]
            if row["live"] and not row["machine"].startswith("@")
        }

    def settled(self, via: str, servers: set[str]) -> dict[str, str] | None:
        """Every machine held by one of ``servers``, evenly (within one of each other)."""
        owners = self.owners(via)
        everyone = set(self.tncs) | set(self.serial)
        counts = Counter(owners.values())
        even = max(counts.values(), default=0) - min(counts.values(), default=0) <= 1
        if set(owners) == everyone and set(counts) == servers and even:
            return owners
        return None

    def wait_settled(self, via: str, servers: set[str], timeout: float = 60) -> dict[str, str]:
        found: dict[str, str] = wait_for(
            f"the machines spread over {sorted(servers)}",
            lambda: self.settled(via, servers),
            timeout=timeout,
            describe=lambda: Counter(self.owners(via).values()),
        )
        return found

    def receipts_by(self) -> Counter[tuple[str, str, str]]:
        """How often each control received each file completely: (machine, name, sha256)."""
        out: Counter[tuple[str, str, str]] = Counter()
        if not self.receipts.exists():
            return out
        for line in self.receipts.read_text().splitlines():
            r = json.loads(line)
            out[
                (
                    r["machine"],
                    r["path"].replace("\\", "/").rsplit("/", 1)[-1].rsplit(":", 1)[-1],
                    r["sha256"],
                )
            ] += 1
        return out

    def close(self) -> None:
        for client in self.clients.values():
            client.close()


def start_cluster(
    procs: Procs,
    root: Path,
    db: str,
    *,
    tnc: int,
    serial_haas: int = 0,
    pin: dict[str, list[str]] | None = None,
    latency_ms: float = 0.0,
    block_rate: float = 0.0,
    extra: dict[str, str] | None = None,
) -> Cluster:
    """The fleet and its configuration (short leases, pins, ``extra`` lines of a machine's
    table); no server started yet."""
    config = root / "shop.toml"
    receipts = root / "receipts.jsonl"
    procs.start(
        "fleet",
        "sim",
        "fleet",
        "--tnc",
        str(tnc),
        "--haas",
        "0",
        "--serial-haas",
        str(serial_haas),
        "--root",
        str(root / "machines"),
        "--config-out",
        str(config),
        "--poll",
        "0.5",
        "--receipts",
        str(receipts),
        "--latency",
        str(latency_ms),
        "--block-rate",
        str(block_rate),
    )
    wait_for(
        "the fleet", lambda: "listening" in procs.log("fleet"), describe=lambda: procs.log("fleet")
    )
    text = config.read_text()
    text = text.replace("[server]\n", f"[server]\nlease_seconds = {LEASE}\n", 1)
    text += (
        "\n[library]\n"
        f'path = "{root / "programs"}"\ninbox = "{root / "inbox"}"\n'
        f'archive = "{root / "archive"}"\n'
    )
    lines = {m: f"servers = {json.dumps(servers)}" for m, servers in (pin or {}).items()}
    for machine, line in (extra or {}).items():
        lines[machine] = f"{lines[machine]}\n{line}" if machine in lines else line
    for machine, line in lines.items():
        named = f'name = "{machine}"\n'
        assert text.count(named) == 1, machine
        text = text.replace(named, named + line + "\n")
    config.write_text(text)
    cluster = Cluster(
        procs,
        root,
        db,
        config,
        receipts,
        [f"tnc-{i + 1}" for i in range(tnc)],
        [f"haas-serial-{k + 1}" for k in range(serial_haas)],
    )
    cluster.key = create_key(config, db)
    return cluster


def publish_programs(
    client: httpx.Client, count: int, size: int, first: int = 0
) -> dict[str, bytes]:
    """Upload and release ``P<first>.H`` .. as programs of about ``size`` bytes."""
    out = {}
    for k in range(first, first + count):
        name, data = f"P{k:02d}.H", program(k, size)
        put = client.put(f"/api/programs/{name}", content=data)
        assert put.status_code == 201, put.text
        rel = client.post(f"/api/programs/{name}/versions/1/release")
        assert rel.status_code == 200, rel.text
        out[name] = data
    return out


def wait_all_ended(
    client: httpx.Client, ids: list[int], timeout: float = 120
) -> list[dict[str, Any]]:
    """The jobs once none is queued or running (a list of all jobs, one request)."""
    wanted = set(ids)

    def listed() -> list[dict[str, Any]]:
        rows: list[dict[str, Any]] = client.get("/api/jobs", params={"limit": 10_000}).json()
        return [j for j in rows if j["id"] in wanted]

    def ended() -> list[dict[str, Any]] | None:
        rows = listed()
        done = len(rows) == len(wanted) and all(
            j["state"] not in ("queued", "running") for j in rows
        )
        return rows if done else None

    found: list[dict[str, Any]] = wait_for(
        "every job to end",
        ended,
        timeout=timeout,
        describe=lambda: Counter(j["state"] for j in listed()),
    )
    return found


def sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def audit_rows(db: str, action: str) -> list[dict[str, Any]]:
    """The audit rows of ``action`` straight from the database."""
    from sqlalchemy import select

    from opendnc.server.store.db import make_engine, make_sessions
    from opendnc.server.store.models import AuditEntry

    engine = make_engine(db)
    try:
        with make_sessions(engine)() as session:
            rows = session.scalars(select(AuditEntry).where(AuditEntry.action == action)).all()
            return [
                {
                    "actor": r.actor,
                    "job_id": r.job_id,
                    "machine": r.machine,
                    "result": r.result,
                    **dict(r.detail or {}),
                }
                for r in rows
            ]
    finally:
        engine.dispose()
