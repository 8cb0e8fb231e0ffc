"""Haas program conventions: EOB patterns, SUB padding, % delimiters, O-number."""

from __future__ import annotations

import pytest

from opendnc.xmodem.haas import (
    Eob,
    from_wire,
    has_tape_delimiters,
    program_filename,
    program_header,
    strip_padding,
    to_wire,
)

PROGRAM = b"%\nO01234(BRACKET OP1)\nG00 X0. Y0.\n\nM30\n%\n"


@pytest.mark.parametrize(
    ("eob", "wire"),
    [
        (Eob.LF, PROGRAM),
        (Eob.CR, PROGRAM.replace(b"\n", b"\r")),
        (Eob.CRLF, PROGRAM.replace(b"\n", b"\r\n")),
        (Eob.CRCR, PROGRAM.replace(b"\n", b"\r\r")),
        (Eob.LFLF, PROGRAM.replace(b"\n", b"\n\n")),
    ],
)
def test_eob_conversion_both_ways(eob: Eob, wire: bytes) -> None:
    assert to_wire(PROGRAM, eob) == wire
    assert from_wire(wire, eob) == PROGRAM
    # a CR LF file on the PC converts the same way as an LF file
    assert to_wire(PROGRAM.replace(b"\n", b"\r\n"), eob) == wire


def test_delimiters_and_o_number_are_kept_byte_for_byte() -> None:
    for eob in Eob:
        wire = to_wire(PROGRAM, eob)
        assert wire.startswith(b"%" + eob.wire + b"O01234(BRACKET OP1)" + eob.wire)
        assert wire.endswith(b"M30" + eob.wire + b"%" + eob.wire)


def test_padding_strip() -> None:
    assert strip_padding(PROGRAM + b"\x1a" * 48) == PROGRAM
    assert strip_padding(b"\x1a") == b""


def test_program_header_variants() -> None:
    header = program_header(b"\n%\nO05555(CS390_Test_NC)\n(Using G0)\n")
    assert header is not None
    assert (header.number, header.name, header.comment) == (5555, "O05555", "CS390_Test_NC")
    bare = program_header(b"%\r\nO1000\r\nG0\r\n%\r\n")
    assert bare is not None
    assert (bare.name, bare.comment) == ("O1000", None)
    assert program_header(b"%\nG00 X1.\n%\n") is None
    assert program_header(b"") is None
    assert program_filename(PROGRAM) == "O01234.nc"
    assert program_filename(b"%\nG0\n%\n") == "program.nc"


def test_tape_delimiters() -> None:
    assert has_tape_delimiters(b"\n%\nO1\nM30\n\n%\n\x1a\x1a")
    assert not has_tape_delimiters(b"O1\nM30\n")
    assert not has_tape_delimiters(b"%\n")
