"""Property tests: MDC request/reply parsers and framers, fed random and near-valid bytes."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from opendnc.errors import PeerClosed, RemoteProtocolError
from opendnc.haas import mdc

names = st.sampled_from([name for name, _ in mdc.QUERIES.values()] + ["MACRO", "STATUS", "X"])
field_text = st.text(alphabet="0123456789.:-() ABCDEOM#", max_size=12)


@st.composite
def near_valid_reply(draw: st.DrawFn) -> bytes:
    payload = draw(names) + "".join(", " + draw(field_text) for _ in range(draw(st.integers(0, 5))))
    control = draw(st.sampled_from(list(mdc.ControlType)))
    wire = bytearray(mdc.frame_reply(payload, control))
    if draw(st.booleans()) and wire:
        wire[draw(st.integers(0, len(wire) - 1))] ^= draw(st.integers(1, 255))
    return bytes(wire)


typed_replies = st.one_of(
    st.builds(
        mdc.TextValue,
        st.sampled_from(["SERIAL NUMBER", "MODEL", "SOFTWARE VERSION"]),
        st.from_regex(r"[A-Z0-9.\-]{1,12}", fullmatch=True),
    ),
    st.builds(mdc.Mode, st.sampled_from(["MDI", "MEM", "ZERO", "LIST PROG"]), st.booleans()),
    st.builds(
        mdc.Count,
        st.sampled_from(["TOOL CHANGES", "USING TOOL", "M30 #1", "M30 #2"]),
        st.integers(0, 10**6),
    ),
    st.builds(
        mdc.Duration,
        st.sampled_from(["P.O. TIME", "C.S. TIME", "LAST CYCLE"]),
        st.integers(0, 99999 * 3600),
    ),
    st.builds(
        mdc.ProgramStatus,
        st.sampled_from(["MDI", "O00123", "O5"]),
        st.sampled_from(["IDLE", "FEED HOLD", "ALARM ON"]),
        st.integers(0, 10**6),
    ),
    st.just(mdc.Busy()),
    st.builds(mdc.MacroValue, st.integers(-(10**6), 10**6).map(lambda n: n / 1000)),
    st.just(mdc.WriteAccepted()),
    st.just(mdc.Refused("?")),
)


@given(
    st.lists(typed_replies, max_size=6),
    st.sampled_from(list(mdc.ControlType)),
    st.lists(st.integers(1, 30), max_size=30),
)
def test_reply_roundtrip_through_any_cuts(
    replies: list[mdc.Reply], control: mdc.ControlType, cuts: list[int]
) -> None:
    wire = b"".join(mdc.frame_reply(r.to_payload(), control) for r in replies)
    framer = mdc.ReplyFramer()
    got: list[mdc.Reply] = []
    pos = 0
    for cut in [*cuts, len(wire)]:
        framer.feed(wire[pos : pos + cut])
        pos += cut
        while (payload := framer.next_payload()) is not None:
            got.append(mdc.parse_reply(payload))
    assert got == replies


@given(st.one_of(near_valid_reply(), st.binary(max_size=200)))
def test_reply_side_only_raises_protocol_errors(wire: bytes) -> None:
    conn = mdc.MdcConnection()
    conn.send(mdc.Query(100))
    try:
        conn.receive_data(wire)
        conn.receive_data(b"")
        while conn.next_event() is not None:
            conn.reset()
            conn.send(mdc.Query(500))
    except (RemoteProtocolError, PeerClosed):
        pass


@given(st.text(max_size=40))
def test_request_parser_never_fails(line: str) -> None:
    request = mdc.parse_request(line)
    if not isinstance(request, mdc.UnknownRequest):
        assert mdc.parse_request(mdc.encode_request(request).decode().strip()) == request


requests = st.one_of(
    st.builds(mdc.Query, st.sampled_from(sorted(mdc.QUERIES))),
    st.builds(mdc.MacroRead, st.integers(0, 99999)),
    st.builds(
        mdc.MacroWrite, st.integers(1, 99999), st.integers(-(10**6), 10**6).map(lambda n: n / 64)
    ),
)


@given(requests)
def test_request_roundtrip(request: mdc.Request) -> None:
    framer = mdc.LineFramer()
    framer.feed(mdc.encode_request(request))
    line = framer.next_line()
    assert line is not None
    assert mdc.parse_request(line) == request


@given(st.binary(max_size=3000))
def test_line_framer_only_protocol_errors(data: bytes) -> None:
    framer = mdc.LineFramer()
    try:
        framer.feed(data)
    except RemoteProtocolError:
        return
    while (line := framer.next_line()) is not None:
        mdc.parse_request(line)
