"""What the dry run computes, against values worked out by hand."""

from __future__ import annotations

import math

import pytest

from opendnc.nccheck import (
    Control,
    MoveKind,
    Plane,
    Severity,
    check_text,
    guess_control,
)


def haas(body: str, **kwargs: object) -> object:
    return check_text("%\nO01000\n" + body + "\nM30\n%\n", **kwargs)  # type: ignore[arg-type]


def klartext(*blocks: str) -> object:
    lines = ["BEGIN PGM T MM", *blocks, "END PGM T MM"]
    return check_text("\n".join(f"{n} {b}" for n, b in enumerate(lines)))


def test_guess_control() -> None:
    assert guess_control("0 BEGIN PGM A MM\n1 END PGM A MM") is Control.HEIDENHAIN
    assert guess_control("%\nO1000\nG0 X1.\nM30\n%") is Control.HAAS
    assert guess_control("%PART G71 *\nN10 G00 X+0 *") is Control.ISO
    assert guess_control("G0 X1", "part.i") is Control.ISO
    assert guess_control("", "part.H") is Control.HEIDENHAIN


def test_distances_time_and_tools() -> None:
    result = check_text(
        "%\nO1\nG21 G90 G54\nT3 M06\nS1200 M03\nG00 X0. Y0. Z0.\n"
        "G01 X100. F600.\nG00 X100. Y254.\nM30\n%\n"
    )
    assert result.problems == ()
    assert result.feed_distance == pytest.approx(100.0)
    assert result.rapid_distance == pytest.approx(254.0)
    # 100 mm at 600 mm/min = 10 s, 254 mm at 25,400 mm/min = 0.6 s, one tool change 4 s
    assert result.cycle_time_s == pytest.approx(14.6)
    (tool,) = result.tools
    assert (tool.tool, tool.line, tool.speed, tool.feed_distance) == ("3", 4, 1200.0, 100.0)
    assert result.extents == {"X": (0.0, 100.0), "Y": (0.0, 254.0), "Z": (0.0, 0.0)}


def test_arcs_by_centre_and_by_radius() -> None:
    result = haas(
        "G21 G90 G54\nT1 M06\nS1000 M03\nG00 X10. Y0. Z0.\n"
        "G03 X0. Y10. I-10. J0. F100.\n"  # quarter circle around the origin
        "G02 X10. Y0. R-10.\n"  # the long way (R < 0): three quarters around (10, 10)
        "G17 G02 X10. Y0. I-10. J0."  # a full circle
    )
    assert result.problems == ()
    quarter, three_quarters, full = result.moves[-3:]
    assert quarter.kind is MoveKind.ARC_CCW
    assert quarter.center == pytest.approx((0.0, 0.0, 0.0))
    assert three_quarters.kind is MoveKind.ARC_CW
    assert three_quarters.center == pytest.approx((10.0, 10.0, 0.0))
    assert full.start == full.end
    arc_length = 10.0 * (math.pi / 2 + 3 * math.pi / 2 + 2 * math.pi)
    assert result.feed_distance == pytest.approx(arc_length)
    # extents hold the quadrant points the arcs pass: (-10, 0) and (0, -10) of the full
    # circle, (10, 20) and (20, 10) of the three-quarter arc
    assert result.extents["X"] == pytest.approx((-10.0, 20.0))
    assert result.extents["Y"] == pytest.approx((-10.0, 20.0))


def test_arc_in_the_zx_plane_and_a_helix() -> None:
    result = haas(
        "G21 G90\nT1 M06\nS1000 M03\nG00 X0. Y0. Z0.\nG18 G02 X10. Z10. R10. F100.\n"
        "G17 G03 X10. Y0. Z15. I-5. J0."
    )
    assert result.problems == ()
    arc, helix = result.moves[-2:]
    assert arc.plane is Plane.ZX
    assert arc.center == pytest.approx((10.0, 0.0, 0.0)) or arc.center == pytest.approx(
        (0.0, 0.0, 10.0)
    )
    assert helix.plane is Plane.XY
    assert result.feed_distance == pytest.approx(10 * math.pi / 2 + math.hypot(10 * math.pi, 5))


def test_canned_cycle_holes_absolute_and_incremental() -> None:
    result = haas(
        "G21 G90 G54\nT2 M06\nS800 M03\nG00 X0. Y0. Z10.\n"
        "G81 G98 Z-5. R2. F100.\nX20.\nG91 X10. L2\nG90 G80"
    )
    assert result.problems == ()
    holes = [m.end for m in result.moves if m.kind is MoveKind.FEED]
    assert holes == [(0.0, 0.0, -5.0), (20.0, 0.0, -5.0), (30.0, 0.0, -5.0), (40.0, 0.0, -5.0)]
    # G98: back to the start level Z10 after each hole
    assert result.end.position["Z"] == 10.0
    assert result.feed_distance == pytest.approx(4 * 7.0)


