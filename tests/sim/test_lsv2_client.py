"""The blocking Client over real TCP against the virtual TNC."""

from __future__ import annotations

import io
import os
import stat
import struct
from collections.abc import Iterator
from datetime import datetime
from pathlib import Path

import pytest

from opendnc.errors import (
    ControlRefused,
    InputError,
    SafetyLockError,
    TransportError,
    TransportTimeout,
)
from opendnc.lsv2 import Client, ExecutionMode, Family, KeyCode, MemoryType, ProgramState
from opendnc.lsv2.messages import Message
from opendnc.lsv2.payloads import ScopeSignal
from opendnc.sim.tnc import TncHandle, start_tnc
from tests.sim.lsv2_fixtures import itnc530, pinned_state, tnc640

__all__ = ["itnc530", "tnc640"]


@pytest.fixture
def client(tnc640: TncHandle) -> Iterator[Client]:
    with Client("127.0.0.1", tnc640.port, timeout=5) as c:
        yield c


@pytest.fixture
def unsafe(tnc640: TncHandle) -> Iterator[Client]:
    with Client("127.0.0.1", tnc640.port, timeout=5, safe_mode=False) as c:
        yield c


@pytest.fixture
def old(itnc530: TncHandle) -> Iterator[Client]:
    with Client("127.0.0.1", itnc530.port, timeout=5, safe_mode=False) as c:
        yield c


def disk(tnc: TncHandle, wire: str) -> Path:
    drive, _, rest = wire.partition(":")
    return Path(tnc.root, drive, *[p for p in rest.replace("\\", "/").split("/") if p])


def test_connect_sequence_and_trace(tnc640: TncHandle) -> None:
    seen: list[tuple[str, Message]] = []
    raw: list[tuple[str, bytes]] = []
    with Client(
        "127.0.0.1",
        tnc640.port,
        trace=lambda d, m: seen.append((d, m)),
        trace_bytes=lambda d, b: raw.append((d, b)),
    ) as c:
        assert c.versions.model == "TNC640"
        assert c.family is Family.TNC_NEW
        assert c.buffer_size == 4096  # sim advertises 4096
        assert c.secure_file_send
        assert c.parameters.max_block_length >= 4096
        assert "INSPECT" in c.logins
    assert raw[0] == ("send", bytes.fromhex("00000008415F4C47494E535045435400"))
    assert raw[1] == ("recv", bytes.fromhex("00000000545F4F4B"))
    names = [m.mnemonic for d, m in seen if d == "send"]
    assert names[:2] == ["A_LG", "R_VR"]
    assert names[-1] == "A_LO"
    assert ("recv", seen[1][1]) in seen


def test_buffer_fits_max_block_length_of_payload() -> None:
    # 4088 payload bytes + 8 header bytes: the 4096-byte telegram buffer is the right one
    with start_tnc("tnc320") as tnc, Client("127.0.0.1", tnc.port) as c:
        assert c.parameters.max_block_length == 4088
        assert c.buffer_size == 4096
        assert c.versions.splc == "No version given"
    with start_tnc("tnc426") as tnc, Client("127.0.0.1", tnc.port) as c:
        assert c.buffer_size == 1024
    with start_tnc("tnc640") as tnc, Client("127.0.0.1", tnc.port, max_buffer=256) as c:
        assert c.buffer_size == 256


def test_old_tnc426_connects_without_newer_selectors() -> None:
    with start_tnc("tnc426") as tnc, Client("127.0.0.1", tnc.port) as c:
        assert c.family is Family.TNC4XX
        assert c.versions.control_id is None
        with pinned_state(tnc, ProgramState.CANCELLED, ExecutionMode.PASS_REFERENCES):
            assert c.program_state() is ProgramState.CANCELLED
            assert c.execution_mode() is ExecutionMode.PASS_REFERENCES
        names = {e.name for e in c.list_dir("TNC:/")}
        assert names


