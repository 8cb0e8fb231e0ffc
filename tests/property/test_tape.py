"""Properties of the tape engine: ISO -> EIA -> ISO is the identity, and the reader and the
punch receiver give only typed errors on any bytes."""

from __future__ import annotations

import contextlib
from pathlib import Path
from tempfile import TemporaryDirectory

from hypothesis import given, settings
from hypothesis import strategies as st

from opendnc.errors import DncError
from opendnc.tape.codes import EIA_TABLE, Code, Codec, Eob, eia_to_iso, iso_to_eia
from opendnc.tape.feed import program_wire
from opendnc.tape.profiles import PROFILES
from opendnc.tape.reader import ReaderConfig, TapeReader
from opendnc.tape.session import PunchReceiver

# NC text EIA can carry: its characters and line ends ("%" is ER)
EIA_TEXT = st.text(alphabet=[*sorted(set(EIA_TABLE)), "\n"], max_size=300)
# NC program lines as the NC-text guard lets them through (upper case outside comments)
BLOCK = st.text(alphabet="GMXYZFNOST0123456789.-+ #=[]*/", max_size=30).map(str.strip)
COMMENT = st.text(alphabet="ABCxyz 0123456789.,-", max_size=12).map(lambda c: f"({c})")
LINE = st.one_of(BLOCK, st.tuples(BLOCK, COMMENT).map(" ".join))


@settings(max_examples=100, deadline=None)
@given(EIA_TEXT)
def test_iso_eia_iso_is_the_identity(text: str) -> None:
    assert eia_to_iso(iso_to_eia(text)) == text


@settings(max_examples=80, deadline=None)
@given(st.binary(max_size=400), st.sampled_from(sorted(PROFILES)), st.booleans())
def test_reader_gives_only_typed_errors(data: bytes, name: str, tv: bool) -> None:
    profile = PROFILES[name]
    for code in (Code.ISO, Code.EIA):
        codec = Codec(code, parity=profile.software_parity and code is Code.ISO)
        reader = TapeReader(ReaderConfig(codec=codec, tv_check=tv, max_block=64))
        try:
            reader.feed(data)
            reader.quiet()
            reader.text()
        except DncError:
            pass


@settings(max_examples=80, deadline=None)
@given(st.lists(st.binary(max_size=60), max_size=8), st.sampled_from(sorted(PROFILES)))
def test_punch_receiver_gives_only_typed_errors(pieces: list[bytes], name: str) -> None:
    receiver = PunchReceiver(PROFILES[name], start_timeout=1.0, quiet=1.0)
    try:
        for piece in pieces:
            receiver.receive_data(piece)
        receiver.timed_out()
        if receiver.finished:
            receiver.result()
    except DncError:
        pass


# bytes a noisy line or a feeding control sends: NUL, DEL (with and without parity), DC codes
MAX_BYTES = 200
FILLER = st.lists(
    st.sampled_from([b"\0", b"\x7f", b"\xff", b"\x11", b"\x13", b"\x93"]),
    min_size=MAX_BYTES + 1,
    max_size=2 * MAX_BYTES,
)


@settings(max_examples=60, deadline=None)
@given(
    st.one_of(
        st.binary(min_size=MAX_BYTES + 1, max_size=600),
        st.tuples(st.binary(max_size=40), FILLER).map(
            lambda parts: b"\x12%\n" + parts[0] + b"".join(parts[1])
        ),
    ),
    st.sampled_from(list(Code)),
    st.integers(1, 64),
)
def test_a_stream_longer_than_max_bytes_ends(data: bytes, code: Code, chunk: int) -> None:
    """More than ``max_bytes`` bytes never keep a record open: it ended within them, or a
    typed error."""
    reader = TapeReader(
        ReaderConfig(codec=Codec(code, parity=code is Code.ISO), max_bytes=MAX_BYTES)
    )
    try:
        for start in range(0, len(data), chunk):
            reader.feed(data[start : start + chunk])
    except DncError:
        return
    assert reader.ended is not None
    assert reader.received <= MAX_BYTES


@settings(max_examples=40, deadline=None)
@given(
    st.lists(LINE, min_size=1, max_size=12),
    st.sampled_from(sorted(PROFILES)),
    st.sampled_from(list(Eob)),
)
def test_a_program_reads_back_as_sent(lines: list[str], name: str, eob: Eob) -> None:
    """Every profile: our wire bytes of a program, read by the reader, give its text back."""
    profile = PROFILES[name].with_changes(eob=eob)
    body = [line for line in lines if line and line != "%"]
    text = "%\nO0001 (P)\n" + "".join(f"{line}\n" for line in body) + "M30\n%\n"
    with TemporaryDirectory() as folder:
        path = Path(folder) / "O0001.nc"
        path.write_text(text)
        wire = program_wire(path, profile)
    eof = None if profile.eof_byte is None else chr(profile.eof_byte)
    reader = TapeReader(
        ReaderConfig(codec=profile.codec(), end_at_percent=profile.end_at_percent, eof_char=eof)
    )
    reader.feed(wire)
    reader.quiet()
    program = reader.program
    content = ["O0001 (P)", *body, "M30"]
    heads = {
        "percent": ["%"],
        "okuma": ["%"],
        "siemens": ["%_N_O0001_MPF", ";$PATH=/_N_MPF_DIR"],
        "fagor": ["%O0001,MX,"],
    }
    head = heads[profile.framing.value]
    tail = ["%"] if profile.end_at_percent else []
    assert program == head + content + tail
    assert reader.label == (["$O0001.MIN"] if profile.framing.value == "okuma" else [])


@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=300), st.sampled_from(sorted(PROFILES)), st.sampled_from(list(Code)))
def test_any_file_is_framed_or_refused_with_a_typed_error(
    data: bytes, name: str, code: Code
) -> None:
    profile = PROFILES[name].with_changes(line="8N2") if code is Code.EIA else PROFILES[name]
    profile = profile.with_changes(code=code)
    with TemporaryDirectory() as folder:
        path = Path(folder) / "O0001.nc"
        path.write_bytes(data)
        with contextlib.suppress(DncError):
            program_wire(path, profile)
