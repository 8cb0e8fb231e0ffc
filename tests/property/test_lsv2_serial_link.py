"""Hypothesis properties of the serial LSV2 link engine under a faulty line.

Two engines talk through a simulated line (tests/unit/lsv2/serial_line.py) that loses,
duplicates and changes link characters at random. Whatever happens:

* the engines never raise (faults surface only as ``LinkFailed`` events with a typed error);
* the exchange ends: every request is answered, or the client reports a failure;
* nothing is delivered twice, out of order or altered: the control serves a prefix of the
  requests, each once, and the client gets the matching prefix of answers.

A changed character flips one bit; inside a block at most one character per 64 is changed or
lost, and never a NUL is lost: the XOR block check catches every single error in a block, but
not errors that cancel each other (docs/lsv2-serial.md, "What the block check cannot see").
Outside blocks every handshake character may be lost, repeated or changed.

With a port that marks parity errors (docs/lsv2-serial.md, "Parity errors") that limit goes:
``test_marked_errors_never_alter_a_telegram_however_many_per_block`` changes up to 15 % of all
characters, marked, blocks and handshake alike.
"""

from __future__ import annotations

import random

from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from opendnc.lsv2.serial_link import LinkTiming
from tests.unit.lsv2.serial_line import MARKED, Fault, exchange

TIMING = LinkTiming(time0=0.5, time1=0.5, time2=0.2)


def faulty(
    seed: int, drop: float, dup: float, flip: float, forged: list[int] | None = None
) -> Fault:
    """Random faults on one lane; the sent bytes are followed to know what is inside a frame.

    A flip that turns a DLE '0' into DLE '1' (they differ in one bit) is appended to ``forged``.
    """
    rng = random.Random(seed)
    state = {"since_flip": 64, "in_frame": False, "dle": False, "bcc_next": False, "prev": -1}

    def track(b: int) -> bool:
        """Update the frame tracker with sent byte ``b``; return whether it is a body byte."""
        if state["bcc_next"]:
            state["bcc_next"] = False
            state["in_frame"] = False
            return False
        if state["dle"]:
            state["dle"] = False
            if b == 0x02:
                state["in_frame"] = True
                return False
            if b == 0x03 and state["in_frame"]:
                state["bcc_next"] = True
            return False
        if b == 0x10:
            state["dle"] = True
            return False
        return bool(state["in_frame"])

    def fault(b: int) -> list[int]:
        body = track(b)
        after_dle = state["prev"] == 0x10 and not body
        state["prev"] = b
        state["since_flip"] += 1
        r = rng.random()
        if r < drop:
            if not body:
                return []
            # A lost NUL, or two lost equal bytes, inside one block leave the XOR check
            # unchanged: one fault per 64 characters at most, and no lost NULs
            # (docs/lsv2-serial.md "What the block check cannot see").
            if b == 0 or state["since_flip"] < 64:
                return [b]
            state["since_flip"] = 0
            return []
        if r < drop + dup:
            # A line cannot repeat one character; a doubled body byte would also be invisible
            # to XOR. Repeats of handshake characters model a gateway replaying a chunk.
            return [b] if body else [b, b]
        if r < drop + dup + flip and state["since_flip"] >= 64:
            state["since_flip"] = 0
            changed = b ^ (1 << rng.randrange(8))
            if forged is not None and after_dle and (b, changed) == (0x30, 0x31):
                forged.append(changed)
            return [changed]
        return [b]

    return fault


