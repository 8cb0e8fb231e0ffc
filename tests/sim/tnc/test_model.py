"""Unit tests of the virtual TNC model: profiles, path sandbox, PLC views, machine, screen."""

from __future__ import annotations

import io
import struct
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from opendnc.errors import ControlRefused, InputError
from opendnc.lsv2.constants import DataType
from opendnc.lsv2.payloads import SystemParameters
from opendnc.sim.tnc.control import Control
from opendnc.sim.tnc.filesystem import WirePath, parse_path
from opendnc.sim.tnc.machine import ExecMode, Machine, PgmState, parse_program
from opendnc.sim.tnc.plc import PlcMemory, resolve_data_path, table_rows
from opendnc.sim.tnc.population import klartext_demo
from opendnc.sim.tnc.profiles import PROFILES, get_profile
from opendnc.sim.tnc.screen import render_status
from tests.peers import require_module

GOLDEN_SPR = bytes.fromhex(
    "0001dcd000009c4000027910000003e800027cf8000003e8000280e000000090"
    "00028170000003e8000000400001d4c00002855800000190f000000000000000"
    "0001d500000003e80001d8e8000003e800000000000000000000000000000000"
    "019f0ff80000000000000000001f16fd0080002060389a6e"
)
DRIVES = ("TNC:", "PLC:", "SYS:", "LOG:")
ROOT = WirePath("TNC:", ())


class FakeClock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


# -- profiles -------------------------------------------------------------------------------
def test_tnc320_system_parameters_are_the_captured_bytes() -> None:
    assert PROFILES["tnc320"].system_parameters() == GOLDEN_SPR


@pytest.mark.parametrize("key", list(PROFILES))
def test_profiles_are_self_consistent(key: str) -> None:
    p = PROFILES[key]
    raw = p.system_parameters()
    assert len(raw) == p.sys_par_length
    params = SystemParameters.from_bytes(raw)  # the shared codec reads it back
    assert params.max_block_length == p.max_block_length
    assert params.words >= 1700
    assert p.plc.image_size > p.plc.strings_start
    parts = p.version_parts()
    assert len(parts) in (4, 5)
    assert parts[-1]  # pyLSV2 needs a non-empty last part
    # the release type (R_VR 6) is refused by the iTNC and the TNC 426, answered elsewhere
    if p.key in ("itnc530", "tnc426"):
        assert p.version_selector(6) is None
    else:
        assert p.version_selector(6) == "Release"
    # Every size up to the family's limit is accepted (the Eclipse plugin asks for 4096 on
    # any TNC 6xx regardless of max_block_length).
    assert max(p.buffer_sizes().values()) == p.max_buffer


def test_unknown_profile_names_choices() -> None:
    with pytest.raises(InputError, match="tnc640"):
        get_profile("tnc999")


# -- path sandbox ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("TNC:", "TNC:\\"),
        ("tnc:\\\\nc_prog//demo\\", "TNC:\\nc_prog\\demo"),
        ("nc_prog/./x.h", "TNC:\\nc_prog\\x.h"),
        ("\\table\\tool.t", "TNC:\\table\\tool.t"),
        ("a\\..\\b.h", "TNC:\\b.h"),
        ("PLC:\\x", "PLC:\\x"),
    ],
)
def test_parse_path_normalises(text: str, expected: str) -> None:
    assert str(parse_path(text, ROOT, DRIVES)) == expected


@pytest.mark.parametrize(
    "text",
    ["..", "TNC:\\..", "C:\\x", "TNC:\\a:b", "x\0y", "a\\b\x01", "nul.", "TNC:\\x \\y", "X" * 300],
)
def test_parse_path_rejects(text: str) -> None:
    with pytest.raises(ControlRefused) as info:
        parse_path(text, ROOT, DRIVES)
    assert info.value.code == 31


@settings(max_examples=300, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    st.lists(
        st.sampled_from(["..", ".", "", "a", "B", "/", "\\", ":", "C:", "TNC:", "~", "\x00", "é"])
        | st.text(max_size=6),
        max_size=10,
    )
)
def test_hostile_paths_stay_inside_the_root(tmp_path: Path, parts: list[str]) -> None:
    control = _control_cache(tmp_path)
    text = "".join(parts)
    try:
        wp = control.fs.parse(text, WirePath("TNC:", ("nc_prog",)))
        host = control.fs.host_path(wp)
    except ControlRefused as exc:
        code = exc.code
    else:
        code = 0
    if code:
        assert code == 31
        return
    assert wp.drive in DRIVES
    assert ".." not in wp.parts
    assert host.resolve().is_relative_to(tmp_path.resolve())


_CONTROLS: dict[Path, Control] = {}


def _control_cache(root: Path) -> Control:
    if root not in _CONTROLS:
        _CONTROLS[root] = Control(PROFILES["tnc640"], root)
    return _CONTROLS[root]


def test_symlink_out_of_the_root_is_refused(tmp_path: Path) -> None:
    control = Control(PROFILES["tnc640"], tmp_path / "root")
    outside = tmp_path / "outside"
    outside.mkdir()
    (tmp_path / "root" / "TNC" / "link").symlink_to(outside)
    with pytest.raises(ControlRefused):
        control.fs.host_path(control.fs.parse("TNC:\\link\\x.h", ROOT))


