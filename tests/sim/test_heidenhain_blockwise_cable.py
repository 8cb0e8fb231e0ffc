"""`opendnc heidenhain send/recv` against the virtual TNC in blockwise mode, through the cable.

A 2,000-line program goes to the control and comes back byte-identical (115200 baud, 10 bits a
character as 7E1; at the classic 9600 baud the same run takes about two minutes each way).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from typer.testing import CliRunner

from opendnc.cli.main import app
from opendnc.sim.cable import CableProcess
from opendnc.sim.tnc import TncHandle, start_tnc
from opendnc.sim.tnc.serial_front import attach_serial

runner = CliRunner()
LINE = ["--baud", "115200", "--timeout", "20"]


def program(n: int) -> bytes:
    lines = [b"0 BEGIN PGM BIG MM", b"1 BLK FORM 0.1 Z X+0 Y+0 Z-40"]
    lines += [
        b"%d L X%+d.%03d Y%+d.5 R0 F%d" % (i, i % 300, i % 997, -(i % 41), 500 + i)
        for i in range(2, n - 1)
    ]
    lines.append(b"%d END PGM BIG MM" % (n - 1))
    return b"".join(line + b"\r\n" for line in lines)


@pytest.fixture(scope="module")
def line(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[TncHandle, str]]:
    with (
        CableProcess(baud=115200, bits_per_char=10) as cable,
        start_tnc("itnc530", root=tmp_path_factory.mktemp("tnc")) as tnc,
    ):
        attach_serial(tnc, cable.path_a, mode="blockwise", baud=115200)
        yield tnc, cable.path_b


def test_2000_line_program_both_ways_byte_identical(
    line: tuple[TncHandle, str], tmp_path: Path
) -> None:
    tnc, port = line
    data = program(2000)
    assert data.count(b"\r\n") == 2000
    (tmp_path / "BIG.H").write_bytes(data)
    sent = runner.invoke(
        app, ["heidenhain", "send", str(tmp_path / "BIG.H"), "--port", port, *LINE]
    )
    assert sent.exit_code == 0, (sent.stdout, sent.stderr)
    assert "sent BIG.H: 2000 lines" in sent.stdout
    assert (tnc.root / "TNC" / "BIG.H").read_bytes() == data
    back = tmp_path / "back"
    back.mkdir()
    got = runner.invoke(
        app, ["heidenhain", "recv", str(back), "--port", port, "--request", "BIG.H", *LINE]
    )
    assert got.exit_code == 0, (got.stdout, got.stderr)
    assert (back / "BIG.H").read_bytes() == data


def test_request_for_a_missing_program_is_a_clear_error(
    line: tuple[TncHandle, str], tmp_path: Path
) -> None:
    _, port = line
    got = runner.invoke(
        app, ["heidenhain", "recv", str(tmp_path), "--port", port, "--request", "NONE.H", *LINE]
    )
    assert got.exit_code == 1
    assert "no file NONE.H" in got.stderr
    assert list(tmp_path.iterdir()) == []


def test_noisy_line_bad_blocks_are_nakked_and_resent(tmp_path: Path) -> None:
    """Bit errors (1e-4, with the UART's parity check) spoil some blocks: NAK, resend, exact."""
    data = program(600)
    (tmp_path / "N.H").write_bytes(data)
    with (
        CableProcess(baud=115200, bits_per_char=10, noise=1e-4, seed=5, parity_check=True) as cable,
        start_tnc("itnc530", root=tmp_path / "tnc") as tnc,
    ):
        attach_serial(tnc, cable.path_a, mode="blockwise", baud=115200)
        sent = runner.invoke(
            app, ["heidenhain", "send", str(tmp_path / "N.H"), "--port", cable.path_b, *LINE]
        )
        stats = cable.close()
    assert stats is not None
    assert stats.b_to_a.corrupted > 0, "no fault reached the control"
    if sent.exit_code == 0:
        repeated = int(sent.stdout.split("(")[1].split()[0])
        assert repeated > 0
        assert (tnc.root / "TNC" / "N.H").read_bytes() == data
    else:  # retries exhausted: a clear error and no file on the control
        assert "blockwise send" in sent.stderr
        assert not (tnc.root / "TNC" / "N.H").exists()
