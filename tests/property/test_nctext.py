"""Hypothesis: the NC text scanner agrees with a plain byte-by-byte reading of the rules,
whatever the input and however it is cut into pieces; it never raises anything untyped."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from opendnc.errors import ProgramTextError
from opendnc.nctext import TAPE_CODES, TextProblem, TextScanner, check_program, find_problem

BLANK = set(b"\t\n\r ")


def reference(data: bytes) -> tuple[int, int, int] | None:
    """(offset, line, column) of the first problem, read one byte at a time."""
    edge = BLANK | TAPE_CODES
    start = 0
    while start < len(data) and data[start] in edge:
        start += 1
    end = len(data)
    while end > start and data[end - 1] in edge:
        end -= 1
    in_comment = False
    for i in range(start, end):
        byte = data[i]
        if byte in (0x0A, 0x0D):
            in_comment = False
        ok = byte in (0x09, 0x0A, 0x0D) or 0x20 <= byte <= 0x7E
        if ok and not in_comment and 0x61 <= byte <= 0x7A:
            ok = False
        if not ok:
            head = data[:i]
            crlf = head.count(b"\r\n")
            line = head.count(b"\n") + head.count(b"\r") - crlf + 1
            last = max(head.rfind(b"\n"), head.rfind(b"\r"))
            return i, line, i - last
        if byte == 0x28:
            in_comment = True
        elif byte == 0x29:
            in_comment = False
    return None


ALPHABET = st.sampled_from(
    [*b"G01XYZF.-( )%\n\r\t;#[]=", *b"gxq", 0x00, 0x02, 0x12, 0x14, 0x1A, 0x7F, 0x80, 0xB3]
)
PROGRAMS = st.lists(ALPHABET, max_size=120).map(bytes) | st.binary(max_size=120)


def fed(data: bytes, cuts: list[int]) -> TextProblem | None:
    scanner = TextScanner()
    pos = 0
    for cut in cuts:
        scanner.feed(data[pos : pos + cut])
        pos += cut
    scanner.feed(data[pos:])
    return scanner.finish()


@settings(max_examples=600, deadline=None)
@given(data=PROGRAMS, cuts=st.lists(st.integers(0, 30), max_size=8))
def test_scanner_matches_reference_in_any_pieces(data: bytes, cuts: list[int]) -> None:
    expected = reference(data)
    whole = find_problem(data)
    assert fed(data, cuts) == whole
    if expected is None:
        assert whole is None
        check_program(data)
    else:
        assert whole is not None
        assert (whole.offset, whole.line, whole.column) == expected
        assert whole.byte == data[whole.offset]
        with pytest.raises(ProgramTextError) as caught:
            check_program(data)
        assert caught.value.problem == whole


@settings(max_examples=200, deadline=None)
@given(
    lines=st.lists(st.text(alphabet="GMXYZF0123456789. ", max_size=30), max_size=20),
    eob=st.sampled_from(["\n", "\r\n", "\r"]),
)
def test_clean_programs_always_pass(lines: list[str], eob: str) -> None:
    text = ("%" + eob + eob.join(lines) + eob + "%" + eob).encode()
    assert find_problem(text) is None
    assert find_problem(b"\x12\x00" + text + b"\x14" + b"\x1a" * 10) is None