def test_listing_drives_and_info(client: Client, tnc640: TncHandle) -> None:
    drives = [d.name for d in client.drives()]
    assert "TNC:" in drives
    root = client.list_dir("TNC:/")
    by_name = {e.name: e for e in root}
    assert by_name["nc_prog"].is_dir
    assert by_name["table"].is_dir
    single = client.list_dir("TNC:/nc_prog", multi=False)
    multi = client.list_dir("TNC:/nc_prog", multi=True)
    assert [(e.name, e.size) for e in single] == [(e.name, e.size) for e in multi]
    on_disk = {p.name for p in disk(tnc640, "TNC:/nc_prog").iterdir() if not p.name.startswith(".")}
    assert {e.name for e in multi} == on_disk
    info = client.dir_info()
    assert info.path.rstrip("\\/").endswith("nc_prog")
    some_file = next(e for e in multi if not e.is_dir)
    fi = client.file_info(some_file.path)
    assert fi is not None
    assert fi.size == some_file.size == disk(tnc640, some_file.path).stat().st_size
    assert client.file_info("TNC:/nc_prog/does_not_exist.h") is None
    assert not client.exists("TNC:/nope/none.h")


def test_mkdir_recursive_rmdir_delete(client: Client, tnc640: TncHandle) -> None:
    assert client.make_dir("TNC:/t_mk/a/b")
    assert disk(tnc640, "TNC:/t_mk/a/b").is_dir()
    assert not client.make_dir("TNC:/t_mk/a/b")
    info = client.file_info("TNC:/t_mk/a")
    assert info is not None
    assert info.is_dir
    with pytest.raises(ControlRefused) as err:
        client.remove_dir("TNC:/t_mk/a")  # not empty
    assert err.value.code == 54
    assert "directory" in err.value.text
    client.remove_dir("TNC:/t_mk/a/b")
    client.remove_dir("TNC:/t_mk/a")
    client.remove_dir("TNC:/t_mk/a", missing_ok=True)
    client.delete_file("TNC:/t_mk/none.h", missing_ok=True)
    with pytest.raises(ControlRefused) as err:
        client.delete_file("TNC:/t_mk/none.h")
    assert err.value.code == 32
    assert err.value.text == "file not found"


@pytest.mark.parametrize("size", [0, 1, 4086, 4087, 100_000])
def test_binary_round_trip(client: Client, tnc640: TncHandle, tmp_path: Path, size: int) -> None:
    data = os.urandom(size)
    src = tmp_path / "up.bin"
    src.write_bytes(data)
    remote = f"TNC:/nc_prog/rt_{size}.bin"
    assert client.upload(src, remote) == size
    assert disk(tnc640, remote).read_bytes() == data
    dst = tmp_path / "down.bin"
    assert client.download(remote, dst) == size
    assert dst.read_bytes() == data
    assert client.read_file(remote) == data
    client.upload(src, remote)  # overwrite works
    client.delete_file(remote)


def test_ascii_line_ends(client: Client, tnc640: TncHandle, tmp_path: Path) -> None:
    lines = [f"{i} L X+{i} Y-{i} F1000" for i in range(600)]
    text_lf = ("\n".join(lines) + "\n").encode()
    remote = "TNC:/nc_prog/ascii_test.h"
    seen: list[tuple[int, int | None]] = []
    crlf = text_lf.replace(b"\n", b"\r\n")
    client.write_file(remote, crlf, binary=False, progress=lambda d, t: seen.append((d, t)))
    assert seen[-1] == (len(crlf), len(crlf))
    assert [d for d, _ in seen] == sorted(d for d, _ in seen)
    client.write_file(remote, text_lf, binary=False)
    stored = disk(tnc640, remote).read_bytes()
    assert stored == text_lf.replace(b"\n", b"\r\n")
    assert client.read_file(remote, binary=False) == stored
    assert client.read_file(remote, binary=False, line_end=b"\n") == text_lf
    progress: list[tuple[int, int | None]] = []
    client.download(
        remote, tmp_path / "a.h", binary=False, progress=lambda d, t: progress.append((d, t))
    )
    assert (tmp_path / "a.h").read_bytes() == stored
    assert progress[-1][0] == len(stored)
    client.delete_file(remote)


