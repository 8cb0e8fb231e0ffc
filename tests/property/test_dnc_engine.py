"""Property test: the drip-feed engine under any interleaving of control bytes and time."""

from __future__ import annotations

from pathlib import Path
from tempfile import TemporaryDirectory

from hypothesis import given, settings
from hypothesis import strategies as st

from opendnc.haas.dnc_engine import (
    XOFF,
    XON,
    DncConfig,
    DncRun,
    Drain,
    Finish,
    ProgramFeed,
    Send,
    Wait,
)

lines = st.lists(
    st.text(alphabet="GMXYZF0123456789. #=[]*", min_size=0, max_size=40), min_size=0, max_size=40
)
# what the control sends between two steps, and how long that takes
control = st.tuples(
    st.sampled_from([b"", b"", bytes([XOFF]), bytes([XON]), bytes([XOFF, XON]), b"\x15"]),
    st.sampled_from([0.0, 0.01, 0.3]),
)


@settings(max_examples=150, deadline=None)
@given(lines, st.integers(1, 64), st.lists(control, max_size=400))
def test_engine_sends_the_whole_program_once_and_never_while_paused(
    program: list[str], chunk: int, script: list[tuple[bytes, float]]
) -> None:
    with TemporaryDirectory() as tmp:
        path = Path(tmp) / "p.nc"
        path.write_text("\n".join(program) + "\n", encoding="latin-1")
        expected_feed = ProgramFeed(path)
        try:
            expected = b"".join(expected_feed)
        finally:
            expected_feed.close()
        now = [0.0]
        feed = ProgramFeed(path)
        config = DncConfig(chunk=chunk, xoff_timeout=1000.0, linger=0.25)
        run = DncRun(feed, config, clock=lambda: now[0])
        sent = bytearray()
        steps = iter(script)
        try:
            for _ in range(100_000):
                data, seconds = next(steps, (bytes([XON]), 0.3))  # then: resume, let time pass
                run.incoming(data)
                now[0] += seconds
                step = run.next_step()
                if isinstance(step, Send):
                    assert not run.streamer.paused  # no byte goes out after a DC3
                    assert 0 < len(step.data) <= chunk
                    sent += step.data
                elif isinstance(step, Wait):
                    assert 0 < step.seconds <= 0.25
                elif isinstance(step, Finish):
                    break
                else:
                    assert isinstance(step, Drain)
                    assert bytes(sent) == expected  # drained only once all was handed out
            else:
                raise AssertionError("the run never finished")
        finally:
            feed.close()
        assert bytes(sent) == expected
        report = run.report()
        assert report.bytes_sent == len(expected)
