"""The punch receiver's endings and the split of the control's bytes during a send."""

from __future__ import annotations

from pathlib import Path

import pytest

from opendnc.errors import InputError, TransferError, TransportTimeout
from opendnc.tape.codes import Code, Codec
from opendnc.tape.profiles import get_profile
from opendnc.tape.reader import End
from opendnc.tape.serial_io import Incoming, first_difference, unique_path, write_files
from opendnc.tape.session import PunchReceiver


def _iso(text: str) -> bytes:
    return Codec(Code.ISO, parity=True).encode_text(text, 0)


def test_a_punch_starts_at_dc2_and_ends_at_its_percent() -> None:
    receiver = PunchReceiver(get_profile("fanuc-0i"), start_timeout=1.0)
    receiver.receive_data(_iso("\x11\x13O0001\n"))  # flow bytes and stray text before DC2
    assert not receiver.finished
    receiver.receive_data(b"\x12\0\0" + _iso("%\nO0009\nG01\n%\n") + b"\0\x14")
    result = receiver.result()
    assert (result.text, result.name, result.ended) == (
        "%\nO0009\nG01\n%\n",
        "O0009.nc",
        End.PERCENT,
    )
    assert receiver.leftover == _iso("\n") + b"\0\x14"


def test_quiet_before_the_end_is_a_failure_unless_asked() -> None:
    strict = PunchReceiver(get_profile("fanuc-0i"), quiet=0.1)
    strict.receive_data(b"\x12" + _iso("%\nO0009\nG01\n"))
    with pytest.raises(TransferError, match=r"quiet .* line 4.*nothing was written"):
        strict.timed_out()
    loose = PunchReceiver(get_profile("fanuc-0i"), quiet=0.1, quiet_ends=True)
    loose.receive_data(b"\x12" + _iso("X 1.500\n"))
    loose.timed_out()
    assert loose.result().text == "X 1.500\n"


def test_no_punch_and_a_closed_link_are_typed() -> None:
    waiting = PunchReceiver(get_profile("fanuc-0i"), start_timeout=2.0)
    with pytest.raises(TransportTimeout, match="no punch from the control within 2 s"):
        waiting.timed_out()
    cut = PunchReceiver(get_profile("siemens-840d"))
    cut.receive_data(b"%_N_A_MPF\nG0 X1\n")
    with pytest.raises(TransferError, match="the link closed after 16 bytes"):
        cut.peer_closed()


def test_incoming_takes_both_dc3_bytes_and_keeps_a_punch_whole() -> None:
    incoming = Incoming()
    assert incoming.split(b"\x11\x93\x13\x91") == b"\x11\x13\x13\x11"
    punch = b"\x12\x00" + _iso("%\nX3\n")
    assert incoming.split(b"\x11" + punch) == b"\x11"
    assert incoming.split(b"\x13") == b""  # after DC2 everything belongs to the punch
    assert bytes(incoming.kept) == punch + b"\x13"


def test_first_difference_names_the_line() -> None:
    assert first_difference("%\nA\nB\n", "%\nA \nB\n") is None
    assert first_difference("%\nA\nB\n", "%\nA\nC\n") == "line 3: sent 'B', punched 'C'"


def test_only_characters_and_the_leader_keep_a_punch_open() -> None:
    receiver = PunchReceiver(get_profile("fanuc-0i"), start_timeout=1.0, quiet=0.5)
    receiver.receive_data(b"\x12")
    armed = receiver.timer
    receiver.receive_data(b"\0" * 20)  # leader: the punch is coming
    assert receiver.timer is not armed
    receiver.receive_data(_iso("%\nO0009\n"))
    armed = receiver.timer
    for _ in range(50):  # a noisy line after the start: filler and DC codes only
        receiver.receive_data(b"\0\x11\xff\x93" * 100)
    assert receiver.timer is armed
    with pytest.raises(TransferError, match=r"quiet for 0\.5 s"):
        receiver.timed_out()


def test_files_are_written_all_or_none(tmp_path: Path) -> None:
    (tmp_path / "B.SPF").mkdir()  # the second rename fails: a folder holds its name
    (tmp_path / "B.SPF" / "keep").write_text("x")
    with pytest.raises(InputError, match=r"cannot write .*B\.SPF: .*nothing was written"):
        write_files([(tmp_path / "A.MPF", b"%_N_A_MPF\n"), (tmp_path / "B.SPF", b"%_N_B_SPF\n")])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["B.SPF"]
    write_files([(tmp_path / "A.MPF", b"A\n"), (tmp_path / "C.SPF", b"C\n")])
    assert (tmp_path / "A.MPF").read_bytes() + (tmp_path / "C.SPF").read_bytes() == b"A\nC\n"


def test_unique_path_skips_names_taken_on_disk_or_planned(tmp_path: Path) -> None:
    (tmp_path / "O0001.nc").write_text("%\n")
    planned = [tmp_path / "O0001-1.nc"]
    assert unique_path(tmp_path, "O0001.nc", planned) == tmp_path / "O0001-2.nc"
    with pytest.raises(InputError, match="file name too long"):
        unique_path(tmp_path, "N" * 5000 + ".nc")
