"""Codec: golden vectors from captures and docs/lsv2.md, round trips, malformed payloads."""

from __future__ import annotations

import pytest

from opendnc.errors import InputError, RemoteProtocolError
from opendnc.lsv2.constants import (
    AttributeScheme,
    ExecutionMode,
    Family,
    ProgramState,
    RunInfo,
    detect_family,
    error_text,
)
from opendnc.lsv2.framing import Frame
from opendnc.lsv2.messages import (
    REGISTRY,
    CommandDone,
    DirReply,
    Login,
    Message,
    ParametersReply,
    Refused,
    RunInfoReply,
    SendFile,
    SystemInfoReply,
    VersionReply,
    decode,
    encode,
)
from opendnc.lsv2.payloads import DirectoryInfo, FileEntry, Versions
from opendnc.lsv2.runinfo import (
    AxesConfig,
    AxesNames,
    AxesPositions,
    AxisConfig,
    AxisName,
    AxisPosition,
    NcError,
    Overrides,
    SelectedProgram,
    ToolInfo,
    decode_run_info,
    encode_run_info,
)
from tests.unit.lsv2.samples import PARAMS, S_PR_GOLDEN, SAMPLES, TNC320_S_VR_PAYLOAD


@pytest.mark.parametrize("message", SAMPLES, ids=lambda m: m.mnemonic)
def test_round_trip(message: Message) -> None:
    frame = encode(message)
    assert decode(Frame(frame.mnemonic, frame.payload)) == message


def test_samples_cover_every_registered_telegram() -> None:
    assert {m.mnemonic for m in SAMPLES} == set(REGISTRY)


def test_login_golden() -> None:
    assert encode(Login("INSPECT")).payload == b"INSPECT\0"
    assert encode(Login("FILEPLC", "807667")).payload == b"FILEPLC\x00807667\x00"
    assert len(encode(Login("FILEPLC", "807667")).payload) == 15


def test_system_parameters_golden_both_ways() -> None:
    msg = decode(Frame("S_PR", S_PR_GOLDEN))
    assert isinstance(msg, ParametersReply)
    p = msg.params
    assert (p.markers_start, p.markers, p.inputs_start, p.inputs) == (122064, 40000, 162064, 1000)
    assert (p.words_start, p.words, p.strings_start, p.strings) == (64, 120000, 165208, 400)
    assert (p.string_length, p.input_words_start, p.output_words_start) == (240, 120064, 121064)
    assert (p.lsv2_version, p.lsv2_flags, p.max_block_length) == (1, 0x9F, 4088)
    assert (p.lsv2_flags_ex, p.max_trace_lines, p.scope_channels) == (0x001F16FD, 128, 32)
    assert p.password_key == 0x60389A6E
    assert p.extra is None
    assert encode(msg).payload == S_PR_GOLDEN
    long_form = S_PR_GOLDEN + b"\x00\x00\x00\x07"
    assert decode(Frame("S_PR", long_form)) == ParametersReply(
        PARAMS.__class__.from_bytes(long_form)
    )
    assert encode(decode(Frame("S_PR", long_form))).payload == long_form


def test_system_parameters_wrong_length() -> None:
    with pytest.raises(RemoteProtocolError, match="120 or 124"):
        decode(Frame("S_PR", S_PR_GOLDEN[:-1]))


def test_tnc320_versions_from_seed() -> None:
    msg = decode(Frame("S_VR", TNC320_S_VR_PAYLOAD))
    assert isinstance(msg, VersionReply)
    v = Versions.from_parts(msg.parts)
    assert v == Versions(
        "TNC320", "771855 18 SP1", "Basic V18-00", "0000000100000100", splc="No version given"
    )
    assert encode(VersionReply(v.to_parts())).payload == TNC320_S_VR_PAYLOAD
    assert detect_family(v.model) is Family.TNC_NEW


def test_versions_need_four_or_five_parts() -> None:
    with pytest.raises(RemoteProtocolError):
        Versions.from_parts(("a", "b", "c"))


