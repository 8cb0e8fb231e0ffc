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
"""

from __future__ import annotations

import random

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from opendnc.lsv2.serial_link import LinkTiming
from tests.unit.lsv2.serial_line import Fault, exchange

TIMING = LinkTiming(time0=0.5, time1=0.5, time2=0.2)


def faulty(seed: int, drop: float, dup: float, flip: float) -> Fault:
    """Random faults on one lane; the sent bytes are followed to know what is inside a frame."""
    rng = random.Random(seed)
    state = {"since_flip": 64, "in_frame": False, "dle": False, "bcc_next": False}

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
            return [b ^ (1 << rng.randrange(8))]
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
    out = exchange(
        tagged,
        up=faulty(seed, drop, dup, flip),
        down=faulty(seed + 1, drop, dup, flip),
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
        # never a stuck link: an answer is missing only because the control gave it up
        assert out.control.stats.failures > 0
    else:
        assert "serial LSV2 link" in out.failure


@settings(max_examples=60, deadline=None)
@given(requests=payloads, seed=st.integers(0, 2**32 - 1))
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
