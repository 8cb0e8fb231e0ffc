"""Profiles, framing, names and restart preambles per control."""

from __future__ import annotations

from pathlib import Path

import pytest

from opendnc.errors import InputError
from opendnc.haas.modal import scan
from opendnc.tape.codes import Code
from opendnc.tape.dialects import dialect_preamble, get_dialect
from opendnc.tape.errors import TapeNameError
from opendnc.tape.feed import TapeFeed, program_wire
from opendnc.tape.naming import check_send_name, received_name
from opendnc.tape.profiles import PROFILES, get_profile

NAMES = {
    "fanuc-0i", "fanuc-30i", "mitsubishi-m80", "mazak-smooth", "okuma-osp",
    "siemens-828d", "siemens-840d", "fagor", "haas",
}  # fmt: skip


def test_every_profile_the_issue_names_is_there() -> None:
    assert set(PROFILES) == NAMES
    for profile in PROFILES.values():
        bits, parity, _stop = profile.port_settings
        assert (bits, parity) in {(8, "N"), (7, "E")}
        assert profile.chars_per_second == profile.baud / profile.bits_per_char


def test_fanuc_7e2_is_opened_8n2_with_parity_in_the_codec() -> None:
    fanuc = get_profile("fanuc-0i")
    assert (fanuc.line, fanuc.port_settings, fanuc.bits_per_char) == ("7E2", (8, "N", 2.0), 11)
    assert fanuc.codec().parity
    assert not get_profile("mazak-smooth").codec().parity
    with pytest.raises(InputError, match="EIA line is 8 bits"):
        fanuc.with_changes(code=Code.EIA)
    with pytest.raises(InputError, match="unknown profile"):
        get_profile("heidenhain")


def _program(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_framing_per_control(tmp_path: Path) -> None:
    path = _program(tmp_path, "PART1.nc", "%\nO0001 (A)\nG0 X1.\nM30\n%\n")
    assert program_wire(path, get_profile("haas")) == b"%\r\nO0001 (A)\r\nG0 X1.\r\nM30\r\n%\r\n"
    assert program_wire(path, get_profile("siemens-840d")) == (
        b"%_N_PART1_MPF\n;$PATH=/_N_MPF_DIR\nO0001 (A)\nG0 X1.\nM30\n\x1a"
    )
    assert program_wire(path, get_profile("fagor")) == b"%PART1,MX,\nO0001 (A)\nG0 X1.\nM30\n\x04"
    okuma = program_wire(path, get_profile("okuma-osp").with_changes(line="8N2"))
    assert okuma == b"$PART1.MIN\r\n%\r\nO0001 (A)\r\nG0 X1.\r\nM30\r\n%\r\n"


def test_tv_check_pads_and_comments_strip(tmp_path: Path) -> None:
    path = _program(tmp_path, "O1.nc", "%\nO0001 (A)\nG01\nG1\n%\n")
    profile = get_profile("mazak-smooth").with_changes(tv_check=True, strip_comments=True)
    assert program_wire(path, profile) == b"%\nO0001 \nG01 \nG1\n%\n"


def test_send_name_rules(tmp_path: Path) -> None:
    fanuc = get_profile("fanuc-0i")
    check_send_name(fanuc, ["%\n", "O1234 (X)\n"], Path("a.nc"))
    with pytest.raises(InputError, match="more than 4 digits"):
        check_send_name(fanuc, ["%\n", "O12345\n"], Path("a.nc"))
    with pytest.raises(InputError, match="no O-number"):
        check_send_name(fanuc, ["%\n", "G00\n"], Path("a.nc"))
    check_send_name(get_profile("fanuc-30i"), ["<SHAFT_2>\n"], Path("a.nc"))
    with pytest.raises(InputError, match="Sinumerik name"):
        check_send_name(get_profile("siemens-828d"), ["%\n"], Path("has-dash.mpf"))
    with pytest.raises(InputError, match="Okuma file name"):
        check_send_name(get_profile("okuma-osp"), ["%\n"], Path("1ABC.nc"))


def test_received_names() -> None:
    assert received_name(get_profile("fanuc-0i"), [], ["%", "O0007 (X)"]) == "O0007.nc"
    assert received_name(get_profile("fanuc-30i"), [], ["%", "<SHAFT 2>"]) == "SHAFT_2.nc"
    assert received_name(get_profile("okuma-osp"), ["$PART1.MIN"], ["%"]) == "PART1.MIN"
    assert received_name(get_profile("siemens-840d"), [], ["%_N_SHAFT_SPF"]) == "SHAFT.SPF"
    assert received_name(get_profile("fagor"), [], ["%Fagor Automation,MX,"]) == (
        "Fagor_Automation.PIM"
    )
    assert received_name(get_profile("fanuc-0i"), [], ["%", "G00"]) is None


def test_siemens_restart_preamble_speaks_siemens() -> None:
    state = scan(["G21", "T1 M06", "G54", "S1000 M03", "G01 X1. F100."])
    plan = dialect_preamble(state, 9, get_dialect("siemens"))
    assert plan.preamble == (
        "; OPENDNC RESTART AT LINE 9", "G21", "G0 G17 G40 G90", "SUPA G0 Z0",
        "T1 M06", "G54", "S1000 M03", "G01 F100.",
    )  # fmt: skip
    okuma = dialect_preamble(state, 9, get_dialect("okuma"))
    assert "G91 G28 Z0." not in okuma.preamble
    assert any("retract by hand" in w for w in okuma.warnings)


def test_restart_keeps_a_siemens_header(tmp_path: Path) -> None:
    text = "%_N_A_MPF\n;$PATH=/_N_MPF_DIR\nG21\nG0 X1\nG1 X2 F100.\nM30\n"
    path = _program(tmp_path, "A.MPF", text)
    feed = TapeFeed(path, get_profile("siemens-840d"), from_line=5)
    try:
        wire = b"".join(feed).decode()
    finally:
        feed.close()
    assert wire.startswith("%_N_A_MPF\n;$PATH=/_N_MPF_DIR\n; OPENDNC RESTART AT LINE 5\nG21\n")
    assert wire.endswith("G1 X2 F100.\nM30\n\x1a")


def test_received_names_breaking_the_rules_are_typed_errors() -> None:
    with pytest.raises(TapeNameError, match="up to 4 digits"):
        received_name(get_profile("fanuc-0i"), [], ["%", "O12345 (X)"])
    assert received_name(get_profile("haas"), [], ["%", "O12345"]) == "O12345.nc"
    with pytest.raises(TapeNameError, match=r"'B{32}\.\.\. \(4000 characters\)'.* 24"):
        received_name(get_profile("siemens-840d"), [], [f"%_N_{'B' * 4000}_MPF"])
    assert received_name(get_profile("siemens-840d"), [], [f"%_N_{'B' * 24}_MPF"]) == (
        "B" * 24 + ".MPF"
    )
    okuma = get_profile("okuma-osp")
    for label in ("$ABCDEFGHIJKLMNOPQ.MIN", "$PART1.MINX"):
        with pytest.raises(TapeNameError, match="Okuma name is up to 16"):
            received_name(okuma, [label], ["%"])
    assert received_name(okuma, ["$ABCDEFGHIJKLMNOP.SUB"], ["%"]) == "ABCDEFGHIJKLMNOP.SUB"
    with pytest.raises(TapeNameError, match="up to 20 characters"):
        received_name(get_profile("fagor"), [], [f"%{'F' * 21},MX,"])
