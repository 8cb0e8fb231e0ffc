"""Operations driven by scripted answers: the exact telegram sequences, fallbacks, refusals."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TypeVar

import pytest

from opendnc.errors import ControlRefused, SafetyLockError
from opendnc.lsv2 import ops
from opendnc.lsv2.constants import Family
from opendnc.lsv2.messages import (
    BlockDefect,
    ChangeDir,
    DeleteFile,
    DirInfoReply,
    DirReply,
    FileData,
    FileDone,
    Login,
    Message,
    Ok,
    ParametersReply,
    ReadDir,
    ReadDirInfo,
    ReadFile,
    ReadParameters,
    ReadRunInfo,
    ReadVersion,
    Refused,
    RunInfoReply,
    SendFile,
    SystemCommand,
    VersionReply,
)
from opendnc.lsv2.ops.base import Op, Receive, Send, SessionState, Step, ensure_login
from opendnc.lsv2.ops.files import ascii_blocks
from opendnc.lsv2.payloads import DirectoryInfo, FileEntry
from opendnc.lsv2.runinfo import NcError
from tests.unit.lsv2.samples import PARAMS

T = TypeVar("T")


def play(op: Op[T], script: Sequence[tuple[Step, Message | None]]) -> T:
    """Run ``op`` checking each step against the script and answering as scripted."""
    step = next(op)
    for expected, answer in script:
        assert step == expected
        try:
            step = op.send(answer)
        except StopIteration as done:
            return done.value  # type: ignore[no-any-return]
    raise AssertionError(f"operation wants more: {step!r}")


def test_connect_with_buffer_fallback_and_no_secure_send() -> None:
    state = SessionState()
    small = PARAMS.__class__.from_bytes(PARAMS.to_bytes())
    parts = ("TNC640", "340595 11 SP4", "PLC", "0001")
    play(
        ops.connect(state),
        [
            (Login("INSPECT"), Ok()),
            (ReadVersion(), VersionReply(parts)),
            (ReadVersion(5), Refused(24)),
            (ReadVersion(6), VersionReply(("Release",))),
            (ReadVersion(7), Refused(24)),
            (ReadParameters(), ParametersReply(small)),
            # 4088 payload bytes + 8 header bytes = 4096: asked first, then fallbacks
            (SystemCommand(7), Refused(24)),  # 4096 refused
            (SystemCommand(6), Refused(24)),  # 3072 refused
            (SystemCommand(5), Ok()),  # 2048 accepted
            (SystemCommand(19), Refused(22)),
        ],
    )
    assert state.buffer_size == 2048
    assert not state.secure_send
    assert state.family is Family.TNC_NEW
    assert state.versions is not None
    assert state.versions.release_type == "Release"
    assert state.versions.control_id is None


def test_list_dir_falls_back_to_single_entries() -> None:
    state = SessionState(logins={"FILE"})
    info = DirectoryInfo(0, "TNC:\\nc_prog\\")
    listing = play(
        ops.list_dir(state),
        [
            (ReadDirInfo(), DirInfoReply(info)),
            (ReadDir(1), Refused(24)),
            (ReadDir(0), DirReply((FileEntry("a.h", 3),))),
            (Ok(), DirReply((FileEntry("..", 0, 0, 0x20),))),
            (Ok(), FileDone()),
        ],
    )
    assert [(e.name, e.path, e.size) for e in listing] == [("a.h", "TNC:\\nc_prog\\a.h", 3)]


def test_upload_overwrites_and_waits_for_secure_ack() -> None:
    state = SessionState(logins={"FILE"}, secure_send=True, buffer_size=512)
    data = bytes(range(256)) * 3
    play(
        ops.upload(state, "TNC:/x.bin", data, binary=True),
        [
            (SendFile("TNC:\\x.bin", 1), Refused(34)),
            (DeleteFile("TNC:\\x.bin"), Ok()),
            (SendFile("TNC:\\x.bin", 1), Ok()),
            (FileData(data[:502]), Ok()),
            (FileData(data[502:]), Ok()),
            (FileDone(), Ok()),
        ],
    )


def test_upload_block_defect_is_control_refused() -> None:
    state = SessionState(logins={"FILE"})
    with pytest.raises(ControlRefused) as err:
        play(
            ops.upload(state, "TNC:/x.h", b"1 L\n", binary=False),
            [(SendFile("TNC:\\x.h", 0), Ok()), (FileData(b"1 L\0"), BlockDefect(103))],
        )
    assert err.value.code == 103
    assert "format error" in err.value.text


def test_nc_error_loop_ends_at_57() -> None:
    state = SessionState(logins={"DNC"})
    e1 = NcError(3, 3, -5, "first")
    e2 = NcError(1, 2, 7, "second")
    errors = play(
        ops.nc_errors(state),
        [
            (ReadRunInfo(27), RunInfoReply(e1.to_bytes())),
            (ReadRunInfo(28), RunInfoReply(e2.to_bytes())),
            (ReadRunInfo(28), Refused(57)),
        ],
    )
    assert errors == [e1, e2]


def test_safe_mode_blocks_before_anything_is_sent() -> None:
    state = SessionState()
    for op in (
        ops.write_machine_parameter(state, "a", "b"),
        ops.emulate_key(state, 0x01C0),
        ops.lock_keyboard(state, True),
    ):
        with pytest.raises(SafetyLockError):
            next(op)


@pytest.mark.parametrize("name", ["PLCDEBUG", "DNC", "plcdebug", " dnc"])
def test_explicit_machine_logins_are_locked_in_safe_mode(name: str) -> None:
    state = SessionState()
    with pytest.raises(SafetyLockError, match="login"):
        next(ops.login(state, name, "807667"))
    assert state.logins == set()


def test_explicit_machine_login_allowed_when_unsafe_and_other_logins_in_safe_mode() -> None:
    unsafe = SessionState(safe_mode=False)
    play(ops.login(unsafe, "PLCDEBUG", "807667"), [(Login("PLCDEBUG", "807667"), Ok())])
    assert "PLCDEBUG" in unsafe.logins
    safe = SessionState()
    play(ops.login(safe, "FILE"), [(Login("FILE", None), Ok())])
    assert safe.logins == {"FILE"}


def test_reads_still_take_machine_logins_internally_in_safe_mode() -> None:
    # R_MB needs PLCDEBUG on real controls: the implicit login must not be locked
    state = SessionState()
    play(ensure_login(state, "PLCDEBUG"), [(Login("PLCDEBUG", None), Ok())])
    assert "PLCDEBUG" in state.logins


def test_remove_dir_leaves_the_directory_first() -> None:
    state = SessionState(logins={"FILE"})
    play(
        ops.remove_dir(state, "TNC:/a/b", missing_ok=True),
        [(ChangeDir("TNC:\\a\\"), Refused(55))],
    )


@pytest.mark.parametrize("limit", [5, 8, 100])
def test_ascii_blocks_end_at_line_ends(limit: int) -> None:
    data = b"1 L\x002 LONGER LINE\x003\x00" + b"X" * 20 + b"\x00"
    blocks = list(ascii_blocks(data, limit))
    assert b"".join(blocks) == data
    assert all(len(b) <= limit for b in blocks)
    for block in blocks[:-1]:
        # only a line longer than the limit may be cut mid-line
        assert block.endswith(b"\0") or b"\0" not in block


@pytest.mark.parametrize(
    "path", ["TNC:/table/tool.t", "TNC:\\TOOL_P.TCH", "PLC:/oem.sys", "SYS:/x", "TNC:/datum.D"]
)
def test_tables_and_plc_files_are_locked_in_safe_mode(path: str) -> None:
    state = SessionState(logins={"FILE"})
    for op in (
        ops.upload(state, path, b"x", binary=True),
        ops.delete_file(state, path),
        ops.copy_file(state, "TNC:/a.h", path),
        ops.move_file(state, path, "TNC:/b.h"),
    ):
        with pytest.raises(SafetyLockError):
            next(op)
    assert next(ops.upload(SessionState(logins={"FILE"}), "TNC:/nc_prog/a.h", b"x", binary=True))


def _store_fails_on(bad: bytes) -> tuple[list[bytes], Callable[[bytes], None]]:
    stored: list[bytes] = []

    def sink(data: bytes) -> None:
        if data == bad:
            raise OSError("disk full")
        stored.append(data)

    return stored, sink


def test_download_acks_each_block_before_storing_it() -> None:
    stored, sink = _store_fails_on(b"never")
    op = ops.download(SessionState(logins={"FILE"}), "TNC:/a.h", sink, binary=False)
    assert next(op) == ReadFile("TNC:\\a.h", 0)
    assert op.send(FileData(b"1 L\0")) == Send(Ok())
    assert stored == []  # the T_OK goes out first; the block is stored while the answer travels
    assert op.send(None) == Receive()
    assert stored == [b"1 L\r\n"]
    with pytest.raises(StopIteration) as done:
        op.send(FileDone())
    assert done.value.value == 5


def test_download_store_failure_stops_the_control_at_its_next_block() -> None:
    stored, sink = _store_fails_on(b"b")
    op = ops.download(SessionState(logins={"FILE"}), "TNC:/a.bin", sink, binary=True)
    next(op)
    assert op.send(FileData(b"a")) == Send(Ok())
    assert op.send(None) == Receive()
    assert op.send(FileData(b"b")) == Send(Ok())
    assert op.send(None) == Receive()  # storing failed: the answer under way is taken first
    assert op.send(FileData(b"c")) == BlockDefect()
    with pytest.raises(OSError, match="disk full"):
        op.send(None)
    assert stored == [b"a"]


def test_download_store_failure_on_the_last_block_sends_nothing_more() -> None:
    _, sink = _store_fails_on(b"z")
    op = ops.download(SessionState(logins={"FILE"}), "TNC:/a.bin", sink, binary=True)
    next(op)
    assert op.send(FileData(b"z")) == Send(Ok())
    assert op.send(None) == Receive()  # storing failed
    with pytest.raises(OSError, match="disk full"):
        op.send(FileDone())


def test_connect_reads_max_block_length_as_payload_capacity() -> None:
    """The TNC 320 capture advertises 4088: the 4096-byte buffer (4088 + header) is chosen."""
    state = SessionState()
    parts = ("TNC320", "771855 18 SP1", "Basic V18-00", "No version given", "0000000100000100")
    play(
        ops.connect(state),
        [
            (Login("INSPECT"), Ok()),
            (ReadVersion(), VersionReply(parts)),
            (ReadVersion(5), Refused(24)),
            (ReadVersion(6), Refused(24)),
            (ReadParameters(), ParametersReply(PARAMS)),
            (SystemCommand(7), Ok()),
            (SystemCommand(19), Ok()),
        ],
    )
    assert PARAMS.max_block_length == 4088
    assert state.buffer_size == 4096