@pytest.mark.parametrize(
    ("model", "family"),
    [
        ("iTNC530", Family.ITNC530),
        ("iTNC530 Programmierplatz", Family.ITNC530),
        ("TNC640", Family.TNC_NEW),
        ("TNC 620", Family.TNC_NEW),
        ("TNC128", Family.TNC_NEW),
        ("TNC7", Family.TNC7),
        ("MANUALplus 620", Family.LATHE_NEW),
        ("CNCPILOT640", Family.LATHE_NEW),
        ("MillPlusIT V600", Family.MILLPLUS),
        ("TNC 426/430M", Family.TNC4XX),
        ("TNC 430", Family.TNC4XX),
        ("SomethingElse", Family.UNKNOWN),
    ],
)
def test_family_detection(model: str, family: Family) -> None:
    assert detect_family(model) is family


def test_attribute_schemes() -> None:
    d_new = FileEntry("x", attributes=0x20)
    d_old = FileEntry("x", attributes=0x40)
    assert d_new.is_directory(AttributeScheme.NEW)
    assert not d_new.is_directory(AttributeScheme.OLD)
    assert d_new.is_write_protected(AttributeScheme.OLD)
    assert d_old.is_directory(AttributeScheme.OLD)
    assert d_old.is_write_protected(AttributeScheme.NEW)
    assert Family.ITNC530.attribute_scheme is AttributeScheme.OLD
    assert Family.TNC_NEW.attribute_scheme is AttributeScheme.NEW


def test_axis_example_golden() -> None:
    # docs/lsv2.md#run-time-information axis example (wire)
    payload = (
        b"\x00\x050.0000\x000.0000\x00500.0000\x000.0000\x000.0000\x00X\x00Y\x00Z\x00B\x00C\x00"
    )
    value = RunInfoReply(payload).value(RunInfo.AXES_POSITION)
    assert isinstance(value, AxesPositions)
    assert value.as_dict() == {"X": 0.0, "Y": 0.0, "Z": 500.0, "B": 0.0, "C": 0.0}
    assert encode_run_info(RunInfo.AXES_POSITION, value) == payload


def test_nc_error_example_golden() -> None:
    # docs/lsv2.md#nc-errors example (wire): class 3, group 3, number -2130706422
    text = "010 Machine guard is open !"
    payload = b"\x00\x03\x00\x03" + (-2130706422).to_bytes(4, "big", signed=True)
    payload += text.encode() + b"\0"
    value = decode_run_info(RunInfo.FIRST_ERROR, payload)
    assert value == NcError(3, 3, -2130706422, text)
    assert encode_run_info(RunInfo.NEXT_ERROR, value) == payload


@pytest.mark.parametrize(
    ("selector", "value"),
    [
        (RunInfo.AXES_CONFIG, AxesConfig((AxisConfig(0, 1, "X"), AxisConfig(1, 1, "Y")))),
        (RunInfo.AXES_NAMES, AxesNames((AxisName(0, "X1", "X"),))),
        (RunInfo.AXES_POSITION, AxesPositions((AxisPosition("X", "-1.5"),))),
        (RunInfo.EXEC_STATE, ExecutionMode.AUTOMATIC),
        (RunInfo.SELECTED_PGM, SelectedProgram("TNC:\\a.h", "TNC:\\b.h", 12)),
        (RunInfo.OVERRIDE, Overrides(10000, 5000, 100)),
        (RunInfo.PGM_STATE, ProgramState.IDLE),
        (RunInfo.NC_UPTIME, 3600),
        (RunInfo.SPINDLE2_RUNTIME, 0),
        (RunInfo.CURRENT_TOOL, ToolInfo(5, 0, 2)),
        (RunInfo.CURRENT_TOOL, ToolInfo(5, 1, 2, 100.5, 6.0)),
    ],
)
def test_run_info_round_trip(selector: int, value: object) -> None:
    raw = encode_run_info(selector, value)  # type: ignore[arg-type]
    assert decode_run_info(selector, raw) == value


def test_run_info_errors() -> None:
    with pytest.raises(RemoteProtocolError, match="execution mode 9"):
        decode_run_info(RunInfo.EXEC_STATE, b"\x00\x09")
    with pytest.raises(RemoteProtocolError, match="not a number"):
        decode_run_info(RunInfo.AXES_POSITION, b"\x00\x01abc\x00X\x00")
    with pytest.raises(RemoteProtocolError, match="selector 99"):
        decode_run_info(99, b"")
    with pytest.raises(InputError):
        encode_run_info(RunInfo.OVERRIDE, 5)