def test_failed_download_leaves_no_file(client: Client, tmp_path: Path) -> None:
    target = tmp_path / "never.h"
    with pytest.raises(ControlRefused) as err:
        client.download("TNC:/nc_prog/missing.h", target)
    assert err.value.code == 32
    assert list(tmp_path.iterdir()) == []


def test_download_and_upload_get_umask_permissions(
    client: Client, tnc640: TncHandle, tmp_path: Path
) -> None:
    # both ends used mkstemp's 0600 once; a downloaded program must be readable by other users
    src = tmp_path / "up.h"
    src.write_bytes(b"0 BEGIN PGM UP MM\r\n1 END PGM UP MM\r\n")
    old = os.umask(0o027)
    try:
        client.upload(src, "TNC:/nc_prog/perm.h")
        client.download("TNC:/nc_prog/perm.h", tmp_path / "down.h")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "down.h").stat().st_mode) == 0o640
    assert stat.S_IMODE(disk(tnc640, "TNC:/nc_prog/perm.h").stat().st_mode) == 0o640
    client.delete_file("TNC:/nc_prog/perm.h")


def test_upload_missing_local_file(client: Client, tmp_path: Path) -> None:
    with pytest.raises(InputError):
        client.upload(tmp_path / "nope.h", "TNC:/nc_prog/nope.h")


def test_copy_and_move(client: Client, tnc640: TncHandle) -> None:
    client.write_file("TNC:/nc_prog/cp_src.h", b"0 BEGIN PGM X MM\r\n", binary=True)
    client.make_dir("TNC:/cp_dir")
    client.copy_file("TNC:/nc_prog/cp_src.h", "TNC:/cp_dir/")
    assert disk(tnc640, "TNC:/cp_dir/cp_src.h").read_bytes() == b"0 BEGIN PGM X MM\r\n"
    client.move_file("TNC:/cp_dir/cp_src.h", "TNC:/cp_dir/renamed.h")
    assert not disk(tnc640, "TNC:/cp_dir/cp_src.h").exists()
    assert disk(tnc640, "TNC:/cp_dir/renamed.h").exists()
    client.move_file("TNC:/nc_prog/cp_src.h", "TNC:/cp_dir/moved.h")
    assert not disk(tnc640, "TNC:/nc_prog/cp_src.h").exists()
    with pytest.raises(ControlRefused):
        client.copy_file("TNC:/nc_prog/cp_src.h", "TNC:/cp_dir/x.h")
    for name in ("renamed.h", "moved.h"):
        client.delete_file(f"TNC:/cp_dir/{name}")
    client.remove_dir("TNC:/cp_dir")


def test_machine_state(client: Client, tnc640: TncHandle) -> None:
    program = next(e for e in client.list_dir("TNC:/nc_prog") if e.name.lower().endswith(".h"))
    tnc640.call(lambda c: c.select_program(program.path))
    sel = client.selected_program()
    assert sel.main.lower().replace("/", "\\") == program.path.lower()
    with pinned_state(tnc640, ProgramState.INTERRUPTED, ExecutionMode.SINGLE_STEP):
        assert client.program_state() is ProgramState.INTERRUPTED
        assert client.execution_mode() is ExecutionMode.SINGLE_STEP
    tnc640.call(lambda c: c.machine.set_overrides(5000, 12000, 100))
    ov = client.overrides()
    assert (ov.feed, ov.spindle, ov.rapid) == (5000, 12000, 100)
    assert ov.percent == (50.0, 120.0, 1.0)
    axes = client.axes_position()
    assert set(axes.as_dict()) >= {"X", "Y", "Z"}
    before = tnc640.call(lambda c: c.machine.uptimes())
    up = client.uptimes()
    after = tnc640.call(lambda c: c.machine.uptimes())
    assert up.nc is not None
    assert before[30] <= up.nc <= after[30]  # the simulator's own clock brackets the answer
    assert before[33] <= (up.spindle1 or 0) <= after[33]
    assert up.spindle2 == 0  # the TNC 640 profile has one spindle