def test_g65_arguments_m97_and_m99_p() -> None:
    text = (
        "%\nO1000\nG65 P2000 A3. B4.\nM97 P100 L3\nM98 P2001\nN20 #110 = 1\nM30\n"
        "N100 #101 = #101 + 1\nM99\n%\nO2000\n#100 = SQRT[#1 * #1 + #2 * #2]\nM99\n"
        "%\nO2001\nM99 P20\n%\n"
    )
    result = check_text(text)
    assert result.problems == ()
    assert result.end.variables[100] == 5.0
    assert result.end.variables[101] == 3.0
    assert result.end.variables[110] == 1.0
    assert 1 not in result.end.variables  # G65 arguments are the macro's own locals


def test_endless_recursion_is_stopped() -> None:
    result = check_text("%\nO1000\nM98 P1000\nM30\n%\n")
    assert [(p.line, p.severity) for p in result.problems] == [(3, Severity.ERROR)]
    assert "nest deeper than 20" in result.problems[0].message


def test_work_offsets_set_by_the_program_and_g28() -> None:
    result = haas("#5221 = -100.\nG10 L2 P2 X-50.\nG90 G54 X1.\nG55 X1.\nG28 G91 X0.\nG90")
    assert result.problems == ()
    assert result.end.machine_position["X"] == 0.0
    assert result.end.position["X"] == 50.0  # in G55


def test_klartext_repeat_and_subprogram_counts() -> None:
    result = klartext(
        "Q1 = 0",
        "Q2 = 0",  # set before it is read (else a warning)
        "LBL 1",
        "Q1 = Q1 + 1",
        "CALL LBL 1 REP 4",
        "CALL LBL 2",
        "CALL LBL 2",
        "M30",
        "LBL 2",
        "Q2 = Q2 + 10",
        "LBL 0",
    )
    assert result.problems == ()
    assert result.end.variables == {1: 5.0, 2: 20.0}


def test_klartext_polar_helix_and_tangent_arc() -> None:
    result = klartext(
        "TOOL CALL 1 Z S1000",
        "L X+0 Y+0 Z+0 R0 FMAX M3",
        "CC X+0 Y+0",
        "LP PR+10 PA+90 R0 F100",  # to (0, 10)
        "CP IPA-720 IZ-4 DR-",  # two turns clockwise, 4 down
        "L X+10",  # tangent direction +X at (10, 10)
        "CT X+20 Y+0",  # a quarter circle around (10, 0), clockwise
    )
    assert result.problems == ()
    assert result.end.position == pytest.approx({"X": 20.0, "Y": 0.0, "Z": -4.0})
    helix = math.hypot(2 * 2 * math.pi * 10, 4)
    assert result.feed_distance == pytest.approx(10 + helix + 10 + math.pi * 5, rel=1e-6)
    ct = result.moves[-1]
    assert ct.kind is MoveKind.ARC_CW
    assert ct.center == pytest.approx((10.0, 0.0, -4.0))


def test_klartext_pattern_datum_shift_and_m89() -> None:
    # cycle parameters are lines without a block number after the CYCL DEF (TNC files)
    text = """0 BEGIN PGM T MM
1 TOOL CALL 5 Z S2000 F300
2 L Z+50 R0 FMAX M3
3 CYCL DEF 7.0 DATUM SHIFT
4 CYCL DEF 7.1 X+100
5 CYCL DEF 201 REAMING ~
  Q200=2 ;SET-UP CLEARANCE ~
  Q201=-10 ;DEPTH ~
  Q206=100 ;FEED RATE FOR PLNGNG ~
  Q211=0.5 ;DWELL TIME AT DEPTH ~
  Q208=0 ;RETRACTION FEED RATE ~
  Q203=+0 ;SURFACE COORDINATE ~
  Q204=20 ;2ND SET-UP CLEARANCE
6 PATTERN DEF ~
  POS1 (X+10 Y+10 Z+0) ~
  POS2 (X+20 Y+10 Z-1)
7 CYCL CALL PAT
8 M89
9 L X+5 Y+5 R0 FMAX
10 END PGM T MM
"""
    result = check_text(text)
    assert result.problems == ()
    bottoms = [m.end for m in result.moves if m.kind is MoveKind.FEED and m.end[2] < 0]
    assert bottoms == [(110.0, 10.0, -10.0), (120.0, 10.0, -11.0), (105.0, 5.0, -10.0)]
    # reaming leaves at the feed (Q208 = 0: Q206): 2 x 12 mm a hole
    assert result.feed_distance == pytest.approx(3 * 24.0)


