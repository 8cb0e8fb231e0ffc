"""The virtual TNC under hostile input: garbage, absurd lengths, peers vanishing mid-transfer."""

from __future__ import annotations

import contextlib
import socket
import struct
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from opendnc.lsv2.framing import Frame, TelegramFramer
from opendnc.sim.tnc import TncHandle, start_tnc
from opendnc.sim.tnc.filesystem import WirePath


@pytest.fixture(scope="module")
def tnc(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TncHandle]:
    with start_tnc("tnc640", root=tmp_path_factory.mktemp("robust")) as handle:
        yield handle


class Raw:
    """A tiny raw-socket LSV2 peer built on the project's framer."""

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=5)
        self.framer = TelegramFramer()

    def send(self, name: str, payload: bytes = b"") -> None:
        self.sock.sendall(TelegramFramer.encode(Frame(name, payload)))

    def recv(self) -> Frame:
        while (frame := self.framer.next_frame()) is None:
            data = self.sock.recv(65536)
            if not data:
                raise ConnectionError("closed")
            self.framer.feed(data)
        return frame

    def ask(self, name: str, payload: bytes = b"") -> Frame:
        self.send(name, payload)
        return self.recv()

    def closed(self) -> bool:
        try:
            self.sock.settimeout(3)
            return self.sock.recv(65536) == b"" or self.closed()
        except (ConnectionResetError, TimeoutError):
            return True

    def close(self) -> None:
        self.sock.close()


def logged_in(port: int, *logins: str) -> Raw:
    raw = Raw(port)
    for login in logins or ("INSPECT", "FILE"):
        assert raw.ask("A_LG", login.encode() + b"\0").mnemonic == "T_OK"
    return raw


def healthy(port: int) -> None:
    """Another client still gets answers."""
    raw = logged_in(port)
    try:
        assert raw.ask("R_VR").mnemonic == "S_VR"
        assert raw.ask("R_DI").mnemonic == "S_DI"
    finally:
        raw.close()


def test_unknown_and_malformed_telegrams_get_errors(tnc: TncHandle) -> None:
    raw = Raw(tnc.port)
    try:
        assert raw.ask("R_VR").payload == b"\x01\x17"  # no login yet: 23
        assert raw.ask("A_LG", b"INSPECT\0").mnemonic == "T_OK"
        assert raw.ask("Z_ZZ", b"abc").payload == b"\x01\x16"  # unknown telegram: 22
        assert raw.ask("R_RI", b"\x01").payload == b"\x01\x14"  # bad format: 20
        assert raw.ask("R_VR", b"\x63").payload == b"\x01\x18"  # bad selector: 24
        assert raw.ask("R_CD").payload == b"\x01\x18"  # exists, layout unknown: 24
        assert raw.ask("T_OK").mnemonic == "T_ER"  # nothing to continue
        assert raw.ask("R_DI").payload == b"\x01\x17"  # FILE not logged in
        big = b"x" * 300  # larger than the 256-byte start buffer
        assert raw.ask("C_DC", big + b"\0").payload == b"\x01\x14"
        assert raw.ask("R_VR").mnemonic == "S_VR"
    finally:
        raw.close()


def test_absurd_length_drops_only_that_connection(tnc: TncHandle) -> None:
    bystander = logged_in(tnc.port)
    bad = Raw(tnc.port)
    bad.sock.sendall(struct.pack(">I4s", 0xFFFFFFF0, b"S_FL") + b"junk")
    reply = bad.recv()
    assert reply.payload == b"\x01\x14"
    assert bad.closed()
    bad.close()
    assert bystander.ask("R_VR").mnemonic == "S_VR"
    bystander.close()
    healthy(tnc.port)


def test_non_ascii_name_drops_connection(tnc: TncHandle) -> None:
    bad = Raw(tnc.port)
    bad.sock.sendall(b"\x00\x00\x00\x00\xff\xfe\x00\x01")
    assert bad.recv().mnemonic == "T_ER"
    assert bad.closed()
    bad.close()
    healthy(tnc.port)


