"""DPRNT formatting rules (Haas manual) and the capture-side framer/parser."""

from __future__ import annotations

import pytest

from opendnc.errors import InputError
from opendnc.haas.dprnt import (
    DprntLineFramer,
    DroppedLine,
    FramedLine,
    Text,
    Variable,
    format_value,
    parse_line,
    parse_statement,
    render,
)


@pytest.mark.parametrize(
    ("value", "fmt", "expected"),
    [
        (1.5436, (4, 4), "   1.5436"),  # manual: X#1[44]
        (1.5436, (0, 3), "1.544"),  # rounded to the last printed place
        (1.5436, (4, 0), "   1"),  # no point, whole part not rounded up
        (1.5, (1, 4), "1.5000"),  # trailing zeros kept
        (12345.6, (2, 2), "12345.60"),  # a longer whole part grows the field
        (-1.5, (4, 4), "  -1.5000"),  # our documented sign choice
        (1.99996, (1, 4), "2.0000"),  # rounding carries into the whole part
        (-0.00001, (1, 2), "0.00"),  # no negative zero
        (None, (2, 1), " 0.0"),  # null prints as zero
        (0.5, (0, 1), "0.5"),  # at least one whole place
    ],
)
def test_format_value(value: float | None, fmt: tuple[int, int], expected: str) -> None:
    assert format_value(value, *fmt) == expected


@pytest.mark.parametrize("fmt", [(0, 0), (5, 4), (4, 5), (3, 6), (9, 0)])
def test_illegal_formats(fmt: tuple[int, int]) -> None:
    with pytest.raises(InputError, match="illegal DPRNT format"):
        format_value(1.0, *fmt)


def test_statement_text_star_is_space() -> None:
    items = parse_statement("DPRNT[***MEASURED*INSIDE*DIAMETER***]")
    assert items == (Text("   MEASURED INSIDE DIAMETER   "),)
    assert render(items, lambda n: None) == "   MEASURED INSIDE DIAMETER   "


def test_statement_variables() -> None:
    items = parse_statement("DPRNT[X#5041[44]*Z#5223[34]]")
    assert items == (Text("X"), Variable(5041, 4, 4), Text(" Z"), Variable(5223, 3, 4))
    values = {5041: 0.5, 5223: -2.53104}
    assert render(items, values.get) == "X   0.5000 Z -2.5310"


def test_empty_statement_prints_nothing() -> None:
    assert render(parse_statement("DPRNT[]"), lambda n: None) == ""


@pytest.mark.parametrize(
    "source",
    [
        "DPRNT X1",
        "DPRNT[#1]",
        "DPRNT[#1[54]]",
        "DPRNT[#1[4]]",
        "DPRNT[a]b]",
        "DPRNT[X\x01]",
        "PRNT[]",
    ],
)
def test_bad_statements(source: str) -> None:
    with pytest.raises(InputError):
        parse_statement(source)


def test_framer_line_ends_and_control_bytes() -> None:
    framer = DprntLineFramer()
    framer.feed(b"\x12A 1\r")
    framer.feed(b"\nB 2\nC\x00 3\r\r\n")
    framer.feed(b"\x14D 4")
    # CR LF split across feeds is one line end; CR CR LF is an empty line then one end
    assert list(framer.events()) == [FramedLine(t) for t in ("A 1", "B 2", "C 3", "")]
    assert framer.end_of_stream() == FramedLine("D 4", complete=False)
    assert framer.end_of_stream() is None


def test_framer_drops_the_handshake_of_an_xmodem_receiver_on_the_same_port() -> None:
    # a virtual Haas waiting to receive a program NAKs between the lines it prints (seen in
    # CI: "\x15P 4 X   1.7500 ..."); CAN and SUB end and pad XModem transfers
    framer = DprntLineFramer()
    framer.feed(b"P 3 X   1.2500\r\x15P 4 X   1.7500\r\x18\x18\x1aP 5\x15 X 2.\r")
    printed = ("P 3 X   1.2500", "P 4 X   1.7500", "P 5 X 2.")
    assert list(framer.events()) == [FramedLine(t) for t in printed]


def test_framer_drops_overlong_line_whole_and_keeps_neighbours() -> None:
    framer = DprntLineFramer(max_line=8)
    framer.feed(b"ok 1\n12345")
    framer.feed(b"6789")  # the line passes the limit here ...
    framer.feed(b"ABC\r")  # ... and its tail must not become a line
    framer.feed(b"\nok 2\r\n12345678\n")  # exactly the limit is still a line
    assert list(framer.events()) == [
        FramedLine("ok 1"),
        DroppedLine(12),
        FramedLine("ok 2"),
        FramedLine("12345678"),
    ]


def test_framer_overlong_line_cut_by_end_of_link() -> None:
    framer = DprntLineFramer(max_line=8)
    framer.feed(b"ok\n" + b"M" * 20)
    assert list(framer.events()) == [FramedLine("ok")]
    assert framer.end_of_stream() == DroppedLine(20, complete=False)
    framer.feed(b"new\n")  # a new link starts clean
    assert list(framer.events()) == [FramedLine("new")]


def test_parse_line_fields() -> None:
    parsed = parse_line("X   1.5436 Y  -2.0000 Z-0.25 T1 7 .5")
    assert parsed.numbers == (1.5436, -2.0, -0.25, 1.0, 7.0, 0.5)
    assert parsed.get("x") == 1.5436
    assert parsed.get("Z") == -0.25
    assert parsed.get("Q") is None
    assert [f.label for f in parsed.fields] == ["X", "Y", "Z", "T", "", ""]


def test_parse_line_without_numbers() -> None:
    assert parse_line("   MEASURED INSIDE DIAMETER").numbers == ()