rates = st.floats(min_value=0.0, max_value=0.05)
payloads = st.lists(st.binary(max_size=40), min_size=1, max_size=12)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    requests=payloads,
    seed=st.integers(0, 2**32 - 1),
    drop=rates,
    dup=rates,
    flip=rates,
    retries=st.integers(1, 5),
    link_check=st.booleans(),
)
# A NAK with one bit changed reads ENQ (0x15 / 0x05): it was taken for the control moving on,
# the request was counted delivered and never served.
@example(
    requests=[
        b"\x00" * 10,
        b"",
        b"",
        b"",
        b"\x00" * 19,
        b"\x00" * 9,
        b"\x00" * 4,
        b"",
        b"",
        b"",
        b"\x00" * 2,
        b"",
    ],
    seed=1298188,
    drop=0.0,
    dup=0.0,
    flip=0.046875,
    retries=2,
    link_check=False,
)
# A repeated DLE before STX lost the block start; a payload 0x05 was then taken for ENQ and its
# DLE 0, changed to DLE 1, acknowledged a request the control never read.
@example(
    requests=[b"", b"", b"\x00", b"\x00", b"\x00\x00", b""],
    seed=438,
    drop=0.005859375,
    dup=0.046875,
    flip=0.03125,
    retries=4,
    link_check=False,
)
# A repeated ENQ is answered DLE 0 twice; the second one changed to DLE 1 acknowledges a block
# whose STX is lost: the line forged the acknowledgement (see the end of the test).
@example(
    requests=[b"\x00\x00", b""],
    seed=209319,
    drop=0.015625,
    dup=0.015625,
    flip=0.03125,
    retries=1,
    link_check=True,
)
def test_faulty_line_never_loses_duplicates_or_alters(
    requests: list[bytes],
    seed: int,
    drop: float,
    dup: float,
    flip: float,
    retries: int,
    link_check: bool,
) -> None:
    tagged = [i.to_bytes(2, "big") + r for i, r in enumerate(requests)]
    forged: list[int] = []
    out = exchange(
        tagged,
        up=faulty(seed, drop, dup, flip, forged),
        down=faulty(seed + 1, drop, dup, flip, forged),
        timing=TIMING,
        retries=retries,
        link_check=link_check,
        answer_timeout=30.0,
    )
    assert out.failure != "horizon"
    n = len(out.served)
    assert out.served == tagged[:n], "control served a repeat or an altered request"
    assert out.answers == tagged[: len(out.answers)], "client got a repeat or altered answer"
    if out.failure is None:
        assert out.answers == tagged
    elif out.failure == "answer timeout":
        # Never a stuck link: an answer is missing only because the control gave it up, or
        # because the line changed a DLE 0 into DLE 1 (one bit): LSV2 has no sequence numbers,
        # so the sender cannot tell that from the receiver's acknowledgement and counts a
        # telegram delivered that the receiver never read (docs/lsv2-serial.md, "What the
        # link cannot see"). Both engines are then idle; the client's own answer timeout
        # reports it, as here.
        assert out.control.stats.failures > 0 or forged, "stuck link"
        assert out.client.idle
        assert out.control.idle
    else:
        assert "serial LSV2 link" in out.failure


@settings(max_examples=60, deadline=None)
@given(requests=payloads, seed=st.integers(0, 2**32 - 1))
# A lost block end let the client's retry ENQ vanish into the control's block: the late NAK
# now gets the ENQ again at once instead of costing a try to LSV2TIME1.
@example(requests=[b"\x00\x00"], seed=1000000)
@example(
    requests=[
        b"\x00\x00",
        b"\x00\x10",
        b"\x00\x10",
        b"\x00\x10",
        b"",
        b"\x00",
        b"\x00\x10",
        b"\x00\x00\x00",
        b"\x00" * 5,
    ],
    seed=4010212,
)
def test_light_faults_with_default_retries_always_complete(
    requests: list[bytes], seed: int
) -> None:
    tagged = [i.to_bytes(2, "big") + r for i, r in enumerate(requests)]
    out = exchange(
        tagged,
        up=faulty(seed, 0.002, 0.002, 0.002),
        down=faulty(seed + 1, 0.002, 0.002, 0.002),
        timing=TIMING,
    )
    assert out.failure is None
    assert out.answers == tagged
    assert out.served == tagged


@settings(max_examples=200, deadline=None)
@given(data=st.binary(max_size=600), cuts=st.lists(st.integers(0, 600), max_size=8))
def test_random_bytes_never_raise(data: bytes, cuts: list[int]) -> None:
    from opendnc.lsv2.serial_link import LinkRole, SerialLink

    for role in LinkRole:
        link = SerialLink(role)
        link.check_link(0.0)
        last = 0
        t = 0.0
        for c in [*sorted({c % (len(data) + 1) for c in cuts}), len(data)]:
            t += 0.3
            link.receive_data(data[last:c], t)
            link.tick(t)
            last = c
        link.data_to_send()
        while link.next_event() is not None:
            pass


