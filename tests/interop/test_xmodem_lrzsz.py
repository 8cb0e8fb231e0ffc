"""Interop with Debian's lrzsz (``sx``/``rx``) over real pty pairs, all modes, both ways.

Our side opens the pty slave through pyserial, as ``opendnc xmodem --port /dev/pts/N`` does;
lrzsz runs on the master. ``rx`` keeps the SUB padding of the last block, so its output is
compared as "our file + SUB padding shorter than one block"; 1 MiB is a multiple of every
block size (no padding at all), the other sizes are not. Our receiver strips the padding, so
the files we receive must not end in SUB (``random_file`` sees to that).

``rx`` flushes its tty input right after writing each ACK; on a raw pty (no line delay) our
next block can land before that flush and be thrown away (rx then NAKs after 5 s). For the
"we send, rx receives" direction rx therefore runs on the pty slave and our side uses the
master in packet mode, which holds each block until rx's flush has happened
(``FlushGatedMaster``) -- the delay a real line has anyway. One test also runs rx against our
pyserial path with a 0.5 ms turnaround, where such losses are rare but possible.
"""

from __future__ import annotations

import io
from pathlib import Path

import pytest

from opendnc.xmodem.driver import receive, send
from opendnc.xmodem.events import EotAnswer
from opendnc.xmodem.framing import Mode
from opendnc.xmodem.receiver import ReceiverConfig
from opendnc.xmodem.sender import SenderConfig
from tests.interop.xmodem_peers import (
    assert_padded_copy,
    peer_link,
    peer_on_slave,
    random_file,
    stop,
)
from tests.peers import require_command

pytestmark = pytest.mark.interop

MIB = 1 << 20
SIZES = [
    pytest.param(10_000 + 33, id="10k+33"),
    pytest.param(MIB, id="1MiB"),
    # not a multiple of any block size, and the block number wrapped many times over: what
    # 5 MiB also showed, for a fifth of the time (speed is benchmarks/xmodem.py's)
    pytest.param(MIB - 77, id="1MiB-77"),
]
RX_TURNAROUND = 0.0005


# lrzsz gets file names relative to the folder it runs in (every test runs it in
# ``tmp_path``): Debian's 0.12.21-10+deb12u1 refuses an absolute path ("Security Violation").
def _rx_args(mode: Mode, out: Path) -> list[str]:
    return ["rx", "-X", "-q", *(["-c"] if mode.uses_crc else []), out.name]


def _sx_args(mode: Mode, source: Path) -> list[str]:
    return ["sx", "-X", "-q", *(["-k"] if mode is Mode.ONE_K else []), source.name]


@pytest.mark.parametrize("size", SIZES)
@pytest.mark.parametrize("mode", list(Mode))
def test_we_send_rx_receives(tmp_path: Path, mode: Mode, size: int) -> None:
    require_command("rx")
    data = random_file(tmp_path / "source.bin", size, seed=size)
    out = tmp_path / "rx.bin"
    config = SenderConfig(start_timeout=20)
    with peer_on_slave(_rx_args(mode, out), cwd=tmp_path) as (stream, proc):
        done = send(stream, data, mode=mode, config=config)
        code, err = stop(proc, timeout=15)
    assert done.size == len(data)
    # rx answers EOT about 1 s late and can lose that ACK when it exits; all blocks were
    # ACKed either way
    assert done.eot_answer in (EotAnswer.ACK, EotAnswer.CLOSED, EotAnswer.NONE)
    assert code == 0, err
    assert_padded_copy(out.read_bytes(), data, 1024 if mode is Mode.ONE_K else 128)


@pytest.mark.parametrize("size", SIZES)
@pytest.mark.parametrize("mode", list(Mode))
def test_sx_sends_we_receive(tmp_path: Path, mode: Mode, size: int) -> None:
    require_command("sx")
    data = random_file(tmp_path / "source.bin", size, seed=size + 1)
    sink = io.BytesIO()
    config = ReceiverConfig(start_timeout=20)
    with peer_link(_sx_args(mode, tmp_path / "source.bin"), cwd=tmp_path) as (stream, proc):
        done = receive(stream, sink, mode=mode, config=config)
        code, err = stop(proc, timeout=15)
    assert code == 0, err
    assert done.size == len(data)
    assert sink.getvalue() == data


@pytest.mark.parametrize("mode", list(Mode))
def test_we_send_rx_receives_through_pyserial(tmp_path: Path, mode: Mode) -> None:
    """Our real port path (pyserial on the slave) against rx on the master."""
    require_command("rx")
    data = random_file(tmp_path / "source.bin", 64 * 1024 + 5, seed=7)
    out = tmp_path / "rx.bin"
    config = SenderConfig(turnaround=RX_TURNAROUND, start_timeout=20)
    with peer_link(_rx_args(mode, out), cwd=tmp_path) as (stream, proc):
        done = send(stream, data, mode=mode, config=config)
        code, err = stop(proc, timeout=15)
    assert done.size == len(data)
    assert code == 0, err
    assert_padded_copy(out.read_bytes(), data, 1024 if mode is Mode.ONE_K else 128)
