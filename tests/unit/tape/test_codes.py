"""ISO and EIA codes: golden bytes worked out by hand from the code tables in docs/tape.md."""

from __future__ import annotations

import pytest

from opendnc.tape.codes import (
    DC1,
    DC2,
    DC4,
    EIA_EOB,
    EIA_TABLE,
    Bad,
    Code,
    Codec,
    Eob,
    eia_to_iso,
    iso_to_eia,
)
from opendnc.tape.errors import NoCodeError, TapeParityError


def test_iso_even_parity_golden() -> None:
    # % = 0x25 has three ones: bit 8 set -> 0xA5; LF 0x0A two ones -> 0x0A;
    # G 0x47 four ones -> 0x47; 0 = 0x30 two -> 0x30; 1 = 0x31 three -> 0xB1
    codec = Codec(Code.ISO, parity=True)
    assert codec.encode_block("%") == bytes([0xA5, 0x0A])
    assert codec.encode_block("G01") == bytes([0x47, 0x30, 0xB1, 0x0A])
    # CR 0x0D has three ones -> 0x8D
    assert Codec(Code.ISO, eob=Eob.CRLF).eob_bytes == bytes([0x8D, 0x0A])
    assert Codec(Code.ISO, eob=Eob.LFCRCR).eob_bytes == bytes([0x0A, 0x8D, 0x8D])
    assert Codec(Code.ISO, parity=False, eob=Eob.CR).encode_block("G01") == b"G01\r"


def test_eia_golden() -> None:
    # G = channels 1,2,3,6,7 -> 0x67; 0 = channel 6 -> 0x20; 1 = channel 1 -> 0x01; EOB ch 8
    assert Codec(Code.EIA).encode_block("G01") == bytes([0x67, 0x20, 0x01, 0x80])
    assert iso_to_eia("X-1.\n") == bytes([0x37, 0x40, 0x01, 0x6B, EIA_EOB])


def test_eia_table_has_odd_parity_and_no_collisions() -> None:
    values = list(EIA_TABLE.values())
    assert len(set(values)) == len(values)
    assert all(value.bit_count() % 2 == 1 for value in values)  # channel 5 makes it odd
    # the DC codes a control sends in the data direction stay distinct from characters
    assert not {DC1, DC2, DC4, EIA_EOB} & set(values)


def test_no_code_names_line_and_column() -> None:
    with pytest.raises(NoCodeError, match=r"'#' at line 2, column 2 has no EIA code"):
        iso_to_eia("G01\nX#1\n")
    with pytest.raises(NoCodeError, match="line 7, column 3"):
        Codec(Code.ISO).encode_text("AB\u00e9", 7)


def test_decode_flags_parity_and_unknown_bytes() -> None:
    iso = Codec(Code.ISO, parity=True)
    assert iso.decode_byte(0xB1) == "1"
    assert iso.decode_byte(0x31) == Bad(0x31, parity=True)  # 1 without its parity bit
    assert iso.decode_byte(0x00) is None  # feed
    eia = Codec(Code.EIA)
    assert eia.decode_byte(0x03) == Bad(0x03, parity=True)  # two holes: even, not EIA
    assert eia.decode_byte(0x7F) is None  # tape feed / rubout
    with pytest.raises(TapeParityError, match="line 2, column 1"):
        eia_to_iso(bytes([0x01, EIA_EOB, 0x03]))


def test_eia_extra_characters_per_machine() -> None:
    codec = Codec(Code.EIA, eia_extra={"#": 0x0E})  # 3 holes, as Okuma lets the user set
    assert codec.encode_text("#1", 1) == bytes([0x0E, 0x01])
    assert codec.decode_byte(0x0E) == "#"