def test_travel_in_inch_checks_a_metric_program() -> None:
    from opendnc.nccheck import MachineLimits, Units

    vf2 = MachineLimits(
        name="vf2",
        family="haas",
        travel={"X": (-30.0, 0.0)},
        travel_units=Units.INCH,
        work_offsets={"G54": {"X": -20.0}},  # -508 mm
    )
    # X-254 mm + offset -508 mm = -762 mm = -30 inch: on the limit; X-255 is 1 mm beyond
    inside = haas("G21 G90 G54\nG00 X-254.", machine=vf2)
    assert inside.problems == ()
    beyond = haas("G21 G90 G54\nG00 X-255.", machine=vf2)
    assert [p.line for p in beyond.problems] == [4]
    assert "X goes to -763 in machine coordinates" in beyond.problems[0].message
    assert haas("G20 G90 G54\nG00 X-10.", machine=vf2).problems == ()
    klartext_tnc = MachineLimits(
        family="heidenhain",
        travel={"X": (-1.0, 1.0)},
        travel_units=Units.INCH,
        work_offsets={"G54": {"X": 0.0}},
    )
    text = "0 BEGIN PGM T MM\n1 L X+26 R0 FMAX\n2 END PGM T MM\n"
    result = check_text(text, machine=klartext_tnc)
    assert [p.line for p in result.problems] == [2]


def test_klartext_approach_departure_and_normal_vectors() -> None:
    result = klartext(
        "TOOL CALL 1 Z S1000 F200",
        "L X-20 Y-20 Z+5 R0 FMAX M3",
        "L Z-2 F AUTO",
        "APPR LCT X+0 Y+0 R5 RL F100",
        "L X+50",
        "DEP LCT X-20 Y-20 R5 F AUTO",
        "LN X+1 Y+2 Z+3 NX+0 NY+0 NZ+1",
    )
    assert [(p.line, p.severity) for p in result.problems] == [
        (5, Severity.WARNING),
        (7, Severity.WARNING),
    ]
    assert result.end.position == {"X": 1.0, "Y": 2.0, "Z": 3.0}
    assert result.feed_distance == pytest.approx(
        7 + math.hypot(20, 20) + 50 + math.hypot(70, 20) + math.hypot(21, 22, 5)
    )


def test_a_length_offset_of_another_tool_is_a_warning() -> None:
    result = haas("G21 G90 G54\nT2 M06\nG43 H2 Z50.\nT3 M06\nG43 H2 Z50.")
    assert [(p.line, p.severity) for p in result.problems] == [(7, Severity.WARNING)]
    assert result.problems[0].message.startswith("G43 H2 with tool T3 in the spindle")


def test_blank_form_with_decimals_that_look_like_its_numbers() -> None:
    result = klartext("BLK FORM 0.1 Y X-10.1 Y+0.1 Z-20.2", "BLK FORM 0.2 X+10.1 Y+50.2 Z+0.1")
    assert result.problems == ()
    assert result.stock is not None
    assert result.stock.minimum == (-10.1, 0.1, -20.2)
    assert result.stock.maximum == (10.1, 50.2, 0.1)
    assert result.stock.axis == "Y"


def test_program_names_are_not_m_functions() -> None:
    text = "0 BEGIN PGM M100 MM\n1 CALL PGM TNC:\\M5000.H\n2 L Z+5 R0 FMAX M77\n3 END PGM M100 MM\n"
    result = check_text(
        text, library={"TNC:\\M5000.H": "0 BEGIN PGM M5000 MM\n1 END PGM M5000 MM"}.get
    )
    assert [(p.line, p.message) for p in result.problems] == [
        (3, "M77 is not an M function of the TNC")
    ]


def test_an_endless_loop_in_a_library_program_is_named_by_its_call() -> None:
    from opendnc.nccheck import Budget

    sub = "%\nO2000\nN1 #100 = #100 + 1\nGOTO 1\nM99\n%\n"
    main = "%\nO1000\nG21\nM98 P2000\nM30\n%\n"
    result = check_text(main, library={"O02000": sub}.get, budget=Budget(blocks=50_000))
    assert [(p.line, p.severity) for p in result.problems] == [(4, Severity.ERROR)]
    assert result.problems[0].message.startswith(
        "endless loop: the jump back at line 4 (in O02000 line 4)"
    )


