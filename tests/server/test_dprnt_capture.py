"""DPRNT capture in the server: a virtual Haas NGC (``--dprnt tcp:PORT``) runs a program that
prints; the server stores every line, publishes it on the event stream and serves it as JSON
(after an id) and CSV. Also the migration that adds the table, up from 0002 and back."""

from __future__ import annotations

import csv
import io
import json
import re
import threading
from datetime import datetime
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import inspect, text

from opendnc.server.config.shop import ConfigError, parse_config
from opendnc.server.store.db import current_revision, make_engine, migrate
from tests.server.conftest import on
from tests.server.srvx_support import (
    PRINTS,
    STORED,
    FleetThread,
    Procs,
    auth,
    create_key,
    free_port,
    httpx,
    serve,
    serve_fleet,
    wait_for,
)


def test_migration_0003_up_from_0002_and_back(db_url: str) -> None:
    engine = make_engine(db_url)
    try:
        migrate(engine, "0002")
        with engine.begin() as conn:
            conn.execute(
                text(
                    "INSERT INTO audit (at, actor, action, result, detail) "
                    "VALUES (CURRENT_TIMESTAMP, 'alice', 'login', 'ok', '{}')"
                )
            )
        migrate(engine, "0003")
        assert current_revision(engine) == "0003"
        columns = {c["name"] for c in inspect(engine).get_columns("dprnt_lines")}
        assert columns == {"id", "machine", "at", "text", "fields", "complete"}
        indexes = [i["column_names"] for i in inspect(engine).get_indexes("dprnt_lines")]
        assert indexes == [["machine", "id"]]
        migrate(engine, "0002")
        assert current_revision(engine) == "0002"
        assert "dprnt_lines" not in inspect(engine).get_table_names()
        with engine.connect() as conn:  # the rows of earlier tables are untouched
            assert conn.execute(text("SELECT actor FROM audit")).scalars().all() == ["alice"]
        migrate(engine)
        assert "dprnt_lines" in inspect(engine).get_table_names()
    finally:
        engine.dispose()


@pytest.mark.parametrize(
    ("machine", "key"),
    [
        ('kind = "lsv2"\nhost = "h"\ndprnt = "tcp://h:5000"', "machines[0].dprnt"),
        ('kind = "haas_ngc"\nhost = "h"\ndprnt = "h:5000"', "machines[0].dprnt"),
        ('kind = "haas_ngc"\nhost = "h"\ndprnt = "tcp://h:99999"', "machines[0].dprnt"),
        ('kind = "haas_ngc"\nhost = "h"\nmdc = true', "machines[0].mdc"),
        ('kind = "haas_serial"\nserial = "/dev/ttyS0"\nmdc = "yes"', "machines[0].mdc"),
        (
            'kind = "haas_serial"\nserial = "/dev/ttyS0"\nmdc_interval = 0',
            "machines[0].mdc_interval",
        ),
        ('kind = "haas_ngc"\nhost = "h"\ndprnt = "serial"', "machines[0].dprnt"),
    ],
)
def test_config_errors_name_the_key(tmp_path: Path, machine: str, key: str) -> None:
    with pytest.raises(ConfigError) as caught:
        parse_config(f'[[machines]]\nname = "m"\n{machine}\n', base=tmp_path)
    assert caught.value.key == key


def _when(text: object) -> datetime | None:
    return datetime.fromisoformat(text) if isinstance(text, str) else None


