"""pyLSV2 (PyPI, an independent LSV2 client) against the virtual TNC, for every profile."""

from __future__ import annotations

import logging
import os
import struct
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from opendnc.sim.tnc import PROFILES, TncHandle, start_tnc
from opendnc.sim.tnc.control import Control
from tests.peers import require_module

pytestmark = pytest.mark.interop
ALL = list(PROFILES)
PW = "807667"


@pytest.fixture(scope="module")
def lsv2() -> Any:
    module = require_module("pyLSV2")
    logging.getLogger("pyLSV2").setLevel(logging.CRITICAL)
    return module


@pytest.fixture(scope="module", params=ALL)
def tnc(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[TncHandle]:
    root = tmp_path_factory.mktemp(f"tnc-{request.param}")
    with start_tnc(request.param, root=root) as handle:
        yield handle


def client(lsv2: Any, tnc: TncHandle, **kw: Any) -> Any:
    c = lsv2.LSV2("127.0.0.1", port=tnc.port, timeout=5, safe_mode=False, **kw)
    c.connect()
    return c


@pytest.fixture
def con(lsv2: Any, tnc: TncHandle) -> Iterator[Any]:
    c = client(lsv2, tnc)
    yield c
    c.disconnect()


def test_connect_versions_and_parameters(con: Any, tnc: TncHandle) -> None:
    p = tnc.profile
    assert con.versions.control == p.model.replace(" ", "")  # pyLSV2 drops blanks
    assert con.versions.nc_sw == p.nc_software.strip() or con.versions.nc_sw == p.nc_software
    assert con.versions.plc == p.plc_software
    assert con.parameters.max_block_length == p.max_block_length
    assert con.parameters.number_of_words == p.plc.words
    assert con.parameters.markers_start_address == p.plc.markers_start
    expected = max(s for s in (256, 512, 1024, 2048, 3072, 4096) if s <= p.max_block_length)
    assert con._llcom.buffer_size == expected
    if p.key == "itnc530":
        assert con.versions.is_itnc()
    elif p.lathe:
        assert con.versions.is_pilot()
    elif p.key == "tnc7":
        assert con.versions.is_tnc7()
    elif p.key != "tnc426":
        assert con.versions.is_tnc()


PASSWORDED = {"FILEPLC", "FILESYS", "FILELOG", "STREAMAXES"}


def test_every_login(lsv2: Any, tnc: TncHandle) -> None:
    for login in lsv2.const.Login:
        c = client(lsv2, tnc)
        try:
            available = login.value in tnc.profile.logins
            if login.value in PASSWORDED:
                assert not c.login(login), login  # refused without the password
                assert c.last_error.e_code in (30, 49)
                assert c.login(login, PW) == available, login
            else:
                assert c.login(login) == available, login
                if not available:
                    assert c.last_error.e_code == 49
            assert c.logout(login)
        finally:
            c.disconnect()


def test_logins(lsv2: Any, con: Any, tnc: TncHandle) -> None:
    L = lsv2.const.Login
    for login in (L.INSPECT, L.FILETRANSFER, L.DIAG, L.PLCDEBUG, L.DNC, L.MONITOR):
        assert con.login(login), login
    assert not con.login(L.FILEPLC)  # needs the PLC password
    assert con.login(L.FILEPLC, PW) == ("FILEPLC" in tnc.profile.logins)
    assert con.login(L.DATA) == tnc.profile.data_paths
    assert con.logout(L.MONITOR)
    assert con.logout(L.FILETRANSFER)
    assert con.directory_info() is not None  # pyLSV2 logs in FILE again on demand
    # MONITOR is exclusive: a second session cannot have it while the first holds it.
    assert con.login(L.MONITOR)
    other = client(lsv2, tnc)
    try:
        assert not other.login(L.MONITOR)
        assert other.last_error.e_code == 49
        con.logout(L.MONITOR)
        assert other.login(L.MONITOR)
    finally:
        other.disconnect()
    # a vanished holder releases MONITOR too
    holder = client(lsv2, tnc)
    assert holder.login(L.MONITOR)
    holder._llcom._tcpsock.close()
    deadline = time.monotonic() + 3
    while not con.login(L.MONITOR) and time.monotonic() < deadline:
        time.sleep(0.02)
    assert con.login(L.MONITOR)
    con.logout(L.MONITOR)


def test_remote_datetime(lsv2: Any, con: Any, tnc: TncHandle) -> None:
    if tnc.profile.date_time:
        stamp = con.get_remote_datetime()
        assert abs(stamp.timestamp() - time.time()) < 5
    else:
        with pytest.raises(lsv2.err.LSV2ProtocolException):
            con.get_remote_datetime()


def is_dir(tnc: TncHandle, entry: Any) -> bool:
    # pyLSV2 reads the old (iTNC) attribute scheme only for controls it recognises as iTNC;
    # a TNC 426 is "unknown" to it, so check the raw bit of the family's scheme.
    if tnc.profile.key == "tnc426":
        return bool(entry.attributes & 0x40)
    return bool(entry.is_directory)


def test_directory_functions(con: Any, tnc: TncHandle) -> None:
    info = con.directory_info()
    assert info.path == "TNC:\\"
    paths = tnc.profile.paths
    names = [e.name for e in con.directory_content()]
    tool_dir, tool_name = paths.tool_table.rsplit("\\", 1)
    assert con.change_directory(tool_dir)
    assert tool_name in [e.name for e in con.directory_content()]
    assert names
    fi = con.file_info(paths.tool_table)
    assert fi is not None
    assert fi.size > 100
    assert not is_dir(tnc, fi)
    di = con.file_info(paths.program_dir + "\\")
    assert di is not None
    assert is_dir(tnc, di)
    assert con.file_info("TNC:\\") is not None
    drives = [d.name for d in con.drive_info()]
    assert "TNC:" in drives
    assert con.change_directory("TNC:")
    files = con.get_file_list("TNC:", pattern=r"[\$A-Za-z0-9_-]*\.(?:[hH]|[iI]|nc|NC)$")
    assert any(paths.mdi_program.lower() == f.lower() for f in files)


def test_mkdir_rmdir_delete_copy_move(lsv2: Any, con: Any, tnc: TncHandle, tmp_path: Path) -> None:
    base = "TNC:\\interop\\a\\b"
    assert con.make_directory(base)
    assert is_dir(tnc, con.file_info(base))
    src = tmp_path / "x.h"
    src.write_bytes(b"0 BEGIN PGM X MM\r\n1 END PGM X MM\r\n")
    assert con.send_file(src, base + "\\x.h", override_file=True, binary_mode=True)
    assert con.copy_remote_file(base + "\\x.h", "TNC:\\interop\\y.h")
    assert con.move_file("TNC:\\interop\\y.h", "TNC:\\interop\\a\\z.h")
    assert con.file_info("TNC:\\interop\\y.h") is None
    assert con.file_info("TNC:\\interop\\a\\z.h").size == src.stat().st_size
    assert not con.delete_empty_directory(base)  # not empty
    assert con.delete_file(base + "\\x.h")
    assert con.delete_file("TNC:\\interop\\a\\z.h")
    assert con.delete_empty_directory(base)
    assert con.file_info(base) is None
    # deleting the current directory: iTNC allows it, the TNC families refuse
    assert con.change_directory("TNC:\\interop\\a")
    assert con.delete_empty_directory("TNC:\\interop\\a") == tnc.profile.delete_cwd_allowed
    assert con.change_directory("TNC:\\")
    con.delete_empty_directory("TNC:\\interop\\a")
    assert con.delete_empty_directory("TNC:\\interop")
    assert not (tnc.root / "TNC" / "interop").exists()


@pytest.mark.parametrize("compat", [False, True], ids=["maxbuf", "buf256"])
def test_transfers_byte_identical(lsv2: Any, tnc: TncHandle, tmp_path: Path, compat: bool) -> None:
    c = client(lsv2, tnc, compatibility_mode=compat)
    try:
        assert c._llcom.buffer_size == (256 if compat else c._llcom.buffer_size)
        binary = os.urandom(9000) + bytes(range(256))
        text = "".join(f"{i} L X+{i} Y-{i} F500\r\n" for i in range(300)).encode()
        for name, data, mode in (("bin.dat", binary, True), ("text.h", text, False)):
            local = tmp_path / name
            local.write_bytes(data)
            remote = f"TNC:\\xfer_{int(compat)}_{name}"
            assert c.send_file(local, remote, override_file=True, binary_mode=mode)
            stored = tnc.root / "TNC" / f"xfer_{int(compat)}_{name}"
            # Without secure file send the control does not answer T_FD, so the client may
            # return before the rename: wait for it briefly.
            deadline = time.monotonic() + 2
            while not stored.exists() and time.monotonic() < deadline:
                time.sleep(0.01)
            assert stored.read_bytes() == data
            back = tmp_path / ("back_" + name)
            assert c.recive_file(remote, back, override_file=True, binary_mode=mode)
            assert back.read_bytes() == data
            assert c.delete_file(remote)
    finally:
        c.disconnect()
    assert not list((tnc.root / ".partial").iterdir())


def test_program_run_seen_by_client(lsv2: Any, con: Any, tnc: TncHandle) -> None:
    K = lsv2.const.KeyCode
    machine = tnc.call(lambda c: (int(c.machine.program_state), int(c.machine.exec_mode)))
    assert (con.program_status(), con.execution_state()) == machine
    ext = ".nc" if tnc.profile.lathe else ".H"
    prog = (
        tnc.profile.paths.mdi_program
        if tnc.profile.lathe
        else (tnc.profile.paths.program_dir.rstrip("\\") + "\\POCKET" + ext)
    )

    def start(control: Control) -> None:
        control.select_program(prog)
        control.machine.exec_mode = control.machine.exec_mode.AUTOMATIC
        control.machine.start()

    tnc.call(start)
    assert con.program_status() == 0
    stack = con.program_stack()
    assert stack.main.lower() == prog.lower()
    before = con.axes_location()
    tnc.call(lambda c: setattr(c.machine, "block_time", 0.01))
    deadline = time.monotonic() + 5
    while con.program_status() != 2 and time.monotonic() < deadline:
        time.sleep(0.02)
    after = con.axes_location()
    if 22 in tnc.profile.ri_selectors:
        assert before is not None
        assert after is not None
        assert before != after
    else:
        assert before is None  # the family has no axis read-out over LSV2
    assert con.program_status() == 2  # finished
    over = con.override_state()
    assert over.feed == 100.0
    tnc.call(lambda c: c.machine.set_overrides(5000, 12000, 2500))
    over = con.override_state()
    assert (over.feed, over.spindle, over.rapid) == (50.0, 120.0, 25.0)
    del K


def test_plc_reads_every_type(lsv2: Any, con: Any, tnc: TncHandle) -> None:
    M = lsv2.const.MemoryType
    lay = tnc.profile.plc

    def poke(control: Control) -> None:
        img = control.plc.image
        img[lay.markers_start + 5] = 1
        img[lay.inputs_start + 6] = 1
        img[lay.outputs_start + 7] = 1
        img[lay.counters_start + 3] = 1
        img[lay.timers_start + 2] = 1
        img[lay.words_start + 100 : lay.words_start + 104] = struct.pack("<i", -123456)
        img[lay.input_words_start + 8 : lay.input_words_start + 10] = struct.pack("<H", 4242)
        img[lay.output_words_start + 16 : lay.output_words_start + 20] = struct.pack("<i", 77)
        control.plc.set_string(5, "HELLO")

    tnc.call(poke)
    assert con.read_plc_memory(5, M.MARKER, 1) == [True]
    assert con.read_plc_memory(6, M.INPUT, 1) == [True]
    assert con.read_plc_memory(7, M.OUTPUT, 1) == [True]
    assert con.read_plc_memory(3, M.COUNTER, 1) == [True]
    assert con.read_plc_memory(2, M.TIMER, 1) == [True]
    assert con.read_plc_memory(25, M.DWORD, 1) == [-123456]
    assert con.read_plc_memory(50, M.WORD, 2) == list(
        struct.unpack("<hh", struct.pack("<i", -123456))
    )
    assert con.read_plc_memory(100, M.BYTE, 4) == list(
        struct.unpack("<4b", struct.pack("<i", -123456))
    )
    assert con.read_plc_memory(4, M.INPUT_WORD, 1) == [4242]
    assert con.read_plc_memory(4, M.OUTPUT_DWORD, 1) == [77]
    assert con.read_plc_memory(5, M.STRING, 1) == ["HELLO"]
    assert con.read_plc_memory(420, M.DWORD, 1)[0] is not None
    assert con.read_plc_memory(0, M.MARKER, 254)[5] is True
    assert con.read_plc_address("D100") == -123456
    assert con.read_plc_address("M5") is True
    assert con.read_plc_address("S5") == "HELLO"


def test_data_paths(con: Any, tnc: TncHandle) -> None:
    if not tnc.profile.data_paths:
        assert con.read_data_path("/PLC/memory/W/0") is None
        return
    from pyLSV2.const import MemoryType as M

    tnc.call(lambda c: c.plc.write(c.profile.plc.words_start + 40, struct.pack("<i", 0x01020304)))
    assert con.read_data_path("/PLC/memory/D/40") == con.read_plc_memory(10, M.DWORD)[0]
    assert con.read_data_path("/PLC/memory/W/40") == con.read_plc_memory(20, M.WORD)[0]
    assert con.read_data_path("/PLC/memory/B/40") == con.read_plc_memory(40, M.BYTE)[0]
    assert con.read_data_path("/PLC/memory/K/7") == 7
    assert con.read_data_path("/TABLE/TOOL/T/1/L") == pytest.approx(65.0)
    assert con.read_data_path("/TABLE/TOOL/T/1/DOC") == "end mill 10"
    assert con.read_data_path("/PLC/memory/X/1") is None


def test_tool_and_errors(con: Any, tnc: TncHandle) -> None:
    if 51 in tnc.profile.ri_selectors:
        previous = tnc.call(lambda c: c.machine.tool)
        tnc.call(lambda c: setattr(c.machine, "tool", 5))
        try:
            tool = con.spindle_tool_status()
        finally:
            tnc.call(lambda c: setattr(c.machine, "tool", previous))
        assert tool is not None
        assert tool.number == 5
        assert tool.length == pytest.approx(40.0)  # BALL_D4 in the fresh tool table
        errors = con.get_error_messages()
        assert errors
        assert "Relay" in errors[0].e_text
    else:
        assert con.spindle_tool_status() is None


def test_keys_change_mode(lsv2: Any, con: Any, tnc: TncHandle) -> None:
    style = tnc.profile.keys.value
    if style == "none":
        assert not con.set_keyboard_access(False)
        return
    K = lsv2.const.KeyCode if style == "new" else lsv2.const.OldKeyCode
    assert con.set_keyboard_access(False)
    assert con.send_key_code(K.MODE_MANUAL)
    assert con.execution_state() == 0
    assert con.send_key_code(K.MODE_AUTOMATIC)
    assert con.execution_state() == 4
    assert con.send_key_code(K.MODE_PGM_EDIT)
    assert con.execution_state() == 4
    assert con.set_keyboard_access(True)


def test_screen_dump_is_bitmap(con: Any, tnc: TncHandle, tmp_path: Path) -> None:
    target = tmp_path / "screen.bmp"
    assert con.grab_screen_dump(target)
    data = target.read_bytes()
    assert data[:2] == b"BM"
    assert struct.unpack_from("<I", data, 2)[0] == len(data)
    width, height = struct.unpack_from("<ii", data, 18)
    assert (width, height) == (640, 480)
    assert not [p for p in (tnc.root / "TNC").iterdir() if p.name.startswith("screendump")]


def test_machine_parameters(con: Any, tnc: TncHandle) -> None:
    name = "7230.0" if tnc.profile.numeric_machine_parameters else "CfgDisplayLanguage.ncLanguage"
    assert con.get_machine_parameter(name)
    assert con.set_machine_parameter(name, "1", safe_to_disk=True)
    assert con.get_machine_parameter(name) == "1"
    assert name in (tnc.root / ".state" / "machine_parameters.json").read_text()
    assert not con.get_machine_parameter("no.such.parameter")


def test_scope_itnc_only(lsv2: Any, con: Any, tnc: TncHandle) -> None:
    if not tnc.profile.scope:
        assert con.read_scope_signals() == []
        return
    signals = con.read_scope_signals()
    assert len(signals) > 5
    chosen = [s for s in signals if s.channel == 0][:3]
    readings = list(con.real_time_readings(chosen, 1, 3000))
    assert readings
    first = readings[0].get_data()
    assert len(first) == 3
    assert len(first[0].data) == 32