def test_truncated_telegram_then_vanish(tnc: TncHandle) -> None:
    bad = Raw(tnc.port)
    bad.sock.sendall(struct.pack(">I4s", 100, b"A_LG") + b"INSP")
    bad.close()
    healthy(tnc.port)


def _partial_files(root: Path) -> list[Path]:
    return [p for p in (root / ".partial").iterdir()]


def test_client_vanishing_mid_upload_leaves_no_file(tnc: TncHandle) -> None:
    raw = logged_in(tnc.port)
    assert raw.ask("C_FL", b"TNC:\\vanish.h\0\x01").mnemonic == "T_OK"
    assert raw.ask("S_FL", b"0 BEGIN PGM VANISH MM\r\n").mnemonic == "T_OK"
    assert len(_partial_files(tnc.root)) == 1
    raw.close()
    deadline = time.monotonic() + 3
    while _partial_files(tnc.root) and time.monotonic() < deadline:
        time.sleep(0.02)
    assert not _partial_files(tnc.root)
    assert not (tnc.root / "TNC" / "vanish.h").exists()
    healthy(tnc.port)


def test_other_telegram_mid_upload_aborts_it(tnc: TncHandle) -> None:
    raw = logged_in(tnc.port)
    try:
        assert raw.ask("C_FL", b"TNC:\\aborted.h\0\x01").mnemonic == "T_OK"
        assert raw.ask("S_FL", b"data").mnemonic == "T_OK"
        assert raw.ask("R_DI").mnemonic == "S_DI"  # upload abandoned
        raw.send("T_FD")  # no secure send: no answer, and no file
        assert raw.ask("R_VR").mnemonic == "S_VR"
        assert not (tnc.root / "TNC" / "aborted.h").exists()
        assert not _partial_files(tnc.root)
    finally:
        raw.close()


def test_oversized_block_mid_upload_is_block_defect(tnc: TncHandle) -> None:
    raw = logged_in(tnc.port)
    try:
        assert raw.ask("C_FL", b"TNC:\\toolong.h\0\x01").mnemonic == "T_OK"
        reply = raw.ask("S_FL", b"x" * 400)
        assert (reply.mnemonic, reply.payload) == ("T_BD", b"\x01\x67")
        assert not _partial_files(tnc.root)
        assert not (tnc.root / "TNC" / "toolong.h").exists()
    finally:
        raw.close()


def test_secure_send_answers_t_fd_and_upload_is_atomic(tnc: TncHandle) -> None:
    raw = logged_in(tnc.port)
    try:
        assert raw.ask("C_CC", b"\x00\x13").mnemonic == "T_OK"
        assert raw.ask("C_CC", b"\x00\x07").mnemonic == "T_OK"  # 4096
        assert raw.ask("C_FL", b"TNC:\\atomic.h\0\x01").mnemonic == "T_OK"
        assert raw.ask("S_FL", b"a" * 4000).mnemonic == "T_OK"
        assert not (tnc.root / "TNC" / "atomic.h").exists()
        assert raw.ask("T_FD").mnemonic == "T_OK"
        assert (tnc.root / "TNC" / "atomic.h").read_bytes() == b"a" * 4000
        assert raw.ask("C_FL", b"TNC:\\atomic.h\0\x01").payload == b"\x01\x22"  # exists: 34
        assert raw.ask("C_FD", b"TNC:\\atomic.h\0").mnemonic == "T_OK"
    finally:
        raw.close()


def test_operations_log_announced_by_m_cc(tnc: TncHandle) -> None:
    raw = logged_in(tnc.port)
    try:
        assert raw.ask("R_ST").mnemonic == "S_ST"
        assert raw.ask("C_ST", bytes(range(12))).mnemonic == "T_OK"
        param = b"\x00\x1boperation.log;12.09.2020;00:00:00;\0"
        assert raw.ask("C_CC", param).mnemonic == "T_OK"
        notice = raw.recv()
        assert (notice.mnemonic, notice.payload) == ("M_CC", b"\x00\x1b\x00\x64")
        block = raw.ask("R_FL", b"TNC:\\operation.log\0\x01")
        log = b""
        while block.mnemonic == "S_FL":
            log += block.payload
            block = raw.ask("T_OK")
        assert block.mnemonic == "T_FD"
        assert log.startswith(b"Operation Logbook Version 1.0")
        assert b"LSV2 login FILE" in log
    finally:
        raw.close()


