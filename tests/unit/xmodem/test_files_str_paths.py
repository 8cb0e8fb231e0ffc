"""Library calls take a str as well as a Path for local files."""

from __future__ import annotations

import io
from pathlib import Path

import pytest

from opendnc.errors import InputError
from opendnc.haas import share
from opendnc.transport.fd import FdStream
from opendnc.xmodem.driver import receive, send
from opendnc.xmodem.files import receive_file, send_file
from opendnc.xmodem.framing import Mode
from tests.interop.xmodem_peers import pty_pair
from tests.unit.xmodem.test_driver import Worker

PROGRAM = b"%\nO04322 (STR PATHS)\nG00 X0. Y0.\nM30\n%\n"


def test_send_file_takes_a_str(tmp_path: Path) -> None:
    source = tmp_path / "part.nc"
    source.write_bytes(PROGRAM)
    with pty_pair() as pair:
        sink = io.BytesIO()
        peer = Worker(
            lambda: receive(FdStream(pair.master_fd, timeout=0.05), sink, mode=Mode.CHECKSUM)
        )
        peer.start()
        report = send_file(pair.slave_path, str(source), mode=Mode.CHECKSUM)
        peer.outcome()
    assert sink.getvalue().rstrip(b"\x1a") == PROGRAM
    assert report.path == source


def test_receive_file_takes_a_str_folder(tmp_path: Path) -> None:
    with pty_pair() as pair:
        peer = Worker(
            lambda: send(FdStream(pair.master_fd, timeout=0.05), PROGRAM, mode=Mode.CHECKSUM)
        )
        peer.start()
        report = receive_file(pair.slave_path, str(tmp_path) + "/")
        peer.outcome()
    assert report.path == tmp_path / "O04322.nc"
    assert report.path.read_bytes() == PROGRAM


def test_receive_into_missing_folder_fails_before_opening_the_port(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="does not exist"):
        receive_file("/dev/null-not-opened", str(tmp_path / "missing") + "/")
    assert list(tmp_path.iterdir()) == []


def test_share_push_takes_str_paths(tmp_path: Path) -> None:
    source = tmp_path / "O00123.nc"
    source.write_bytes(PROGRAM)
    target = tmp_path / "share"
    target.mkdir()
    results = share.push([str(source)], share.parse_target(str(target)))
    assert (target / "O00123.nc").read_bytes() == PROGRAM
    assert len(results) == 1