def test_keys_need_unsafe_mode(client: Client, unsafe: Client, tnc640: TncHandle) -> None:
    with pytest.raises(SafetyLockError):
        client.send_key(KeyCode.MODE_MANUAL)
    with pytest.raises(SafetyLockError):
        client.lock_keyboard()
    unsafe.send_key(KeyCode.MODE_AUTOMATIC)
    assert unsafe.execution_mode() is ExecutionMode.AUTOMATIC
    unsafe.send_key(KeyCode.MODE_MANUAL)
    assert unsafe.execution_mode() is ExecutionMode.MANUAL
    with pytest.raises(ControlRefused) as err:
        unsafe.send_key(0x7FFF)
    assert err.value.code == 39


def test_explicit_machine_logins_need_unsafe_mode(
    client: Client, unsafe: Client, tnc640: TncHandle
) -> None:
    for name in ("PLCDEBUG", "DNC"):
        with pytest.raises(SafetyLockError):
            client.login(name)
        assert name not in client.logins
    client.login("FILE")  # harmless logins stay available in safe mode
    # reads that need those logins still work: they log in internally
    with pinned_state(tnc640, ProgramState.IDLE, ExecutionMode.MDI):
        assert client.execution_mode() is ExecutionMode.MDI
    assert len(client.read_plc("M0", 1)) == 1
    assert {"DNC", "PLCDEBUG"} <= client.logins
    unsafe.login("DNC")
    assert "DNC" in unsafe.logins


def test_plc_memory_every_operand(client: Client, tnc640: TncHandle) -> None:
    def setup(c: object) -> None:
        plc = c.plc  # type: ignore[attr-defined]
        plc.set_bit("M", 905, True)
        plc.set_bit("I", 2, True)
        plc.set_bit("O", 3, True)
        plc.set_bit("C", 1, True)
        plc.set_bit("T", 4, True)
        plc.set_word(1008, 0xFFFE)
        plc.set_dword(1016, -123456)
        plc.set_string(2, "hello PLC")
        lay = plc.layout
        plc.write(lay.words_start + 1003, b"\x85")
        plc.write(lay.input_words_start + 4, struct.pack("<H", 4321))
        plc.write(lay.output_words_start + 8, struct.pack("<i", -77))
        plc.write(lay.input_words_start + 12, struct.pack("<i", 99999))
        plc.write(lay.output_words_start + 2, struct.pack("<H", 65000))

    tnc640.call(setup)
    assert client.read_plc("M904", 3) == [False, True, False]
    assert client.read_plc("I2") == [True]
    assert client.read_plc("O3") == [True]
    assert client.read_plc("C1") == [True]
    assert client.read_plc("T4") == [True]
    assert client.read_plc("B1003") == [-123]
    assert client.read_plc("W1008") == [-2]
    assert client.read_plc("D1016") == [-123456]
    assert client.read_plc("S2") == ["hello PLC"]
    assert client.read_plc("IW4") == [4321]
    assert client.read_plc("OW2") == [65000]
    assert client.read_plc("OD8") == [-77]
    assert client.read_plc("ID12") == [99999]
    assert client.read_plc_memory(MemoryType.WORD, 504) == [-2]
    # multi-telegram reads: 600 markers = 3 R_MB telegrams, 200 words = 2
    many = client.read_plc("M400", 600)
    assert len(many) == 600
    assert many[505] is True
    assert many[495:510] == [client.read_plc(f"M{400 + i}")[0] for i in range(495, 510)]
    words = client.read_plc("W800", 200)
    assert words[104] == -2
    assert words[108] == client.read_plc("W1016")[0]
    assert client.read_plc("S0", 3)[2] == "hello PLC"
    with pytest.raises(InputError):
        client.read_plc("W3")
    with pytest.raises(InputError):
        client.read_plc("X3")
    with pytest.raises(InputError):
        client.read_plc("M0", 10**7)


def test_machine_parameters(client: Client, unsafe: Client) -> None:
    name = "CfgDisplayLanguage.ncLanguage"
    assert client.read_machine_parameter(name) == "ENGLISH"
    with pytest.raises(SafetyLockError):
        client.write_machine_parameter(name, "GERMAN")
    unsafe.write_machine_parameter(name, "GERMAN", temporary=True)
    assert client.read_machine_parameter(name) == "GERMAN"
    unsafe.write_machine_parameter(name, "ENGLISH", temporary=True)
    with pytest.raises(ControlRefused) as err:
        client.read_machine_parameter("No.Such.Parameter")
    assert err.value.code == 40