@settings(max_examples=100, deadline=None)
@given(
    requests=payloads,
    lost=st.lists(st.booleans(), min_size=1, max_size=12),
    doubled=st.lists(st.booleans(), min_size=1, max_size=12),
)
def test_doubled_enq_and_lost_ready_deliver_every_telegram_once(
    requests: list[bytes], lost: list[bool], doubled: list[bool]
) -> None:
    """An ENQ repeated because its DLE 0 was lost, or doubled on the line: the receiver
    answers every ENQ again and each telegram is taken exactly once, in order
    (docs/lsv2-serial.md, "A doubled ENQ")."""
    tagged = [i.to_bytes(2, "big") + r for i, r in enumerate(requests)]

    def doubling(pattern: list[bool]) -> Fault:
        # doubles handshake ENQs by the pattern, never a 0x05 inside a block
        state = {"count": 0, "frame": False, "dle": False, "bcc": False}

        def fault(b: int) -> list[int]:
            if state["bcc"]:
                state["bcc"] = state["frame"] = False
                return [b]
            if state["dle"]:
                state["dle"] = False
                if b == 0x02:
                    state["frame"] = True
                elif b == 0x03 and state["frame"]:
                    state["bcc"] = True
                return [b]
            if b == 0x10:
                state["dle"] = True
                return [b]
            if b != 0x05 or state["frame"]:
                return [b]
            state["count"] += 1
            return [b, b] if pattern[state["count"] % len(pattern)] else [b]

        return fault

    def losing_ready(pattern: list[bool]) -> Fault:
        # drops the '0' of DLE 0 by the pattern (the DLE alone is noise to the sender)
        state = {"dle": False, "count": 0}

        def fault(b: int) -> list[int]:
            after_dle, state["dle"] = state["dle"], b == 0x10 and not state["dle"]
            if after_dle and b == 0x30:
                state["count"] += 1
                if pattern[state["count"] % len(pattern)] and state["count"] % 3:
                    return []
            return [b]

        return fault

    out = exchange(
        tagged,
        up=doubling(doubled),
        down=losing_ready(lost),
        timing=TIMING,
        retries=5,
        answer_timeout=60.0,
    )
    assert out.failure is None, out.failure
    assert out.served == tagged
    assert out.answers == tagged
    assert out.control.stats.failures == out.client.stats.failures == 0


@settings(max_examples=120, deadline=None)
@given(
    requests=payloads,
    seed=st.integers(0, 2**32 - 1),
    rate=st.floats(min_value=0.0, max_value=0.15),
    retries=st.integers(2, 6),
)
def test_marked_errors_never_alter_a_telegram_however_many_per_block(
    requests: list[bytes], seed: int, rate: float, retries: int
) -> None:
    """Characters with one flipped bit fail their parity check and the port marks them
    (docs/lsv2-serial.md, "Parity errors"): any number of them in one block, equal values
    included, never gets a changed, lost or doubled telegram through."""
    tagged = [i.to_bytes(2, "big") + r for i, r in enumerate(requests)]

    def marking(lane_seed: int) -> Fault:
        rng = random.Random(lane_seed)

        def fault(b: int) -> list[int]:
            if rng.random() < rate:
                return [(b ^ (1 << rng.randrange(8))) | MARKED]
            return [b]

        return fault

    out = exchange(
        tagged,
        up=marking(seed),
        down=marking(seed + 1),
        timing=TIMING,
        retries=retries,
        answer_timeout=60.0,
    )
    assert out.failure != "horizon"
    assert out.served == tagged[: len(out.served)], "control served a changed or doubled request"
    assert out.answers == tagged[: len(out.answers)], "client got a changed or doubled answer"
    if out.failure is None:
        assert out.answers == tagged
    elif out.failure == "answer timeout":
        assert out.control.stats.failures > 0, "stuck link"
    else:
        assert "serial LSV2 link" in out.failure
