"""Hypothesis properties of PARMRK decoding (docs/lsv2-serial.md, "Parity errors")."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from opendnc.sim.cable.noise import UartInput, uart_input
from opendnc.transport.marks import MarkDecoder


@st.composite
def marked(draw: st.DrawFn) -> tuple[bytes, list[int], list[int]]:
    # 0xFF and 0x00 often: they are what the marks are made of
    data = draw(st.binary(max_size=300).map(lambda b: bytes(0xFF if c % 5 == 0 else c for c in b)))
    bad = sorted(draw(st.sets(st.integers(0, max(len(data) - 1, 0)), max_size=20)))
    bad = [i for i in bad if i < len(data)]
    cuts = sorted(draw(st.lists(st.integers(0, 2 * len(data) + 1), max_size=30)))
    return data, bad, cuts


@settings(max_examples=400, deadline=None)
@given(marked())
def test_decoding_the_marked_form_gives_back_data_and_errors(
    case: tuple[bytes, list[int], list[int]],
) -> None:
    data, bad, cuts = case
    wire = uart_input(data, bad, UartInput.MARK)
    decoder = MarkDecoder()
    out = bytearray()
    errors: list[int] = []
    last = 0
    for cut in [*cuts, len(wire)]:
        cut = min(cut, len(wire))
        if cut < last:
            continue
        got = decoder.decode(wire[last:cut])
        errors += [len(out) + i for i in got.errors]
        out += got.data
        last = cut
    assert bytes(out) == data
    assert errors == bad
    assert decoder.marked == len(bad)


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=200))
def test_decoder_never_raises_on_arbitrary_input(raw: bytes) -> None:
    decoder = MarkDecoder()
    got = decoder.decode(raw)
    assert all(0 <= i < len(got.data) for i in got.errors)