class EventReader:
    """Reads the server-sent events on a thread and keeps the ``dprnt`` and ``machine`` ones."""

    def __init__(self, base: str, key: str) -> None:
        self.lines: list[dict[str, Any]] = []
        self.machines: list[dict[str, Any]] = []
        self.connected = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read, args=(base, key), daemon=True)
        self._thread.start()

    def _read(self, base: str, key: str) -> None:
        try:
            self._follow(base, key)
        except httpx.TransportError:
            # The server stopped under the stream: between two messages (a quiet stream sends
            # a keep-alive only every 15 s) a stopped reader may not have noticed yet.
            if not self._stop.is_set():
                raise

    def _follow(self, base: str, key: str) -> None:
        with (
            httpx.Client(base_url=base, timeout=None) as client,
            client.stream("GET", "/api/events", headers=auth(key)) as response,
        ):
            self.connected.set()
            kind = ""
            for line in response.iter_lines():
                if self._stop.is_set():
                    return
                if line.startswith("event: "):
                    kind = line[7:]
                elif line.startswith("data: ") and kind == "dprnt":
                    self.lines.append(json.loads(line[6:]))
                elif line.startswith("data: ") and kind == "machine":
                    self.machines.append(json.loads(line[6:]))

    def stop(self) -> None:
        self._stop.set()


@on("postgresql")
def test_lines_printed_by_a_running_program_are_stored_and_served(
    tmp_path: Path, procs: Procs, db_url: str
) -> None:
    mdc_port, dprnt_port = free_port(), free_port()
    memory = tmp_path / "ngc-mem"
    memory.mkdir()
    (memory / "O00500.nc").write_text(PRINTS)
    config = tmp_path / "shop.toml"
    config.write_text(
        f'[library]\npath = "{tmp_path / "lib"}"\n'
        '[[machines]]\nname = "vf2"\nkind = "haas_ngc"\nhost = "127.0.0.1"\n'
        f'mdc_port = {mdc_port}\ndprnt = "tcp://127.0.0.1:{dprnt_port}"\n'
    )
    key = create_key(config, db_url, role="viewer")
    base = serve(procs, config, db_url)
    events = EventReader(base, key)
    assert events.connected.wait(10)
    # The control runs O500 once a reader is on its DPRNT port (the server's listener).
    procs.start(
        "haas",
        *("sim", "haas", "--root", str(memory), "--mdc-port", str(mdc_port)),
        *("--dprnt", f"tcp:{dprnt_port}", "--run", "500"),
    )
    with httpx.Client(base_url=base, timeout=30) as client:

        def lines(since: int = 0) -> list[dict[str, Any]]:
            got: list[dict[str, Any]] = client.get(
                "/api/machines/vf2/dprnt", headers=auth(key), params={"since": since}
            ).json()
            return got

        stored = wait_for(
            "three DPRNT lines",
            lambda: len(got := lines()) == 3 and got,
            describe=lambda: (lines(), procs.log("server"), procs.log("haas")),
        )
        # DPRNT rules: [20] two digits, no decimals; [24] four decimals; * prints a space
        for n, (line, x) in enumerate(zip(stored, (1.5, 3.0, 6.0), strict=True)):
            assert re.fullmatch(rf"PASS\s+{n}\s+X\s+{x:.4f}", line["line"]), line
            assert line["numbers"] == [n, x]
            assert [f["label"] for f in line["fields"]] == ["PASS", "X"]
            assert (line["machine"], line["complete"]) == ("vf2", True)
        ids = [line["id"] for line in stored]
        assert ids == sorted(ids)
        assert lines(since=ids[0]) == stored[1:]
        assert lines(since=ids[-1]) == []

        response = client.get(
            "/api/machines/vf2/dprnt", headers=auth(key), params={"format": "csv"}
        )
        assert response.headers["content-type"].startswith("text/csv")
        rows = list(csv.DictReader(io.StringIO(response.text)))
        assert [r["line"] for r in rows] == [line["line"] for line in stored]
        assert [r["fields"] for r in rows] == ["PASS=0 X=1.5", "PASS=1 X=3", "PASS=2 X=6"]
        assert {r["complete"] for r in rows} == {"yes"}

        wait_for("the lines on the event stream", lambda: len(events.lines) == 3)
        assert [e["id"] for e in events.lines] == ids

        # The newest line is in the machine's status (MTConnect's MESSAGE), in the API and on
        # the event stream, with the time it was captured.
        # compared as times: the API's models write UTC as "Z", the event stream as "+00:00"
        last = (stored[-1]["line"], _when(stored[-1]["at"]))

        def status() -> dict[str, Any]:
            got: dict[str, Any] = (
                client.get("/api/machines/vf2", headers=auth(key)).json()["status"] or {}
            )
            return got

        wait_for(
            "the last line in the status",
            lambda: (status().get("dprnt"), _when(status().get("dprnt_at"))) == last,
            describe=status,
        )
        wait_for(
            "the last line in a status event",
            lambda: any(
                ((m["status"] or {}).get("dprnt"), _when((m["status"] or {}).get("dprnt_at")))
                == last
                for m in events.machines
            ),
        )

        assert client.get("/api/machines/vf2/dprnt").status_code == 401
        missing = client.get("/api/machines/nope/dprnt", headers=auth(key))
        assert missing.status_code == 404
        bad = client.get("/api/machines/vf2/dprnt", headers=auth(key), params={"since": -1})
        assert bad.status_code == 422  # refused where it is read (docs/server.md#api-contract)
    events.stop()

    # A restarted server shows the last line it had stored until the program prints again.
    procs.stop("server")
    with httpx.Client(base_url=serve(procs, config, db_url), timeout=30) as client:
        wait_for(
            "the stored line in the status after a restart",
            lambda: (status().get("dprnt"), _when(status().get("dprnt_at"))) == last,
            describe=status,
        )


