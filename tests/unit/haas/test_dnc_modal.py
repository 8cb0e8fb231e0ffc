"""The modal-state tracker and the restart preamble built from it."""

from __future__ import annotations

from opendnc.haas.modal import ModalState, code_text, restart_preamble, scan, track

PROGRAM = """%
O01234 (POCKET)
G20
G00 G17 G40 G80 G90
T3 M06 (1/2 END MILL)
G00 G54 X0. Y0.
S2500 M03
G43 H03 Z1. M08
G01 Z-0.25 F15.
X2. F30.
G91 G01 X0.1
G90 G02 X3. Y1. R1.
G01 X4.
""".splitlines()


def test_nothing_set() -> None:
    assert scan([]) == ModalState()
    assert track(ModalState(), "%") == ModalState()
    assert track(ModalState(), "(ONLY A COMMENT)") == ModalState()


def test_full_program_state() -> None:
    state = scan(PROGRAM)
    assert state.header == "O01234 (POCKET)"
    assert state.units == "G20"
    assert state.plane == "G17"
    assert state.distance == "G90"
    assert state.work_offset == "G54"
    assert state.tool == "T3"
    assert state.speed == "S2500"
    assert state.spindle == "M03"
    assert state.tool_length == "G43 H03"
    assert state.coolant == "M08"
    assert state.feed == "F30."
    assert state.motion == "G01"


def test_state_before_a_line_and_the_preamble() -> None:
    # restart at file line 11 ("G91 G01 X0.1"): everything up to X2. F30. is in force
    state = scan(PROGRAM[:10])
    plan = restart_preamble(state, 11)
    assert plan.preamble == (
        "%",
        "O01234 (POCKET)",
        "(OPENDNC RESTART AT LINE 11)",
        "G20",
        "G00 G17 G40 G80 G90",
        "G91 G28 Z0.",
        "G90",
        "T3 M06",
        "G54",
        "G43 H03",
        "S2500 M03",
        "M08",
        "G01 F30.",
    )
    assert plan.warnings == ()


def test_incremental_and_no_retract() -> None:
    state = scan(PROGRAM[:11])
    plan = restart_preamble(state, 12, retract=False)
    assert "G91 G28 Z0." not in plan.preamble
    # G91 is restored after the absolute safety block, just before the motion mode
    assert plan.preamble[-2:] == ("G91", "G01 F30.")


def test_arc_in_force_is_a_warning() -> None:
    state = scan(PROGRAM[:12])
    assert state.motion == "G02"
    plan = restart_preamble(state, 13)
    assert plan.preamble[-1] == "F30."
    assert "G02" in plan.warnings[0]


def test_normalisation_and_special_groups() -> None:
    state = scan(["G1 X1.", "G0", "G21", "G18", "G154 P12", "M04 S300", "M88", "G49", "G93"])
    assert state.motion == "G00"
    assert state.units == "G21"
    assert state.plane == "G18"
    assert state.work_offset == "G154 P12"
    assert state.spindle == "M04"
    assert state.speed == "S300"
    assert state.through_coolant
    assert state.tool_length is None
    assert state.feed_mode == "G93"
    preamble = restart_preamble(state, 99).preamble
    assert "S300 M04" in preamble
    assert "M88" in preamble
    assert "G93" in preamble
    assert "G00 G18 G40 G80 G90" in preamble


def test_tool_word_needs_m06_and_m05_stops_spindle() -> None:
    state = scan(["T7", "S100 M03"])
    assert state.tool is None
    assert state.next_tool == "T7"
    state = scan(["M06", "M05", "M09", "G80", "G81 Z-1. R.1"], state)
    assert state.tool == "T7"
    assert state.spindle == "M05"
    assert state.coolant == "M09"
    assert state.motion == "G81"
    preamble = restart_preamble(state, 5).preamble
    assert "T7 M06" in preamble
    assert "S100" in preamble  # stopped: speed only, no M03
    assert "M09" not in preamble


def test_macro_lines_and_comments_change_nothing() -> None:
    state = scan(["G21"])
    for line in ["#100 = 20", "IF [#1 GT 2] GOTO 5", "DPRNT[G90]", "(G91 M03)", "WHILE [1] DO1"]:
        assert track(state, line) is state
    assert code_text("/N10 G01 (C) X1.;ignored") == "N10 G01   X1."


def test_o_line_only_before_anything_else() -> None:
    state = scan(["O00001 (A)", "O00002 (B)"])
    assert state.header == "O00001 (A)"
