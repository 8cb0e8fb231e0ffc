"""Property tests: DPRNT formatter, statement parser, line framer and line parser."""

from __future__ import annotations

import contextlib
import itertools
import math

from hypothesis import assume, given
from hypothesis import strategies as st

from opendnc.errors import InputError
from opendnc.haas import dprnt

formats = st.tuples(st.integers(0, 8), st.integers(0, 8)).filter(lambda f: 1 <= sum(f) <= 8)
values = st.floats(min_value=-1e12, max_value=1e12, allow_nan=False)


@given(values, formats)
def test_format_value_rules(value: float, fmt: tuple[int, int]) -> None:
    whole, frac = fmt
    text = dprnt.format_value(value, whole, frac)
    assert len(text) >= max(whole, 1) + (frac + 1 if frac else 0)
    if frac:
        assert len(text.split(".")[1]) == frac  # trailing zeros kept
        assert abs(float(text) - value) <= 0.5 * 10**-frac + 1e-9 * max(1.0, abs(value))
    else:
        assert "." not in text
        assert float(text) == math.trunc(value)  # truncated, never rounded up
    assert text.lstrip(" ") == text.strip()  # padding only on the left


@given(st.one_of(st.floats(), st.none()), st.integers(-2, 10), st.integers(-2, 10))
def test_format_value_only_input_errors(value: float | None, whole: int, frac: int) -> None:
    with contextlib.suppress(InputError):
        dprnt.format_value(value, whole, frac)


@given(st.text(max_size=60))
def test_statement_parser_only_input_errors(body: str) -> None:
    try:
        items = dprnt.parse_statement(f"DPRNT[{body}]")
    except InputError:
        return
    dprnt.render(items, lambda n: 1.25)


text_item = st.text(
    alphabet=st.characters(whitelist_categories=("Lu", "Nd"), whitelist_characters="+-/ "),
    min_size=1,
    max_size=10,
)
var_item = st.builds(lambda n, f: dprnt.Variable(n, *f), st.integers(1, 99999), formats)


@given(st.lists(st.one_of(text_item.map(dprnt.Text), var_item), max_size=6))
def test_statement_roundtrip(items: list[dprnt.Item]) -> None:
    merged: list[dprnt.Item] = []
    for item in items:  # adjacent text items read back as one
        if merged and isinstance(item, dprnt.Text) and isinstance(merged[-1], dprnt.Text):
            merged[-1] = dprnt.Text(merged[-1].text + item.text)
        else:
            merged.append(item)
    source = "".join(
        i.text.replace(" ", "*") if isinstance(i, dprnt.Text) else f"#{i.number}[{i.whole}{i.frac}]"
        for i in merged
    )
    assert dprnt.parse_statement(f"DPRNT[{source}]") == tuple(merged)


def _feed_in_pieces(framer: dprnt.DprntLineFramer, data: bytes, cuts: list[int]) -> None:
    pos = 0
    for cut in cuts:
        framer.feed(data[pos : pos + cut])
        pos += cut
    framer.feed(data[pos:])


@given(st.binary(max_size=300), st.lists(st.integers(0, 50), max_size=20))
def test_framer_any_bytes_any_slicing(data: bytes, cuts: list[int]) -> None:
    """Any bytes are legal input (feed never raises), and how they were cut into reads
    changes nothing."""
    whole = dprnt.DprntLineFramer(max_line=16)
    sliced = dprnt.DprntLineFramer(max_line=16)
    whole.feed(data)
    _feed_in_pieces(sliced, data, cuts)
    events = list(whole.events())
    assert list(sliced.events()) == events
    assert sliced.end_of_stream() == whole.end_of_stream()
    for event in events:
        if isinstance(event, dprnt.FramedLine):
            assert len(event.text) <= 16
            assert "\r" not in event.text
            assert "\n" not in event.text
            assert event.complete
        else:
            assert event.length > 16


# the bytes the framer drops, written out: NUL, DC1-DC4, NAK, CAN, SUB
line_text = st.binary(max_size=40).map(
    lambda b: b.translate(None, b"\r\n\x00\x11\x12\x13\x14\x15\x18\x1a")
)


@given(
    st.lists(st.tuples(line_text, st.sampled_from([b"\r", b"\n", b"\r\n"])), max_size=12),
    line_text,
    st.lists(st.integers(0, 60), max_size=20),
)
def test_framer_against_model(
    lines: list[tuple[bytes, bytes]], tail: bytes, cuts: list[int]
) -> None:
    """Lines up to the limit come out as lines, longer ones as one DroppedLine each, in order;
    an unterminated tail comes out of end_of_stream marked as cut (or dropped)."""
    limit = 20
    for (_, end), (text, nxt) in itertools.pairwise(lines):
        # a lone CR followed by an empty LF-ended line is one CR LF line end on the wire
        assume(not (end == b"\r" and not text and nxt.startswith(b"\n")))
    data = b"".join(text + end for text, end in lines) + tail
    framer = dprnt.DprntLineFramer(max_line=limit)
    _feed_in_pieces(framer, data, cuts)
    expected = [
        dprnt.FramedLine(t.decode("latin-1")) if len(t) <= limit else dprnt.DroppedLine(len(t))
        for t, _ in lines
    ]
    assert list(framer.events()) == expected
    last = framer.end_of_stream()
    if not tail:
        assert last is None
    elif len(tail) <= limit:
        assert last == dprnt.FramedLine(tail.decode("latin-1"), complete=False)
    else:
        assert last == dprnt.DroppedLine(len(tail), complete=False)


@given(st.one_of(st.text(max_size=120), st.integers(300, 400).map(lambda n: "Z" + "9" * n)))
def test_parse_line_never_fails(text: str) -> None:
    parsed = dprnt.parse_line(text)
    assert all(math.isfinite(v) for v in parsed.numbers)
    assert parsed.text == text


@given(
    st.lists(st.tuples(st.sampled_from(["X", "Y", "Z", "DIA", ""]), values, formats), max_size=5)
)
def test_formatted_values_parse_back(fields: list[tuple[str, float, tuple[int, int]]]) -> None:
    line = " ".join(f"{label}{dprnt.format_value(v, *fmt)}" for label, v, fmt in fields)
    parsed = dprnt.parse_line(line)
    assert len(parsed.fields) == len(fields)
    for got, (label, value, (whole, frac)) in zip(parsed.fields, fields, strict=True):
        assert got.label == label
        assert got.value == float(dprnt.format_value(value, whole, frac))
