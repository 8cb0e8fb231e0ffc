"""`opendnc xmodem send|recv` over a real pty, our engine in a thread on the master side."""

from __future__ import annotations

import io
from pathlib import Path

from typer.testing import CliRunner

from opendnc.cli.xmodem import app
from opendnc.transport.fd import FdStream
from opendnc.xmodem.driver import receive, send
from opendnc.xmodem.framing import Mode, encode_block
from opendnc.xmodem.receiver import ReceiverConfig
from tests.interop.xmodem_peers import pty_pair
from tests.unit.xmodem.test_driver import Worker

PROGRAM = b"%\nO04321(CLI TEST)\nG00 X0. Y0.\nM30\n%\n"


def test_send_converts_eob_and_names_the_program(tmp_path: Path) -> None:
    source = tmp_path / "part.nc"
    source.write_bytes(PROGRAM)
    with pty_pair() as pair:
        sink = io.BytesIO()
        # the CLI opens its port after our first NAK and so discards it: NAK again soon
        config = ReceiverConfig(start_interval=0.2)
        peer = Worker(
            lambda: receive(
                FdStream(pair.master_fd, timeout=0.05), sink, mode=Mode.CHECKSUM, config=config
            )
        )
        peer.start()
        result = CliRunner().invoke(
            app,
            ["send", "--port", pair.slave_path, str(source), "--eob", "crlf"],
        )
        peer.outcome()
    assert result.exit_code == 0, result.output
    assert "O04321" in result.output
    assert sink.getvalue() == PROGRAM.replace(b"\n", b"\r\n")


def test_recv_into_folder_names_file_by_o_number(tmp_path: Path) -> None:
    wire = PROGRAM.replace(b"\n", b"\r\n")
    with pty_pair() as pair:
        peer = Worker(
            lambda: send(FdStream(pair.master_fd, timeout=0.05), wire, mode=Mode.CHECKSUM)
        )
        peer.start()
        result = CliRunner().invoke(
            app,
            ["recv", "--port", pair.slave_path, str(tmp_path), "--eob", "crlf"],
        )
        peer.outcome()
    assert result.exit_code == 0, result.output
    assert [p.name for p in tmp_path.iterdir()] == ["O04321.nc"]
    assert (tmp_path / "O04321.nc").read_bytes() == PROGRAM


def test_failed_recv_leaves_no_file_and_exits_1(tmp_path: Path) -> None:
    out = tmp_path / "out.nc"
    data = bytes(range(256)) * 20
    with pty_pair() as pair:
        master = FdStream(pair.master_fd, timeout=10.0)  # a read returns as data comes: the
        # timeout only bounds a wait for a receiver slowed by a busy machine

        def partial_sender() -> None:
            assert master.read(10) == b"\x15"
            for seq in (1, 2, 3):
                master.write(encode_block(seq, data[(seq - 1) * 128 : seq * 128], crc=False))
                assert master.read(10) == b"\x06"
            master.write(b"\x18\x18")

        peer = Worker(partial_sender)
        peer.start()
        result = CliRunner().invoke(app, ["recv", "--port", pair.slave_path, str(out), "--binary"])
        peer.outcome()
    assert result.exit_code == 1
    assert "sender cancelled the transfer after" in result.output
    assert list(tmp_path.iterdir()) == []