def test_hostile_paths_never_leave_root(tnc: TncHandle, tmp_path: Path) -> None:
    raw = logged_in(tnc.port)
    outside = tnc.root.parent
    try:
        for path in (
            b"TNC:\\..\\..\\escape.h",
            b"..\\escape.h",
            b"/etc/passwd",
            b"TNC:/../../etc/passwd",
            b"C:\\Windows\\escape.h",
            b"TNC:\\a:b.h",
            b"TNC:\\con\x01.h",
        ):
            reply = raw.ask("C_FL", path + b"\0\x01")
            if reply.mnemonic == "T_OK":
                raw.ask("S_FL", b"x")
                raw.send("T_FD")
            raw.ask("R_VR")
        assert not list(outside.glob("escape.h"))
        assert not (tnc.root / "escape.h").exists()
        reply = raw.ask("R_FL", b"TNC:\\..\\..\\..\\..\\etc\\passwd\0\x01")
        assert reply.mnemonic == "T_ER"
    finally:
        raw.close()


@settings(
    max_examples=60,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(
    body=st.binary(max_size=64),
    name=st.sampled_from(["A_LG", "R_FI", "C_FL", "S_FL", "R_RI", "R_MB", "C_CC", "R_DP", "X_YZ"]),
    length_delta=st.integers(-8, 0),
)
def test_random_payloads_never_break_the_server(
    tnc: TncHandle, body: bytes, name: str, length_delta: int
) -> None:
    raw = logged_in(tnc.port)
    try:
        announced = max(0, len(body) + length_delta)
        raw.sock.sendall(struct.pack(">I4s", announced, name.encode()) + body[:announced])
        raw.sock.settimeout(2)
        reply = raw.recv()
        assert reply.mnemonic in ("T_OK", "T_ER", "T_BD", "S_FI", "S_RI", "S_MB", "S_DP", "S_FL")
    except (ConnectionError, TimeoutError):
        pass  # dropping this one connection is an allowed answer
    finally:
        raw.close()
    healthy(tnc.port)


def test_client_vanishing_mid_download(tnc: TncHandle) -> None:
    root_dir = WirePath("TNC:", ())
    tnc.call(lambda c: c.fs.write_atomic(c.fs.parse("TNC:\\big.bin", root_dir), b"z" * 200_000))
    raw = logged_in(tnc.port)
    assert raw.ask("R_FL", b"TNC:\\big.bin\0\x01").mnemonic == "S_FL"
    assert raw.ask("T_OK").mnemonic == "S_FL"
    raw.close()  # gone with ~780 blocks still to come
    healthy(tnc.port)
    assert (tnc.root / "TNC" / "big.bin").stat().st_size == 200_000


def test_connection_limit_answers_error_80(tmp_path: Path) -> None:
    with start_tnc("tnc640", root=tmp_path) as tnc:
        tnc.server.max_connections = 2
        first, second = logged_in(tnc.port), logged_in(tnc.port)
        third = Raw(tnc.port)
        assert third.recv().payload == b"\x01\x50"
        assert third.closed()
        third.close()
        first.close()
        deadline = time.monotonic() + 3
        while tnc.server.connections > 1 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert tnc.server.connections == 1, "the closed session still counts"
        fourth = logged_in(tnc.port)
        fourth.close()
        second.close()


def test_pipelining_flooder_does_not_starve_others(tnc: TncHandle) -> None:
    flooder = logged_in(tnc.port)
    burst = TelegramFramer.encode(Frame("R_VR")) * 5000
    flooder.sock.setblocking(False)
    # A full kernel buffer (BlockingIOError) is exactly the situation we want.
    with contextlib.suppress(BlockingIOError):
        flooder.sock.send(burst)
    probe = logged_in(tnc.port)
    try:
        t0 = time.monotonic()
        for _ in range(20):
            assert probe.ask("R_VR").mnemonic == "S_VR"
        assert time.monotonic() - t0 < 2.0
    finally:
        probe.close()
        flooder.close()
