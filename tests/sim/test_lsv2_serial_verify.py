"""Every serial text upload is verified end to end (docs/lsv2-serial.md, "Every text upload
verified"): the size the control reports after its own line-end conversion, else a read-back.

The link engine closes the lost-block path it knows of; these tests make a block vanish at the
control behind the link's back (an unknown fault) and see the upload fail with a typed error,
no file left, instead of reporting success.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from opendnc.errors import TransferError
from opendnc.lsv2 import Client
from opendnc.lsv2.framing import Frame
from opendnc.lsv2.ops.files import text_size
from opendnc.lsv2.payloads import to_wire_ascii
from opendnc.sim.tnc import TncHandle, start_tnc
from opendnc.sim.tnc.serial_front import SerialFront, attach_serial


def program(lines: int) -> bytes:
    body = b"".join(
        b"%d L X+%d.5 Y-%d R0 F%d\r\n" % (i, i % 300, i, 500 + i) for i in range(1, lines)
    )
    return b"0 BEGIN PGM V MM\r\n" + body + b"%d END PGM V MM\r\n" % lines


@pytest.fixture
def tnc(tmp_path: Path) -> Iterator[tuple[TncHandle, SerialFront]]:
    with start_tnc("tnc320", root=tmp_path / "tnc") as handle:
        yield handle, attach_serial(handle, "pty")


def test_text_size_counts_the_controls_line_ends() -> None:
    data = b"0 BEGIN PGM V MM\r\n1 L X+1\n2 END PGM V MM\r\n"
    assert text_size(data) == len(data) + 1  # the bare LF is stored as CR LF
    assert text_size(data, b"\n") == len(data) - 2
    assert text_size(b"no line end") == 11


def test_clean_text_upload_is_checked_by_size_alone(
    tnc: tuple[TncHandle, SerialFront], tmp_path: Path
) -> None:
    _handle, front = tnc
    data = program(300)
    (tmp_path / "V.H").write_bytes(data)
    with Client.over_serial(front.path, max_buffer=256) as client:
        client.upload(tmp_path / "V.H", "TNC:/V.H", binary=False)
        assert (client.serial_checks, client.serial_readbacks) == (1, 0)
    assert (tmp_path / "tnc" / "TNC" / "V.H").read_bytes() == data


def test_block_lost_behind_the_links_back_fails_the_upload(
    tnc: tuple[TncHandle, SerialFront], tmp_path: Path
) -> None:
    _handle, front = tnc
    data = program(300)
    deliver = front._deliver
    seen = {"S_FL": 0}

    def lose_block_5(frame: Frame) -> None:
        if frame.mnemonic == "S_FL":
            seen["S_FL"] += 1
            if seen["S_FL"] == 5:
                frame = Frame("S_FL", b"")  # confirmed, answered T_OK, and stored as nothing
        deliver(frame)

    front._deliver = lose_block_5  # type: ignore[method-assign]
    with Client.over_serial(front.path, max_buffer=256) as client:
        with pytest.raises(TransferError, match=r"reads back .* bytes on the control"):
            client.write_file("TNC:/V.H", data, binary=False)
        assert client.serial_readbacks == 1
    assert seen["S_FL"] > 5
    assert not (tmp_path / "tnc" / "TNC" / "V.H").exists(), "a damaged program was left"


def test_control_storing_other_line_ends_passes_by_read_back(
    tnc: tuple[TncHandle, SerialFront], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A control that writes LF for each NUL reports another size; the read-back, NUL line ends
    and all, shows the text arrived exact."""
    import opendnc.sim.tnc.handlers_files as handlers

    monkeypatch.setattr(handlers, "from_wire_ascii", lambda data: data.replace(b"\0", b"\n"))
    _handle, front = tnc
    data = program(120)
    with Client.over_serial(front.path, max_buffer=256) as client:
        client.write_file("TNC:/V.H", data, binary=False)
        assert (client.serial_checks, client.serial_readbacks) == (1, 1)
    stored = (tmp_path / "tnc" / "TNC" / "V.H").read_bytes()
    assert stored == data.replace(b"\r\n", b"\n")
    assert to_wire_ascii(stored) == to_wire_ascii(data)