def test_case_insensitive_lookup_keeps_stored_spelling(tmp_path: Path) -> None:
    control = Control(PROFILES["tnc640"], tmp_path)
    wp = control.fs.parse("tnc:\\NC_PROG\\pocket.h", ROOT)
    assert str(control.fs.canonical(wp)) == "TNC:\\nc_prog\\POCKET.H"
    entry = control.fs.entry(wp)
    assert entry.size > 100


def test_population_and_persistence(tmp_path: Path) -> None:
    for key in PROFILES:
        root = tmp_path / key
        control = Control(PROFILES[key], root)
        p = control.profile.paths
        for path in (p.mdi_program, p.tool_table, p.pocket_table):
            assert control.fs.read_bytes(control.fs.parse(path, ROOT))
        rows = control.tool_rows()
        assert rows[1]["NAME"] == "MILL_D10_ROUGH"
        control.fs.write_atomic(control.fs.parse("TNC:\\mine.h", ROOT), b"kept")
        control.mp.write(next(iter(control.mp._permanent)), "42", temporary=False)
        again = Control(PROFILES[key], root)
        assert again.fs.read_bytes(again.fs.parse("TNC:\\mine.h", ROOT)) == b"kept"
        assert again.mp.read(next(iter(again.mp._permanent))) == "42"


def test_table_parser_reads_fixed_width_columns() -> None:
    text = "BEGIN TOOL.T MM\nT     NAME      L\n1     MILL 6    +50.5\n[END]\n"
    assert table_rows(text) == [{"T": "1", "NAME": "MILL 6", "L": "+50.5"}]
    assert table_rows("BEGIN TOOL.T MM\nT     NAME\n1     MILL 6\n") == []  # no [END]: cut off


# -- PLC ------------------------------------------------------------------------------------
def test_plc_views_agree() -> None:
    p = PROFILES["itnc530"]
    plc = PlcMemory(p.plc)
    plc.write(p.plc.words_start + 8, struct.pack("<i", -2))
    assert resolve_data_path("\\PLC\\memory\\D\\8", plc, {}).value == -2
    assert resolve_data_path("\\PLC\\memory\\W\\8", plc, {}).value_type == DataType.INT16
    assert resolve_data_path("\\PLC\\memory\\W\\10", plc, {}).value == -1
    assert resolve_data_path("\\PLC\\memory\\B\\8", plc, {}).value == -2
    assert plc.read(p.plc.words_start + 8, 4) == struct.pack("<i", -2)
    plc.set_bit("M", 9, True)
    assert resolve_data_path("/PLC/memory/M/9", plc, {}).value is True
    assert plc.read(p.plc.markers_start + 9, 1) == b"\x01"
    tools = {3: {"T": "3", "L": "+90.0000", "DOC": "drill"}}
    assert resolve_data_path("\\TABLE\\TOOL\\T\\3\\L", plc, tools).value == 90.0
    assert resolve_data_path("\\TABLE\\TOOL\\T\\3\\DOC", plc, tools).value == "drill"
    sym = "/PLC/program/symbol/global/+STG_WZM[0].WZ.L"
    assert resolve_data_path(sym, plc, {}) == resolve_data_path(sym, plc, {})
    assert (
        resolve_data_path("/PLC/program/symbol/global/MG_BA_AUTO", plc, {}).value_type
        == DataType.BOOL
    )
    for bad in ("\\PLC\\memory\\W\\99999999", "\\PLC\\memory\\Q\\1", "\\TABLE\\TOOL\\T\\9\\L", "x"):
        with pytest.raises(ControlRefused) as info:
            resolve_data_path(bad, plc, tools)
        assert info.value.code == 63
    with pytest.raises(ControlRefused):
        plc.read(len(plc.image) - 1, 2)


# -- machine --------------------------------------------------------------------------------
def test_program_runs_on_the_injected_clock() -> None:
    p = PROFILES["tnc640"]
    clock = FakeClock()
    m = Machine(p, PlcMemory(p.plc), clock)
    m.select("TNC:\\nc_prog\\POCKET.H", klartext_demo("POCKET"))
    with pytest.raises(Exception, match="program-run mode"):
        m.start()
    m.press_key(0x01C3)
    assert m.exec_mode is ExecMode.AUTOMATIC
    m.start()
    assert m.program_state is PgmState.STARTED
    z0 = m.positions["Z"]
    clock.now += 1.1
    m.advance()
    assert m.positions["Z"] != z0
    assert m.current_line > 0
    m.stop()
    frozen = dict(m.positions)
    clock.now += 5
    m.advance()
    assert m.program_state is PgmState.STOPPED
    assert m.positions == frozen
    m.start()
    clock.now += 100
    m.advance()
    assert m.program_state is PgmState.FINISHED
    assert m.part_counter == 1
    assert m.positions["Z"] == 50.0
    assert m.tool == 3
    assert m.uptimes()[32] > 0
    assert m.plc.read(p.plc.words_start + 16, 4) == struct.pack("<i", 1)  # part counter word


