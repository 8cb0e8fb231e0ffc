"""Issue 15, item 5: an R_FL download streams from disk; a quiet downloader holds one block.

The simulator runs in a thread of this process, so tracemalloc sees its allocations: the peak
while connections start downloading a large file and then go quiet must stay near a telegram
buffer per connection, not the file size.
"""

from __future__ import annotations

import os
import tracemalloc
from collections.abc import Iterator
from pathlib import Path

import pytest

from opendnc.lsv2.payloads import to_wire_ascii
from opendnc.sim.tnc import TncHandle, start_tnc
from tests.sim.tnc.test_robustness import Raw, logged_in

BIG = 24 * 1024 * 1024


@pytest.fixture(scope="module")
def tnc(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TncHandle]:
    root = tmp_path_factory.mktemp("stream")
    with start_tnc("tnc640", root=root) as handle:
        folder = handle.root / "TNC" / "nc_prog"
        folder.mkdir(parents=True, exist_ok=True)
        with (folder / "BIG.H").open("wb") as out:
            block = os.urandom(1 << 20)
            for _ in range(BIG >> 20):
                out.write(block)
        yield handle


def test_quiet_downloads_hold_blocks_not_files(tnc: TncHandle) -> None:
    clients: list[Raw] = []
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        for _ in range(4):
            raw = logged_in(tnc.port)
            clients.append(raw)
            first = raw.ask("R_FL", b"TNC:\\nc_prog\\BIG.H\0\x01")
            assert first.mnemonic == "S_FL"
            assert 0 < len(first.payload) <= 4096
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
        for raw in clients:
            raw.close()
    # today's code read the whole 24 MiB per R_FL; streaming holds a few telegram buffers
    assert peak < 2 * 1024 * 1024, f"peak {peak / 1e6:.1f} MB while 4 downloads sat idle"


def _download(raw: Raw, path: bytes, mode: int) -> list[bytes]:
    blocks = []
    reply = raw.ask("R_FL", path + b"\0" + bytes([mode]))
    while reply.mnemonic == "S_FL":
        blocks.append(reply.payload)
        reply = raw.ask("T_OK")
    assert reply.mnemonic == "T_FD"
    return blocks


@pytest.mark.parametrize("size", [0, 1, 245, 246, 247, 5000])
def test_ascii_download_streams_the_same_bytes(tnc: TncHandle, size: int) -> None:
    """CR LF pairs cut by a block edge still become one NUL; every block but the last is full."""
    text = (b"L X+1 Y+2 FMAX\r\n" * 400 + b"CR ALONE\rLF ALONE\n" * 50)[:size]
    (tnc.root / "TNC" / "nc_prog" / "ASCII.H").write_bytes(text)
    raw = logged_in(tnc.port)
    try:
        blocks = _download(raw, b"TNC:\\nc_prog\\ASCII.H", 0)
        binary = _download(raw, b"TNC:\\nc_prog\\ASCII.H", 1)
    finally:
        raw.close()
    assert b"".join(blocks) == to_wire_ascii(text)
    assert b"".join(binary) == text
    step = max(len(b) for b in blocks)
    assert all(len(b) == step for b in blocks[:-1])
    assert len(blocks) >= 1


def test_missing_file_is_refused_at_once(tnc: TncHandle) -> None:
    raw = logged_in(tnc.port)
    try:
        reply = raw.ask("R_FL", b"TNC:\\nc_prog\\NOPE.H\0\x01")
        assert reply.mnemonic == "T_ER"
        assert raw.ask("R_VR").mnemonic == "S_VR"
    finally:
        raw.close()


def test_abandoned_download_closes_the_file(tnc: TncHandle, tmp_path: Path) -> None:
    raw = logged_in(tnc.port)
    try:
        assert raw.ask("R_FL", b"TNC:\\nc_prog\\BIG.H\0\x01").mnemonic == "S_FL"
        assert raw.ask("R_DI").mnemonic == "S_DI"  # another command ends the download
        # the simulator no longer holds BIG.H open
        held = [
            os.readlink(f"/proc/self/fd/{fd}")
            for fd in os.listdir("/proc/self/fd")
            if os.path.exists(f"/proc/self/fd/{fd}")
        ]
        assert not any(p.endswith("BIG.H") for p in held), held
    finally:
        raw.close()
