"""The drip-feed's progress names what has really gone out: a run stopped from its progress
callback (a cancel) or by a broken link restarts from the reported line without skipping a
block the control never got, and without sending again one it already has."""

from __future__ import annotations

from pathlib import Path

import pytest

from opendnc.errors import TransferError
from opendnc.haas.dnc import DncConfig, ProgramFeed
from opendnc.haas.dnc_engine import DncRun, Send

PROGRAM = (
    "%\nO01000 (LONG)\nG20\nT1 M06\nG54\nS1200 M03\n"
    + "".join(f"G01 X{i}.5 Y{i % 7}. F30.\n" for i in range(400))
    + "M30\n%\n"
).encode()


def _run(tmp_path: Path, from_line: int, stop_after: int) -> tuple[bytes, int]:
    """Drive a run until the progress callback has been called ``stop_after`` times and then
    raises (as the server's cancel does); what was written and the last position reported."""
    path = tmp_path / "O01000.nc"
    path.write_bytes(PROGRAM)
    feed = ProgramFeed(path, from_line=from_line)
    reported: list[int] = []

    def progress(done: int, _total: int) -> None:
        reported.append(done)
        if len(reported) >= stop_after:
            raise TransferError("cancelled")

    run = DncRun(feed, DncConfig(chunk=16), clock=lambda: 0.0, progress=progress)
    written = b""
    try:
        while True:
            step = run.next_step()
            assert isinstance(step, Send)  # no flow control here: it always sends
            written += step.data
    except TransferError:
        pass
    finally:
        feed.close()
    assert len(reported) == stop_after  # stopped by the callback, not by the program's end
    return written, reported[-1]


@pytest.mark.parametrize("stop_after", [1, 2, 7, 40, 150])
def test_the_reported_line_is_the_first_one_not_written_whole(
    tmp_path: Path, stop_after: int
) -> None:
    written, done = _run(tmp_path, 1, stop_after)
    restart_line = PROGRAM[:done].count(b"\n") + 1
    whole = written.split(b"\n")[:-1]  # the last piece is a partial line (or empty)
    assert whole == PROGRAM.split(b"\n")[: restart_line - 1]


@pytest.mark.parametrize("stop_after", [2, 9, 60])
def test_a_restarted_run_reports_lines_of_the_file(tmp_path: Path, stop_after: int) -> None:
    written, done = _run(tmp_path, 100, stop_after)
    restart_line = PROGRAM[:done].count(b"\n") + 1
    whole = written.split(b"\n")[:-1]
    line_100 = PROGRAM.split(b"\n")[99]
    preamble_end = next((i for i, w in enumerate(whole) if w == line_100), len(whole))
    assert not any(w.startswith(b"G01 X") for w in whole[:preamble_end])  # only the preamble
    sent_from_the_file = whole[preamble_end:]
    assert restart_line == 100 + len(sent_from_the_file)
