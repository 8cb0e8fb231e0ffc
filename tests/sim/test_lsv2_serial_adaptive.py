"""Serial LSV2 at a bit-error rate of 1e-4: telegram size that follows the line, the CLI's
--telegram-size, and downloads that fail with the link's own words (docs/lsv2-serial.md,
"Telegram size")."""

from __future__ import annotations

import random
import time
from pathlib import Path

from typer.testing import CliRunner

from opendnc.cli.main import app
from opendnc.lsv2 import Client
from opendnc.lsv2.ops.base import TelegramSizer
from opendnc.lsv2.serial_stream import SerialLine
from opendnc.sim.cable import CableProcess
from opendnc.sim.tnc import start_tnc
from opendnc.sim.tnc.serial_front import attach_serial

runner = CliRunner()
BAUD = 115200


def program(lines: int) -> bytes:
    body = b"".join(
        b"%d L X+%d.5 Y-%d R0 F%d\r\n" % (i, i % 300, i, 500 + i) for i in range(1, lines)
    )
    return b"0 BEGIN PGM A MM\r\n" + body + b"%d END PGM A MM\r\n" % lines


def test_sizer_halves_after_repeated_errors_and_doubles_after_clean_blocks() -> None:
    sizer = TelegramSizer(ceiling=1024)
    assert sizer.limit(512) == 512  # the negotiated buffer caps it
    sizer.block_sent(2)
    assert sizer.size == 512  # one retried block is not yet a bad line
    sizer.block_sent(1)
    sizer.block_sent(3)
    assert sizer.size == 512  # nor two that are not in a row
    sizer.block_sent(2)
    assert sizer.changes == [(512, 256)]
    for _ in range(6):
        sizer.block_sent(4)
    assert sizer.size == 64  # the floor
    for _ in range(15):
        sizer.block_sent(1)
    assert sizer.size == 64
    sizer.block_sent(1)
    assert sizer.size == 128
    for _ in range(16 * 4):
        sizer.block_sent(1)
    assert sizer.size == 512  # back to the negotiated size, no further
    assert sizer.limit(512) == 512
    assert sizer.changes[-1] == (256, 512)


def test_upload_telegrams_shrink_on_a_bad_line_and_grow_back(tmp_path: Path) -> None:
    """At 1e-4 a 256-byte telegram fails about one try in five: retried blocks in a row
    halve the size, clean runs double it again; the file arrives exact."""
    data = program(1100)  # about 32 KiB
    root = tmp_path / "tnc"
    with (
        CableProcess(baud=BAUD, bits_per_char=11, noise=1e-4, seed=7, parity_check=True) as cable,
        start_tnc("tnc320", root=root) as tnc,
    ):
        attach_serial(tnc, cable.path_a, baud=BAUD)
        line = SerialLine(cable.path_b, BAUD, telegram_size=256)
        with Client.over_serial(line) as client:
            assert client.buffer_size == 256
            client.write_file("TNC:/A.H", data, binary=False)
            changes = client.telegram_changes
        cable.close()
    assert (root / "TNC" / "A.H").read_bytes() == data
    assert (256, 128) in changes, changes
    assert any(new > old for old, new in changes), changes


def test_cli_moves_files_both_ways_at_1e_4(tmp_path: Path) -> None:
    # One noise pattern: the CLI's path is what this adds; many patterns at this rate are
    # test_lsv2_serial_faults.py's and the property tests' (test_lsv2_serial_transfers.py).
    seed = 11
    text = program(300)  # about 9 KB
    blob = random.Random(seed).randbytes(8000) + b"\x10" * 64
    (tmp_path / "T.H").write_bytes(text)
    (tmp_path / "b.bin").write_bytes(blob)
    root = tmp_path / "tnc"
    with (
        CableProcess(
            baud=BAUD, bits_per_char=11, noise=1e-4, seed=seed, parity_check=True
        ) as cable,
        start_tnc("tnc320", root=root) as tnc,
    ):
        attach_serial(tnc, cable.path_a, baud=BAUD)
        serial = ["lsv2", "--serial", cable.path_b, "--baud", str(BAUD), "--telegram-size", "256"]
        for args in (
            ["put", "--ascii", str(tmp_path / "T.H"), "TNC:/T.H"],
            ["put", str(tmp_path / "b.bin"), "TNC:/b.bin"],
            ["get", "--ascii", "TNC:/T.H", str(tmp_path / "back.h")],
            ["get", "TNC:/b.bin", str(tmp_path / "back.bin")],
        ):
            result = runner.invoke(app, [*serial, *args])
            assert result.exit_code == 0, (args, result.stdout, result.stderr)
        stats = cable.close()
    assert stats is not None
    assert stats.parity_failed > 0, "the line was clean"
    assert (root / "TNC" / "T.H").read_bytes() == text
    assert (root / "TNC" / "b.bin").read_bytes() == blob
    assert (tmp_path / "back.h").read_bytes() == text
    assert (tmp_path / "back.bin").read_bytes() == blob


def test_download_the_control_gives_up_fails_like_an_upload(tmp_path: Path) -> None:
    """4096-byte telegrams at 1e-3 never arrive whole: the control gives its block up, and
    the client says so with the link's words (host status), not after a vague answer timeout;
    no file is left."""
    root = tmp_path / "tnc"
    (root / "TNC").mkdir(parents=True)
    (root / "TNC" / "big.bin").write_bytes(random.Random(3).randbytes(12_000))
    with (
        CableProcess(baud=BAUD, bits_per_char=11, noise=1e-3, seed=5, parity_check=True) as cable,
        start_tnc("tnc320", root=root) as tnc,
    ):
        attach_serial(tnc, cable.path_a, baud=BAUD, retries=1)
        serial = ["lsv2", "--serial", cable.path_b, "--baud", str(BAUD), "--telegram-size", "4096"]
        started = time.monotonic()
        result = runner.invoke(app, [*serial, "get", "TNC:/big.bin", str(tmp_path / "b.bin")])
        took = time.monotonic() - started
        cable.close()
    assert result.exit_code == 1, (result.stdout, result.stderr)
    assert "telegram refused with NAK on every try (host status 11 TX_ERROR)" in result.stderr
    assert "the control's telegram refused" in result.stderr
    assert not (tmp_path / "b.bin").exists()
    assert took < 60, took  # three tries of the transfer, each ended by the link's own limits
