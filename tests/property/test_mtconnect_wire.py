"""Property tests of the MTConnect client's wire parsers: whatever an agent (or anything
answering in its place) sends, the parsers return typed data or raise a DncError, and a valid
stream cut anywhere gives the same documents; a device's part count is the agent's count
however often observations are resent."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from tests.peers import require_module

require_module("lxml")

from opendnc.errors import DncError, RemoteProtocolError  # noqa: E402
from opendnc.mtconnect.device_state import DeviceState  # noqa: E402
from opendnc.mtconnect.documents import (  # noqa: E402
    AgentRefused,
    Devices,
    Streams,
    parse_devices,
    parse_document,
    parse_streams,
)
from opendnc.mtconnect.multipart import MultipartSplitter  # noqa: E402
from tests.unit.test_mtconnect_documents import CURRENT, PROBE, event, streams  # noqa: E402

SAMPLES = [PROBE, CURRENT, streams(17, 1, 41, event("PartCount", "pc", 40, "9"))]


@settings(max_examples=150, deadline=None)
@given(st.binary(max_size=2000))
def test_any_bytes_are_a_document_or_a_typed_error(data: bytes) -> None:
    try:
        document = parse_document(data)
    except (RemoteProtocolError, AgentRefused):
        return
    assert isinstance(document, Devices | Streams)


@settings(max_examples=150, deadline=None)
@given(
    st.sampled_from(SAMPLES),
    st.lists(st.tuples(st.integers(0, 5000), st.binary(min_size=0, max_size=8)), max_size=6),
    st.integers(0, 6000),
)
def test_damaged_documents_are_typed_errors(
    sample: bytes, edits: list[tuple[int, bytes]], cut: int
) -> None:
    data = bytearray(sample[: max(cut, 1)] if cut < len(sample) else sample)
    for at, junk in edits:
        at %= len(data) + 1
        data[at : at + len(junk)] = junk
    try:
        document = parse_document(bytes(data))
    except DncError:
        return
    if isinstance(document, Streams):
        for observation in document.observations:
            assert observation.sequence >= 0


@settings(max_examples=150, deadline=None)
@given(st.binary(max_size=600), st.lists(st.integers(1, 64), min_size=1, max_size=40))
def test_any_multipart_bytes_are_parts_or_a_typed_error(data: bytes, sizes: list[int]) -> None:
    splitter = MultipartSplitter("bnd")
    at = 0
    try:
        for size in sizes * 20:
            if at >= len(data):
                break
            for part in splitter.feed(data[at : at + size]):
                assert isinstance(part, bytes)
            at += size
    except RemoteProtocolError:
        pass


@settings(max_examples=80, deadline=None)
@given(
    st.lists(st.binary(max_size=200), min_size=1, max_size=5),
    st.lists(st.integers(1, 97), min_size=1, max_size=30),
)
def test_a_valid_stream_cut_anywhere_gives_its_documents(
    documents: list[bytes], sizes: list[int]
) -> None:
    wire = b"".join(
        b"--bnd\r\nContent-type: text/xml\r\nContent-length: %d\r\n\r\n%s\r\n" % (len(d), d)
        for d in documents
    )
    splitter = MultipartSplitter("bnd")
    got: list[bytes] = []
    at, turn = 0, 0
    while at < len(wire):
        size = sizes[turn % len(sizes)]
        got += splitter.feed(wire[at : at + size])
        at, turn = at + size, turn + 1
    assert got == documents


@settings(max_examples=80, deadline=None)
@given(
    st.lists(st.integers(0, 10_000), min_size=1, max_size=20),
    st.lists(st.integers(0, 19), max_size=20),
)
def test_the_part_count_is_the_agents_however_often_resent(
    counts: list[int], resend: list[int]
) -> None:
    # the agent's PartCount observations, in order; some documents arrive again later
    state = DeviceState(parse_devices(PROBE), "mill-7")
    state.load(parse_streams(CURRENT))
    sent = [
        parse_streams(streams(17, 1, 41 + i, event("PartCount", "pc", 40 + i, str(count))))
        for i, count in enumerate(counts)
    ]
    for i, document in enumerate(sent):
        state.update(document)
        for again in resend:
            if again <= i:
                state.update(sent[again])
    assert state.snapshot().part_count == counts[-1]