def test_iso_programs_with_a_number_as_their_name() -> None:
    from opendnc.nccheck import Units

    text = "%1000 G70 *\nN10 T1 G17 S1000 *\nN20 G00 X+0 Y+0 Z+1 M03 *\nN30 G01 X+2 F10 *\n"
    text += "N99999999 %1000 G70 *\n"
    assert guess_control(text) is Control.ISO
    result = check_text(text)
    assert result.problems == ()
    assert result.units is Units.INCH
    assert result.end.ended
    # a Haas bolt-hole G70 on the line after the O number is still G-code for a Haas
    assert guess_control("%\nO01000\nG70 I1. J0. L4\nM30\n%\n") is Control.HAAS


def test_the_library_is_asked_once_and_may_fail() -> None:
    asked: list[str] = []

    def library(name: str) -> str | None:
        asked.append(name)
        raise OSError("library offline")

    text = "%\nO1000\n#1 = 0\nWHILE [#1 LT 5] DO1\nG65 P9832\n#1 = #1 + 1\nEND1\nM30\n%\n"
    result = check_text(text, library=library)
    assert asked == ["O09832"]
    assert [(p.line, p.severity, p.message) for p in result.problems] == [
        (5, Severity.WARNING, "calls O09832, which is not in the library")
    ]


def test_call_pgm_asks_the_library_by_the_name_as_written() -> None:
    sub = "0 BEGIN PGM sub MM\n1 Q5 = Q5 + 1\n2 END PGM sub MM\n"
    asked: list[str] = []

    def library(name: str) -> str | None:
        asked.append(name)
        return sub if name == "TNC:\\parts\\sub.h" else None

    result = check_text(
        "0 BEGIN PGM T MM\n1 Q5 = 0\n1 LBL 1\n2 CALL PGM TNC:\\parts\\sub.h\n"
        "3 CALL LBL 1 REP 2\n4 END PGM T MM\n",
        library=library,
    )
    assert result.problems == ()
    assert asked == ["TNC:\\parts\\sub.h"]
    assert result.end.variables[5] == 3.0


def test_fn_functions_as_the_tnc_writes_them() -> None:
    result = klartext(
        "FN 0: Q1 = +30",
        "FN 1: Q2 = +Q1 + +10",
        "FN 2: Q3 = +Q2 - +4",
        "FN 3: Q4 = +Q3 * +2",
        "FN 4: Q5 = +Q4 DIV +8",
        "FN 5: Q6 = SQRT +81",
        "FN 6: Q7 = SIN+Q1",
        "FN 7: Q8 = COS-60",
        "FN 8: Q9 = +3 LEN +4",
        "FN 13: Q10 = +1 ANG +1",
        "Q11 = 2 ^ 3 + ABS -1",
    )
    assert result.problems == ()
    values = result.end.variables
    expected = {1: 30, 2: 40, 3: 36, 4: 72, 5: 9, 6: 9, 7: 0.5, 8: 0.5, 9: 5, 10: 45, 11: 9}
    assert values == pytest.approx({k: float(v) for k, v in expected.items()})


def test_rounded_and_chamfered_corners() -> None:
    result = klartext(
        "TOOL CALL 1 Z S1000",
        "L X+0 Y+0 Z-1 R0 FMAX M3",
        "L X+10 F100",
        "RND R2",
        "L Y+10",  # left turn: a quarter circle of R2 around (8, 2)
        "CHF 3",
        "L X+0",  # a 3 mm chamfer from (10, 7) to (7, 10)
    )
    assert result.problems == ()
    kinds = [m.kind for m in result.moves]
    assert kinds[-5:] == [MoveKind.FEED, MoveKind.ARC_CCW, MoveKind.FEED, MoveKind.FEED,
                          MoveKind.FEED]  # fmt: skip
    arc = result.moves[-4]
    assert arc.start == pytest.approx((8.0, 0.0, -1.0))
    assert arc.end == pytest.approx((10.0, 2.0, -1.0))
    assert arc.center == pytest.approx((8.0, 2.0, -1.0))
    chamfer = result.moves[-2]
    assert chamfer.start == pytest.approx((10.0, 7.0, -1.0))
    assert chamfer.end == pytest.approx((7.0, 10.0, -1.0))
    assert result.feed_distance == pytest.approx(8 + math.pi + 5 + math.hypot(3, 3) + 7)


def test_a_rounding_too_big_for_its_corner_is_an_error() -> None:
    result = klartext(
        "TOOL CALL 1 Z S1000",
        "L X+0 Y+0 Z-1 R0 FMAX M3",
        "L X+3 F100",
        "RND R5",
        "L Y+10",
    )
    assert [(p.line, p.severity) for p in result.problems] == [(5, Severity.ERROR)]
    assert result.problems[0].message == "RND 5 does not fit its corner"