def test_screen_dump_bmp_and_png(client: Client, tmp_path: Path) -> None:
    bmp = client.screen_dump(tmp_path / "screen.bmp")
    assert bmp[:2] == b"BM"
    assert (tmp_path / "screen.bmp").read_bytes() == bmp
    client.screen_dump(tmp_path / "screen.png")
    png = (tmp_path / "screen.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    from PIL import Image

    with Image.open(io.BytesIO(png)) as a, Image.open(io.BytesIO(bmp)) as b:
        assert a.size == b.size
    # the temporary dump was deleted on the control
    assert not [e for e in client.list_dir("TNC:/") if e.name.startswith("screendump")]


def test_operations_log(client: Client, tmp_path: Path) -> None:
    data = client.operations_log(tmp_path / "op.log", since=datetime(2020, 1, 1))
    assert data.startswith(b"Operation Logbook Version 1.0")
    assert (tmp_path / "op.log").read_bytes() == data


def test_tool_table_read_export_write(client: Client, unsafe: Client, tnc640: TncHandle) -> None:
    table = client.read_table()
    assert table.name.upper() == "TOOL.T"
    rows = table.typed_rows()
    assert rows[1]["T"] == 1
    assert isinstance(rows[1]["L"], float)
    assert table.to_csv().splitlines()[0].startswith("T,NAME,L,R")
    assert '"NAME": "MILL_D10_ROUGH"' in table.to_json()
    pocket = client.read_table("TNC:/table/tool_p.tch")
    assert "P" in pocket.column_names
    with pytest.raises(SafetyLockError):
        client.write_table("TNC:/table/tool.t", table)
    table.rows[1]["L"] = "+66.5"
    unsafe.write_table("TNC:/table/tool.t", table)
    again = client.read_table()
    assert again.typed_rows()[1]["L"] == 66.5
    assert tnc640.call(lambda c: c.tool_geometry(1)) == (66.5, 5.0)


def test_refusals_carry_code_and_text(client: Client) -> None:
    with pytest.raises(ControlRefused) as err:
        client.change_dir("TNC:/no/such/dir")
    assert err.value.code in (55, 47)
    assert str(err.value).startswith("change directory to TNC:/no/such/dir")


def test_itnc_specifics(old: Client, itnc530: TncHandle) -> None:
    assert old.family is Family.ITNC530
    names = {e.name: e for e in old.list_dir("TNC:/")}
    assert any(e.is_dir for e in names.values())  # old attribute scheme decoded
    assert any(not e.is_dir for e in names.values())
    itnc530.call(lambda c: c.machine.raise_error("010 Machine guard is open !"))
    errors = old.nc_errors()
    assert errors[-1].text == "010 Machine guard is open !"
    itnc530.call(lambda c: c.machine.clear_errors())
    assert old.nc_errors() == []
    tool = old.current_tool()
    assert tool.axis == 2
    # data paths agree with PLC memory
    itnc530.call(lambda c: c.plc.set_word(2000, 1234))
    assert old.read_data_path("/PLC/memory/W/2000") == 1234
    assert old.read_plc("W2000") == [1234]
    channels = old.scope_channels()
    assert channels
    ch = channels[0]
    rec = old.scope_record([ScopeSignal(ch.number, 0)], interval=max(ch.interval, 600), blocks=3)
    assert len(rec.values) == 1
    assert len(rec.values[0]) == 96
    # connection still in step after the stopped stream
    with pinned_state(itnc530, ProgramState.ERROR_CLEARED, ExecutionMode.MANUAL):
        assert old.program_state() is ProgramState.ERROR_CLEARED


def test_scope_refused_on_new_family(client: Client) -> None:
    with pytest.raises(ControlRefused):
        client.scope_record([ScopeSignal(1, 0)], interval=21000)


def test_timeout_and_lost_connection(tmp_path: Path) -> None:
    with start_tnc("tnc640", latency=0.15) as tnc:
        c = Client("127.0.0.1", tnc.port, timeout=5, max_buffer=256, secure_send=False)
        c.connect()
        c.timeout = 0.05
        with pytest.raises(TransportTimeout):
            c.program_state()
        with pytest.raises(TransportError, match="reconnect"):
            c.program_state()
        c.close()
    with start_tnc("tnc640") as tnc:
        c = Client("127.0.0.1", tnc.port, timeout=5)
        c.connect()
        tnc.stop()
        with pytest.raises(TransportError):
            c.list_dir("TNC:/")
        c.close()


def test_not_connected() -> None:
    from opendnc.errors import LocalProtocolError

    with pytest.raises(LocalProtocolError):
        Client("127.0.0.1", 1).list_dir()
    with pytest.raises(TransportError):
        Client("127.0.0.1", 1, timeout=2).connect()


def test_walk_matches_disk(client: Client, tnc640: TncHandle) -> None:
    client.make_dir("TNC:/walk/a/b")
    client.write_file("TNC:/walk/a/b/deep.h", b"x\r\n", binary=True)
    found = {e.path.lower() for e in client.walk("TNC:/")}
    base = Path(tnc640.root, "TNC")
    on_disk = set()
    for folder, dirs, files in os.walk(base):
        dirs[:] = [d for d in dirs if not d.startswith(".")]
        for name in dirs + [f for f in files if not f.startswith(".")]:
            rel = Path(folder, name).relative_to(base)
            on_disk.add(("TNC:\\" + "\\".join(rel.parts)).lower())
    assert found == on_disk
    assert "tnc:\\walk\\a\\b\\deep.h" in found
    client.delete_file("TNC:/walk/a/b/deep.h")
    for d in ("TNC:/walk/a/b", "TNC:/walk/a", "TNC:/walk"):
        client.remove_dir(d)


def test_cancelled_transfers_keep_the_session_usable(
    client: Client, tnc640: TncHandle, tmp_path: Path
) -> None:
    data = os.urandom(20_000)
    client.write_file("TNC:/nc_prog/cancel.bin", data)

    class Cancelled(Exception):
        pass

    def stop_after_first(done: int, total: int | None) -> None:
        if done > 0:
            raise Cancelled

    with pytest.raises(Cancelled):
        client.download("TNC:/nc_prog/cancel.bin", tmp_path / "c.bin", progress=stop_after_first)
    assert list(tmp_path.iterdir()) == []  # temp file removed, target never created
    with pytest.raises(Cancelled):
        client.write_file("TNC:/nc_prog/cancel2.bin", data, progress=stop_after_first)
    assert client.file_info("TNC:/nc_prog/cancel2.bin") is None  # partial upload dropped
    assert client.read_file("TNC:/nc_prog/cancel.bin") == data  # still in step
    client.delete_file("TNC:/nc_prog/cancel.bin")


def test_local_errors_keep_the_link(client: Client, tnc640: TncHandle) -> None:
    from opendnc.errors import LocalProtocolError

    with pytest.raises(LocalProtocolError, match="exceeds the buffer"):
        client.file_info("TNC:/" + "x" * 5000 + ".h")
    with pytest.raises(InputError, match="Latin-1"):
        client.file_info("TNC:/€.h")
    with pinned_state(tnc640, ProgramState.STOPPED, ExecutionMode.AUTOMATIC):
        assert client.program_state() is ProgramState.STOPPED


def test_system_info(client: Client, tnc640: TncHandle) -> None:
    info = client.system_info()
    assert info.axes_sampling_rate is None  # no remote scope on a TNC 640: R_CI 3 refused
    assert info.dnc_allowed is tnc640.call(lambda c: c.dnc_option)
    assert info.turbo_mode is False
    assert client.read_parameters() == client.parameters
    again = client.read_versions()
    assert (again.model, again.nc_software, again.plc) == (
        client.versions.model,
        client.versions.nc_software,
        client.versions.plc,
    )


def test_system_info_itnc_reports_the_scope_sampling_period(old: Client) -> None:
    # the iTNC 530 answers R_CI 3 with 3000 µs, as captured before a scope recording
    assert old.system_info().axes_sampling_rate == 3000