def test_error_payloads() -> None:
    assert encode(Refused(32)).payload == b"\x01\x20"
    assert decode(Frame("T_ER", b"")) == Refused(None)
    assert Refused(32).text == "file not found"
    assert error_text(77) == "unknown error 77"
    with pytest.raises(RemoteProtocolError, match="T_ER"):
        decode(Frame("T_ER", b"\x01\x02\x03"))


def test_operations_log_telegrams() -> None:
    # docs/lsv2.md#operations-log capture: C_CC 00 1B + "operation.log;12.09.2020;00:00:00;" + 00 =
    # 37 bytes
    from opendnc.lsv2.messages import SystemCommand

    payload = encode(SystemCommand(27, "operation.log;12.09.2020;00:00:00;")).payload
    assert len(payload) == 37
    assert payload[:2] == b"\x00\x1b"
    assert decode(Frame("M_CC", b"\x00\x1b\x00\x64")) == CommandDone(27, 100)


def test_transfer_mode_byte_optional() -> None:
    assert decode(Frame("C_FL", b"TNC:\\a.h\x00\x01")) == SendFile("TNC:\\a.h", 1)
    assert decode(Frame("C_FL", b"TNC:\\a.h\x00")) == SendFile("TNC:\\a.h", None)
    assert decode(Frame("C_FL", b"TNC:\\a.h")) == SendFile("TNC:\\a.h", None)


def test_read_dir_mode_from_last_byte() -> None:
    from opendnc.lsv2.messages import ReadDir

    assert decode(Frame("R_DR", b"\x00\x02")) == ReadDir(2)
    assert decode(Frame("R_DR", b"\x01")) == ReadDir(1)


def test_multi_entry_listing() -> None:
    entries = (FileEntry("a", 1, 2, 3), FileEntry("b", 4, 5, 6), FileEntry("TNC:", 0, 0, 0x10))
    payload = encode(DirReply(entries)).payload
    assert decode(Frame("S_DR", payload)) == DirReply(entries)
    # pyLSV2 steps drive lists in 17-byte records: 12 + "TNC:\0"
    assert len(FileEntry("TNC:").to_bytes()) == 17


def test_directory_info_minimum() -> None:
    info = DirectoryInfo(0xFFFFFFFF, "TNC:\\")
    raw = info.to_bytes()
    assert len(raw) == 170
    assert raw[164:] == b"TNC:\\\x00"
    assert DirectoryInfo.from_bytes(raw) == info
    with pytest.raises(RemoteProtocolError, match="165"):
        DirectoryInfo.from_bytes(raw[:160])


def test_system_info_exact_length() -> None:
    assert encode(SystemInfoReply(2, 3000)).payload == bytes.fromhex("0000000200000BB8")
    with pytest.raises(RemoteProtocolError, match="8 bytes"):
        decode(Frame("S_CI", b"\x00" * 7))


@pytest.mark.parametrize(
    ("name", "payload", "match"),
    [
        ("Z_ZZ", b"", "unknown telegram"),
        ("T_OK", b"\x00", "no payload"),
        ("A_LG", b"", "login"),
        ("R_MB", b"\x00\x00", "5 bytes"),
        ("R_MB", b"\x00\x00\x00\x00\x00", "0 bytes"),
        ("S_OD", b"\x00\x00\x00\x01\x00", "134"),
        ("S_OP", b"\x00" * 21, "22"),
        ("C_FR", b"a.h\x00", "target"),
        ("S_DP", b"\x00\x00\x00\x63\x00", "type 99"),
        ("S_DP", b"\x00\x00\x00\x03\x00", "needs 4"),
        ("S_FI", b"\x00" * 5, "12 bytes"),
        ("C_FL", b"a\x00\x01\x02", "after the path"),
    ],
)
def test_malformed_payloads_name_the_problem(name: str, payload: bytes, match: str) -> None:
    with pytest.raises(RemoteProtocolError, match=match):
        decode(Frame(name, payload))


def test_unencodable_text_is_input_error() -> None:
    with pytest.raises(InputError, match="Latin-1"):
        encode(Login("INSPECT€"))
    with pytest.raises(InputError, match="NUL"):
        encode(Login("IN\0SPECT"))
