"""`opendnc dprnt listen` against a real TCP peer: over-long lines, cut lines (issue 15 item 1).

The peer sends a fixed byte string and closes; the listener stops after that one link
(``--max-connects 1``) and the CSV must hold exactly the complete lines, marked as such.
"""

from __future__ import annotations

import csv
import json
import socket
import threading
import time
from collections.abc import Callable
from pathlib import Path

from typer.testing import CliRunner

from opendnc.cli.main import app

runner = CliRunner()


def capture(
    data: bytes,
    csv_path: Path,
    *extra: str,
    output: list[str] | None = None,
    before_send: Callable[[], None] | None = None,
) -> tuple[list[list[str]], dict[str, int]]:
    """Serve ``data`` to one client over real TCP, capture it with the CLI into ``csv_path``;
    return the CSV rows and the summary the command prints last."""
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    errors: list[BaseException] = []

    def serve() -> None:
        try:
            conn, _ = server.accept()
            if before_send is not None:
                before_send()
            with conn:
                conn.sendall(data)
                conn.shutdown(socket.SHUT_WR)
        except BaseException as exc:  # reported below, not lost in the thread
            errors.append(exc)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        result = runner.invoke(
            app,
            [
                "dprnt",
                "listen",
                "--port",
                f"tcp://127.0.0.1:{port}",
                "--csv",
                str(csv_path),
                "--max-connects",
                "1",
                *extra,
            ],
            env={"COLUMNS": "200"},
        )
    finally:
        server.close()
        thread.join(timeout=10)
    assert not errors, errors
    assert result.exit_code == 0, result.output
    if output is not None:
        output.append(result.output)
    summary = json.loads(result.output.strip().splitlines()[-1])
    rows = list(csv.reader(csv_path.read_text(encoding="utf-8").splitlines()))
    return rows, summary


HEADER = ["timestamp", "line", "fields", "complete"]


def test_overlong_line_is_dropped_and_the_next_line_kept(tmp_path: Path) -> None:
    # the example of the issue: today o.csv keeps only its header
    rows, summary = capture(b"M" * 5000 + b"\r\nGOOD 1\r\n", tmp_path / "o.csv")
    assert rows[0] == HEADER
    assert [row[1:] for row in rows[1:]] == [["GOOD 1", "GOOD=1", "yes"]]
    assert summary == {"lines": 1, "cut": 0, "dropped": 1}


def test_one_mebibyte_line_leaves_no_fragment(tmp_path: Path) -> None:
    data = b"BEFORE 1\r\n" + b"M" * (1 << 20) + b"\r\nGOOD 2\r\n"
    rows, summary = capture(data, tmp_path / "o.csv")
    assert [row[1] for row in rows[1:]] == ["BEFORE 1", "GOOD 2"]
    assert summary == {"lines": 2, "cut": 0, "dropped": 1}


def test_unfinished_mebibyte_line_at_disconnect_is_dropped_not_kept(tmp_path: Path) -> None:
    rows, summary = capture(b"BEFORE 1\r\n" + b"M" * (1 << 20), tmp_path / "o.csv")
    assert [row[1] for row in rows[1:]] == ["BEFORE 1"]
    assert summary == {"lines": 1, "cut": 0, "dropped": 1}


def test_line_cut_by_disconnect_is_kept_and_marked(tmp_path: Path) -> None:
    rows, summary = capture(b"GOOD 1\r\nHALF 2", tmp_path / "o.csv")
    assert [(row[1], row[3]) for row in rows[1:]] == [("GOOD 1", "yes"), ("HALF 2", "no")]
    assert summary == {"lines": 2, "cut": 1, "dropped": 0}


def test_values_are_shown_with_their_labels(tmp_path: Path) -> None:
    """What `DPRNT[X*#100[22]*Z*#5223[44]]` prints, shown as the README says: X=0 Z=-0.5."""
    shown: list[str] = []
    ready = tmp_path / "ready"
    seen: list[bool] = []

    def flag_is_up() -> None:  # the listener has the port open: its ready flag must exist
        deadline = time.monotonic() + 5
        while not ready.exists() and time.monotonic() < deadline:
            time.sleep(0.01)
        seen.append(ready.exists())

    rows, _ = capture(
        b"X  0.00 Z -0.5000\r\nP 7\r\n",
        tmp_path / "o.csv",
        "--ready-file",
        str(ready),
        output=shown,
        before_send=flag_is_up,
    )
    lines = [line for line in shown[0].splitlines() if line[:2].isdigit()]  # timestamped
    assert [line.split(" ", 1)[1] for line in lines] == [
        "X  0.00 Z -0.5000  X=0 Z=-0.5",
        "P 7  P=7",
    ]
    assert [row[1] for row in rows[1:]] == ["X  0.00 Z -0.5000", "P 7"]
    assert seen == [True]  # created once the port was open
    assert not ready.exists()  # and removed when the listener ended
