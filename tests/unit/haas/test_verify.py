"""The end-to-end checks of docs/xmodem.md#end-to-end-checks: punch-back comparison and the
program check line (pure functions; the wire runs are in tests/sim/haas_serial and
tests/interop)."""

from __future__ import annotations

import zlib

from hypothesis import given
from hypothesis import strategies as st

from opendnc.haas.verify import (
    CheckState,
    ProgramMismatch,
    add_check_line,
    check_line,
    compare,
    program_lines,
)

SENT = b"%\nO01000 (FIRST)\nG00 G90 X0. Y0.\nG01 X-2.3600 F20.\nM30\n%\n"
# what a Haas punches with Setting 25 = CR LF: LF before %, empty line before %, SUB padding
PUNCHED = (
    b"\x00\x00\r\n%\r\nO01000 (FIRST)\r\nG00 G90 X0. Y0.\r\nG01 X-2.3600 F20.\r\nM30\r\n\r\n%\r\n"
    + b"\x1a" * 40
)


def test_framing_and_line_ends_do_not_count() -> None:
    result = compare(SENT, PUNCHED)
    assert result.verified
    assert result.lines == 4
    assert result.program == "O01000"
    lines = ["O01000 (FIRST)", "G00 G90 X0. Y0.", "G01 X-2.3600 F20.", "M30"]
    assert program_lines(PUNCHED) == lines


def test_the_issue_change_is_found_with_its_line() -> None:
    result = compare(SENT, PUNCHED.replace(b"X-2.3600", b"X-2.2600"))
    assert not result.verified
    assert result.difference is not None
    assert (result.difference.line, result.difference.sent, result.difference.punched) == (
        3,
        "G01 X-2.3600 F20.",
        "G01 X-2.2600 F20.",
    )
    assert str(ProgramMismatch(result, "O01000")) == (
        "O01000 on the control differs at line 3: "
        "sent 'G01 X-2.3600 F20.', punched 'G01 X-2.2600 F20.'"
    )


def test_a_missing_or_extra_line_is_a_difference() -> None:
    short = compare(SENT, PUNCHED.replace(b"M30\r\n", b""))
    assert short.difference is not None
    assert (short.difference.line, short.difference.punched) == (4, None)
    longer = compare(SENT, PUNCHED.replace(b"M30\r\n", b"M30\r\nM30\r\n"))
    assert longer.difference is not None
    assert (longer.difference.line, longer.difference.sent) == (5, None)


def test_spaces_count_unless_setting_41_is_declared() -> None:
    spaced = PUNCHED.replace(b"G00 G90", b"G00  G90")
    assert not compare(SENT, spaced).verified
    assert compare(SENT, spaced, ignore_spaces=True).verified


def test_check_line_is_a_crc32_of_the_text_without_blanks() -> None:
    marked = add_check_line(SENT)
    lines = marked.split(b"\n")
    assert lines[1] == b"O01000 (FIRST)"  # the check line follows the O line
    text = b"\n".join(line.replace(b" ", b"") for line in SENT.split(b"\n")[1:5])
    assert lines[2] == f"(ODNC CRC32 {zlib.crc32(text):08X})".encode()
    assert check_line(marked).state == CheckState.OK
    # the control's framing, CR LF and the spaces Setting 41 adds keep it valid
    punched = b"\r\n" + marked.replace(b"\n", b"\r\n").replace(b"G00 G90", b"G00  G90") + b"\x1a"
    assert check_line(punched).ok
    # the change of the issue breaks it
    damaged = check_line(marked.replace(b"X-2.3600", b"X-2.2600"))
    assert damaged.state == CheckState.MISMATCH
    assert damaged.line == 2
    assert check_line(SENT).state == CheckState.MISSING


def test_a_check_line_with_a_damaged_marker_or_digits_is_a_mismatch() -> None:
    marked = add_check_line(SENT)
    assert check_line(marked.replace(b"(ODNC", b"(OENC")).state == CheckState.MISMATCH
    assert check_line(marked.replace(b"CRC32 ", b"CRC32 Z")).state == CheckState.MISMATCH
    # adding again replaces the old line instead of stacking a second
    again = add_check_line(add_check_line(SENT.replace(b"F20.", b"F30.")))
    assert again.count(b"(ODNC CRC32") == 1
    assert check_line(again).ok


def test_a_users_own_comment_is_kept() -> None:
    program = SENT.replace(b"M30", b"(CRC32 OF THE FIXTURE IS NOTED)\nM30")
    assert b"(CRC32 OF THE FIXTURE IS NOTED)" in add_check_line(program)
    assert check_line(add_check_line(program)).ok


LINE = st.text(alphabet="GXYZFMST0123456789.- ()", min_size=1, max_size=30).filter(
    lambda s: s.strip() not in ("", "%") and "ODNC" not in s
)


@given(st.lists(LINE, min_size=1, max_size=40), st.sampled_from([b"\n", b"\r\n", b"\r"]))
def test_any_program_checks_ok_after_add_and_a_one_byte_change_is_seen(
    lines: list[str], eol: bytes
) -> None:
    program = eol.join([b"%", b"O01234", *(line.encode() for line in lines), b"%", b""])
    marked = add_check_line(program)
    assert check_line(marked).ok
    assert compare(program, marked.replace(marked.split(eol)[2] + eol, b"")).verified
    # change one digit outside the check line: the sum sees it
    body = marked.split(eol)
    for index in range(3, len(body)):
        line = body[index]
        digits = [i for i, c in enumerate(line) if 0x30 <= c <= 0x38]
        if digits:
            i = digits[0]
            body[index] = line[:i] + bytes([line[i] + 1]) + line[i + 1 :]
            assert check_line(eol.join(body)).state == CheckState.MISMATCH
            break


@given(st.binary(max_size=600))
def test_any_bytes_give_a_typed_answer(data: bytes) -> None:
    assert check_line(data).state in (CheckState.OK, CheckState.MISSING, CheckState.MISMATCH)
    assert isinstance(compare(data, data).verified, bool)
    assert compare(data, data).verified
    assert check_line(add_check_line(data)).state in (CheckState.OK, CheckState.MISMATCH)