def test_keys_and_errors() -> None:
    p = PROFILES["tnc426"]
    m = Machine(p, PlcMemory(p.plc), FakeClock())
    m.press_key(0x004B)  # old-style full sequence
    assert m.exec_mode is ExecMode.AUTOMATIC
    with pytest.raises(Exception, match="unknown key"):
        m.press_key(0x01C0)  # new-style code on an old control
    m.raise_error("Test error")
    assert m.errors[-1].text == "Test error"
    m.press_key(0x0069)  # CE
    assert not m.errors
    tnc7 = PROFILES["tnc7"]
    with pytest.raises(Exception, match="not supported"):
        Machine(tnc7, PlcMemory(tnc7.plc), FakeClock()).press_key(0x01C0)


def test_parse_program_reads_iso_and_klartext() -> None:
    blocks = parse_program("N10 G00 X+20 Y-5 T7 M03 *\n5 L Z+50 R0 FMAX M30\n")
    assert blocks[0].targets == {"X": 20.0, "Y": -5.0}
    assert blocks[0].tool == 7
    assert blocks[0].spindle_on is True
    assert blocks[1].targets == {"Z": 50.0}
    assert blocks[1].spindle_on is False


# -- screen ---------------------------------------------------------------------------------
def test_screen_dump_is_a_valid_bmp(tmp_path: Path) -> None:
    control = Control(PROFILES["tnc640"], tmp_path)
    data = render_status(control.machine)
    assert data[:2] == b"BM"
    assert struct.unpack_from("<I", data, 2)[0] == len(data)
    image_mod = require_module("PIL.Image")
    with image_mod.open(io.BytesIO(data)) as img:
        assert img.size == (640, 480)
        colours = img.getcolors(256)
        assert colours is not None
        assert len(colours) >= 4  # text, background, header, bars: not a blank picture


def test_machine_state_survives_a_restart(tmp_path: Path) -> None:
    control = Control(PROFILES["itnc530"], tmp_path)
    control.machine.part_counter = 41
    control.machine.positions["X"] = 12.5
    control.plc.set_bit("M", 100, True)
    control.save_state()
    again = Control(PROFILES["itnc530"], tmp_path)
    assert again.machine.part_counter == 41
    assert again.machine.positions["X"] == 12.5
    assert again.plc.read(again.profile.plc.markers_start + 100, 1) == b"\x01"


def test_program_call_shows_on_the_program_stack() -> None:
    p = PROFILES["tnc640"]
    clock = FakeClock()
    m = Machine(p, PlcMemory(p.plc), clock)
    m.select("TNC:\\nc_prog\\POCKET.H", klartext_demo("POCKET", call="demo\\FRAME.H"))
    m.press_key(0x01C3)
    m.start()
    seen = set()
    for _ in range(200):
        clock.now += m.block_time / 2
        m.advance()
        seen.add(m.current_program)
    assert "TNC:\\nc_prog\\demo\\FRAME.H" in seen
    assert m.current_program == m.main_program
    assert m.program_state is PgmState.FINISHED


def test_root_reused_by_another_family_gets_its_files(tmp_path: Path) -> None:
    Control(PROFILES["tnc640"], tmp_path)
    (tmp_path / "TNC" / "nc_prog" / "POCKET.H").unlink()
    control = Control(PROFILES["itnc530"], tmp_path)
    assert control.fs.read_bytes(control.fs.parse("TNC:\\TOOL.T", ROOT))
    Control(PROFILES["tnc640"], tmp_path)
    assert not (tmp_path / "TNC" / "nc_prog" / "POCKET.H").exists()  # deletions stick


def test_single_block_mode_stops_after_each_block() -> None:
    p = PROFILES["tnc640"]
    clock = FakeClock()
    m = Machine(p, PlcMemory(p.plc), clock)
    m.select("TNC:\\nc_prog\\POCKET.H", klartext_demo("POCKET"))
    m.press_key(0x01C2)  # single block
    lines = []
    for _ in range(3):
        m.start()
        clock.now += 10 * m.block_time
        m.advance()
        assert m.program_state is PgmState.STOPPED
        lines.append(m.current_line)
    assert lines == sorted(lines)
    assert len(set(lines)) == 3


def test_unknown_tool_stops_the_program_with_an_nc_error() -> None:
    p = PROFILES["tnc640"]
    clock = FakeClock()
    m = Machine(p, PlcMemory(p.plc), clock, tool_known=lambda n: n != 3)
    m.clear_errors()
    m.select("TNC:\\nc_prog\\POCKET.H", klartext_demo("POCKET"))
    m.press_key(0x01C3)
    m.start()
    clock.now += 100
    m.advance()
    assert m.program_state is PgmState.ERROR
    assert m.errors[-1].text == "Tool 3 not defined"
    assert m.current_line == 12  # the TOOL CALL 3 block
    assert m.part_counter == 0
    m.press_key(0x01AE)  # CE
    assert m.program_state is PgmState.ERROR_CLEARED
