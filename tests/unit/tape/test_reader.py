"""The tape reader: end-of-block forms, framing, TV check, DC codes, limits."""

from __future__ import annotations

import pytest

from opendnc.tape.codes import Code, Codec, Eob
from opendnc.tape.errors import TapeCharacterError, TapeParityError, TvCheckError
from opendnc.tape.reader import End, ReaderConfig, TapeReader

BLOCKS = ["%", "O0001", "G01 X1.", "", "M30"]


@pytest.mark.parametrize("eob", list(Eob))
def test_every_eob_reads_the_same_blocks(eob: Eob) -> None:
    codec = Codec(Code.ISO, parity=True, eob=eob)
    reader = TapeReader(ReaderConfig(codec=codec))
    wire = b"\0" * 5 + b"".join(codec.encode_block(b) for b in BLOCKS) + codec.encode_text("%", 0)
    reader.feed(wire)
    assert reader.ended is End.PERCENT
    assert reader.text() == "%\nO0001\nG01 X1.\n\nM30\n%\n"


def test_label_before_the_opening_percent_is_kept_apart() -> None:
    reader = TapeReader(ReaderConfig(codec=Codec(Code.ISO, parity=False)))
    used = reader.feed(b"  $A.MIN\n%\nO1\n%\n\0\0\x14")
    assert reader.label == ["$A.MIN"]
    assert reader.text() == "%\nO1\n%\n"
    assert used == len(b"  $A.MIN\n%\nO1\n%")  # the trailer is left to the caller


def test_tv_check_names_the_block() -> None:
    reader = TapeReader(ReaderConfig(codec=Codec(Code.ISO, parity=False), tv_check=True))
    reader.feed(b"%\nG01 \n")  # four characters: even
    with pytest.raises(TvCheckError, match="line 3"):
        reader.feed(b"G01\n")


def test_parity_error_names_line_and_column() -> None:
    reader = TapeReader(ReaderConfig(codec=Codec(Code.ISO, parity=True)))
    with pytest.raises(TapeParityError, match="line 2, column 2"):
        reader.feed(bytes([0xA5, 0x0A, 0x47, 0x31]))  # '1' without its parity bit


def test_dc4_and_end_of_file_end_a_record() -> None:
    dc = TapeReader(ReaderConfig(codec=Codec(Code.ISO, parity=False)))
    dc.feed(b"\x12\0\0X1\nX2\x14")
    assert (dc.ended, dc.blocks) == (End.DC4, ["X1", "X2"])
    sub = TapeReader(ReaderConfig(codec=Codec(Code.ISO, parity=False), eof_char="\x1a"))
    sub.feed(b"%_N_A_MPF\nG0 X1\n\x1a")
    assert sub.ended is End.EOF
    assert sub.text() == "%_N_A_MPF\nG0 X1\n"


def test_eia_digit_three_is_not_dc3() -> None:
    codec = Codec(Code.EIA)
    reader = TapeReader(ReaderConfig(codec=codec))
    reader.feed(codec.encode_block("%") + codec.encode_block("X3") + codec.encode_text("%", 0))
    assert reader.program == ["%", "X3", "%"]


def test_limits_turn_garbage_into_typed_errors() -> None:
    reader = TapeReader(ReaderConfig(codec=Codec(Code.ISO, parity=False), max_block=8))
    with pytest.raises(TapeCharacterError, match="longer than 8"):
        reader.feed(b"X" * 9)


def test_filler_and_dc_codes_count_against_max_bytes() -> None:
    reader = TapeReader(ReaderConfig(codec=Codec(Code.ISO, parity=False), max_bytes=1000))
    reader.feed(b"\x12%\nO0001\n")  # the record has started
    noise = b"\0\x11" * 100_000  # 200 000 bytes of NUL and DC1: never a character
    with pytest.raises(TapeCharacterError, match="more than 1000 bytes"):
        reader.feed(noise)
    assert reader.received == 1001


def test_a_leader_is_skipped_up_to_max_leader() -> None:
    config = ReaderConfig(codec=Codec(Code.ISO, parity=False), max_leader=600)
    reader = TapeReader(config)
    reader.feed(b"\0" * 300 + b" " * 300 + b"%\nO0001\n" + b"\0" * 700)  # trailer: no leader
    assert (reader.leader, reader.blocks) == (600, ["%", "O0001"])
    long = TapeReader(config)
    with pytest.raises(TapeCharacterError, match="more than 600 feed bytes before the program"):
        long.feed(b"\x7f" * 601 + b"%\n")
