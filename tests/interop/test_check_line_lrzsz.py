"""The program check line over a real peer: Debian's ``sx`` sends, ``receive_file`` checks.

A program whose ``(ODNC CRC32 ...)`` line matches is written and reported ``ok``; one whose
text no longer matches its line (the change issue 20 measured, ``X-2.3600`` -> ``X-2.2600``,
which the 8-bit sum and the NC-text check both let through) is refused and nothing is written.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from opendnc.haas.verify import ProgramDamaged, add_check_line
from opendnc.xmodem.files import receive_file
from opendnc.xmodem.framing import Mode
from opendnc.xmodem.receiver import ReceiverConfig
from tests.interop.xmodem_peers import peer_link, stop
from tests.peers import require_command

pytestmark = pytest.mark.interop

PROGRAM = b"%\nO01000 (FIRST)\nG00 G90 X0. Y0.\nG01 X-2.3600 F20.\nM30\n%\n"
CONFIG = ReceiverConfig(start_timeout=20)


def _sx(source: Path, out: Path) -> str | None:
    """``sx`` sends ``source``; our receiver writes into the folder ``out``."""
    require_command("sx")
    with peer_link(["sx", "-X", "-q", source.name], cwd=source.parent) as (stream, proc):
        try:
            report = receive_file(stream, out, mode=Mode.CHECKSUM, config=CONFIG)
        finally:
            stop(proc, timeout=10)
    return report.check_line


def test_a_matching_check_line_is_reported_ok(tmp_path: Path) -> None:
    source = tmp_path / "O01000.nc"
    source.write_bytes(add_check_line(PROGRAM))
    out = tmp_path / "out"
    out.mkdir()
    assert _sx(source, out) == "ok"
    assert (out / "O01000.nc").read_bytes() == source.read_bytes()


def test_a_program_without_one_is_reported_missing(tmp_path: Path) -> None:
    source = tmp_path / "O01000.nc"
    source.write_bytes(PROGRAM)
    out = tmp_path / "out"
    out.mkdir()
    assert _sx(source, out) == "missing"


def test_a_text_that_no_longer_matches_is_refused_and_not_written(tmp_path: Path) -> None:
    source = tmp_path / "O01000.nc"
    source.write_bytes(add_check_line(PROGRAM).replace(b"X-2.3600", b"X-2.2600"))
    out = tmp_path / "out"
    out.mkdir()
    with pytest.raises(ProgramDamaged, match=r"damaged on the way; the file was not written"):
        _sx(source, out)
    assert list(out.iterdir()) == []