@on("sqlite")
def test_lines_printed_on_a_serial_haas_port_between_mdc_and_xmodem(
    tmp_path: Path, procs: Procs, db_url: str
) -> None:
    haas = FleetThread(tmp_path / "machines", tnc=0, haas=0, serial_haas=1)
    try:
        sim = haas.fleet.sims["haas-serial-1"]
        port = haas.fleet.serial_ports["haas-serial-1"]
        haas.call(lambda: sim.control.save_program(PRINTS))
        haas.call(lambda: sim.control.save_program(STORED))
        client, key = serve_fleet(tmp_path, haas, procs, db_url, machine_keys='dprnt = "serial"\n')
        with client:

            def status() -> dict[str, Any]:
                machine = client.get("/api/machines/haas-serial-1", headers=auth(key)).json()
                return machine["status"] or {}

            def lines() -> list[dict[str, Any]]:
                got: list[dict[str, Any]] = client.get(
                    "/api/machines/haas-serial-1/dprnt", headers=auth(key)
                ).json()
                return got

            wait_for("the first MDC status", lambda: status().get("native_mode") == "MDI")
            haas.call(lambda: sim.control.start_program(500))  # cycle start at the control
            stored = wait_for(
                "three DPRNT lines from the serial port",
                lambda: len(got := lines()) == 3 and got,
                describe=lambda: (lines(), port.messages, procs.log("server")),
            )
            assert [line["numbers"] for line in stored] == [[0, 1.5], [1, 3.0], [2, 6.0]]
            for n, line in enumerate(stored):
                assert re.fullmatch(rf"PASS\s+{n}\s+X\s+\d\.\d{{4}}", line["line"]), line
            wait_for(
                "the last line in the status",
                lambda: (
                    (status().get("dprnt"), status().get("dprnt_at"))
                    == (stored[-1]["line"], stored[-1]["at"])
                ),
                describe=status,
            )
            # the port still does its other work: status by MDC and a punch into the inbox
            wait_for("O500 in the status", lambda: status().get("program") == "O00500")
            port.select("punch:O1234")
            items = wait_for(
                "the punch in the inbox",
                lambda: client.get("/api/inbox", headers=auth(key)).json(),
                describe=lambda: (port.messages, procs.log("server")),
            )
            assert [i["name"] for i in items] == ["O01234.nc"]
            assert len(lines()) == 3  # neither MDC replies nor the punch became DPRNT lines
    finally:
        haas.stop()
