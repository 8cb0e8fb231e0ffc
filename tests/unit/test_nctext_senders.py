"""Programs opendnc did not write are checked before they go out: XModem send and drip-feed."""

from __future__ import annotations

import io
from pathlib import Path

import pytest
from typer.testing import CliRunner

from opendnc.cli.xmodem import app
from opendnc.errors import ProgramTextError, TransferError, TransportError
from opendnc.haas.dnc import DncConfig, stream_program
from opendnc.transport.fd import FdStream
from opendnc.xmodem.driver import receive
from opendnc.xmodem.files import send_file
from opendnc.xmodem.framing import Mode
from opendnc.xmodem.receiver import ReceiverConfig
from tests.interop.xmodem_peers import pty_pair
from tests.unit.xmodem.test_driver import Worker

DAMAGED = b"%\nO01000\nG01 X1. F36.\x02G00 X0.\nM30\n%\n"
NO_PORT = "/dev/does-not-exist"


@pytest.fixture
def damaged(tmp_path: Path) -> Path:
    path = tmp_path / "O01000.nc"
    path.write_bytes(DAMAGED)
    return path


def test_xmodem_send_refuses_before_opening_the_port(damaged: Path) -> None:
    with pytest.raises(ProgramTextError, match=r"O01000\.nc: byte 0x02 .* line 3, column 13"):
        send_file(NO_PORT, damaged)
    with pytest.raises(TransportError):  # binary: the file passes, the port is what fails
        send_file(NO_PORT, damaged, binary=True)


def test_drip_feed_refuses_before_opening_the_port(damaged: Path) -> None:
    with pytest.raises(ProgramTextError, match="not drip-fed"):
        stream_program(NO_PORT, damaged, safe_mode=False)
    with pytest.raises(TransportError):
        stream_program(NO_PORT, damaged, safe_mode=False, config=DncConfig(text_check=False))


def test_cli_send_binary_sends_any_bytes(damaged: Path) -> None:
    refused = CliRunner().invoke(app, ["send", "--port", NO_PORT, str(damaged)])
    assert refused.exit_code == 1
    assert "not NC program text" in refused.output
    with pty_pair() as pair:
        sink = io.BytesIO()
        config = ReceiverConfig(start_interval=0.2)
        stream = FdStream(pair.master_fd, timeout=0.05)
        peer = Worker(lambda: receive(stream, sink, mode=Mode.CHECKSUM, config=config))
        peer.start()
        sent = CliRunner().invoke(
            app, ["send", "--port", pair.slave_path, str(damaged), "--binary", "--mode", "checksum"]
        )
        peer.outcome()
    assert sent.exit_code == 0, sent.output
    assert sink.getvalue() == DAMAGED


@pytest.mark.parametrize("binary", [False, True])
def test_receive_refuses_a_program_that_is_not_text(tmp_path: Path, binary: bool) -> None:
    from opendnc.xmodem.driver import send
    from opendnc.xmodem.files import receive_file

    with pty_pair() as pair:
        stream = FdStream(pair.master_fd, timeout=0.05)
        peer = Worker(lambda: send(stream, DAMAGED, mode=Mode.CHECKSUM))
        peer.start()
        if binary:
            report = receive_file(pair.slave_path, tmp_path, mode=Mode.CHECKSUM, binary=True)
            assert report.path.read_bytes() == DAMAGED
            peer.outcome()
        else:
            # the block is NAKed once, comes again unchanged: the bytes are in the file
            with pytest.raises(ProgramTextError, match=r"offset 21 .* the file was not written"):
                receive_file(pair.slave_path, tmp_path, mode=Mode.CHECKSUM)
            with pytest.raises(TransferError, match="receiver cancelled"):
                peer.outcome()
    assert sorted(p.name for p in tmp_path.iterdir()) == (["O01000.nc"] if binary else [])
