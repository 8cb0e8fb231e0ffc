"""The text-punch capture: start and end triggers, leader noise, chunks split anywhere."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from opendnc.errors import InputError
from opendnc.haas.textpunch import TextCapture
from opendnc.xmodem.haas import Eob

PUNCH = b"\0\0\0\x12%\r\nO01234 (TEXT)\r\nG00 X1.\r\nM30\r\n%\r\n\x14\0\0\0"


def _feed(capture: TextCapture, data: bytes, cuts: list[int]) -> None:
    last = 0
    for cut in sorted(c % (len(data) + 1) for c in cuts):
        capture.feed(data[last:cut])
        last = cut
    capture.feed(data[last:])


def test_a_punch_with_leader_and_punch_codes_is_captured_between_its_percent_lines() -> None:
    capture = TextCapture(eob=Eob.CRLF)
    capture.feed(PUNCH)
    assert capture.done
    assert not capture.failed
    assert capture.program() == b"%\nO01234 (TEXT)\nG00 X1.\nM30\n%\n"


def test_a_percent_leader_does_not_end_an_empty_capture() -> None:
    capture = TextCapture(eob=Eob.LF)
    capture.feed(b"%%%%%%\n%\nO1\nM30\n%\n%%%%%%")
    assert capture.done
    assert capture.program() == b"%%%%%%\n%\nO1\nM30\n%\n"


def test_other_triggers_and_none() -> None:
    capture = TextCapture(start=b"O", end=b"M30", eob=Eob.CR)
    capture.feed(b"junk before\rO7\rG01 X1.\rM30\r%\r")
    assert capture.done
    assert capture.program() == b"O7\nG01 X1.\nM30\n"
    open_ended = TextCapture(start=b"", end=b"", eob=Eob.LF)
    open_ended.feed(b"\0\0\n O9\nM30\n")
    assert not open_ended.done
    open_ended.quiet(2.0)
    assert (open_ended.done, open_ended.failed) == (True, "")
    assert open_ended.program() == b"O9\nM30\n"


def test_a_punch_that_stops_before_its_end_trigger_fails_with_the_reason() -> None:
    capture = TextCapture(eob=Eob.LF)
    capture.feed(b"%\nO6\nG01 X2.")
    capture.quiet(1.5)
    assert capture.done
    assert capture.failed == (
        "no end trigger '%' within 1.5 s of the last character (the punch stopped after 12 bytes)"
    )
    assert capture.program() == b"%\nO6\nG01 X2.\n"


def test_quiet_before_anything_started_changes_nothing() -> None:
    capture = TextCapture()
    capture.feed(b"\0\0 no trigger here")
    capture.quiet(1.0)
    assert (capture.started, capture.done) == (False, False)


def test_a_trigger_made_of_dropped_bytes_is_refused() -> None:
    with pytest.raises(InputError, match="trigger"):
        TextCapture(start=b"\x12")


@given(
    lines=st.lists(
        st.text(alphabet="GMXYZ0123456789. ()", min_size=1, max_size=20).filter(
            lambda s: s.strip() != ""
        ),
        min_size=1,
        max_size=8,
    ),
    leader=st.binary(max_size=8).map(lambda b: bytes(c % 2 * 0x7F for c in b)),
    noise=st.sampled_from([b"", b"\x11", b"\x13\x11", b"\0"]),
    eob=st.sampled_from(list(Eob)),
    cuts=st.lists(st.integers(min_value=0, max_value=500), max_size=6),
)
def test_any_split_of_a_punch_captures_the_same_program(
    lines: list[str], leader: bytes, noise: bytes, eob: Eob, cuts: list[int]
) -> None:
    body = [line.strip().encode() for line in lines]
    wire = leader + b"%" + eob.wire + noise.join(line + eob.wire for line in body)
    wire += b"%" + eob.wire + leader
    capture = TextCapture(eob=eob)
    _feed(capture, wire, cuts)
    assert capture.done
    assert not capture.failed
    assert capture.program() == b"%\n" + b"".join(line + b"\n" for line in body) + b"%\n"
