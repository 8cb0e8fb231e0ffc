"""Hypothesis properties of the serial LSV2 link engine moving files: answers alike.

``tests/property/test_lsv2_serial_link.py`` tags every telegram, so a repeat can always be told
from a new one. A real transfer cannot: an upload's answers are all ``T_OK``, a download's
requests are all ``T_OK``, and LSV2 has no sequence numbers (docs/lsv2-serial.md, "Equal
telegrams in a row"). Here the client sends file blocks (NC text with NUL line ends, or
arbitrary binary, equal blocks included) and the control answers each with ``T_OK``, or the
client asks with ``T_OK`` and the control answers with the next block, over a line that flips
bits (the port marks those characters), loses characters and repeats handshake characters.
Whatever happens:

* the exchange ends (no hang; a virtual clock bounds it);
* the control took a prefix of the blocks, each once, in order (upload), and the client a
  prefix of the blocks (download): never a block lost or doubled in the middle;
* a transfer that did not deliver every block reported a typed link error, or the client's
  answer timeout after the control gave a telegram up (what the client turns into an error).

Before the engine told an answer equal to the previous one from a repeat by whether the peer
had confirmed our DLE 1 for it, this failed: a control that repeated its ``T_OK`` confirmed a
block it never read (the example below; docs/lsv2-serial.md).
"""

from __future__ import annotations

import random

from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from opendnc.lsv2.framing import Frame
from opendnc.lsv2.serial_link import LinkTiming
from tests.unit.lsv2.serial_line import MARKED, Fault, Outcome, exchange

TIMING = LinkTiming(time0=0.5, time1=0.5, time2=0.2)
T_OK = Frame("T_OK")


def noisy(seed: int, mark: float, drop: float, dup: float) -> Fault:
    """One lane of a line whose port marks parity errors (docs/lsv2-serial.md, "Parity errors").

    Any character may have a bit flipped and then arrives marked (rate ``mark``): 8E1 parity
    sees every single-bit error. Unmarked faults are those it lets through: a character lost
    (an overrun, a framing error), and outside blocks a handshake character repeated (a
    gateway replaying a chunk). Inside a block (DLE STX to BCC, stuffing followed) at most one
    unmarked loss per 64 characters and never a NUL: the XOR block check misses a lost NUL and
    two losses that cancel ("What the block check cannot see"); the file operations' own
    end-to-end checks catch those (``tests/sim/test_lsv2_serial_verify.py``).
    """
    rng = random.Random(seed)
    st_ = {"frame": False, "dle": False, "bcc": False, "since": 64}

    def in_block(b: int) -> bool:
        """Follow the sent bytes; True for a byte of a block (stuffed body, DLE ETX, BCC)."""
        if st_["bcc"]:
            st_["bcc"] = st_["frame"] = False
            return True
        if st_["dle"]:
            st_["dle"] = False
            if b == 0x02:
                st_["frame"] = True
                return False
            if b == 0x03 and st_["frame"]:
                st_["bcc"] = True
            return bool(st_["frame"])
        if b == 0x10:
            st_["dle"] = True
            return bool(st_["frame"])
        return bool(st_["frame"])

    def fault(b: int) -> list[int]:
        block = in_block(b)
        st_["since"] += 1
        if rng.random() < mark:
            return [(b ^ (1 << rng.randrange(8))) | MARKED]
        r = rng.random()
        if block:
            if r < drop and b != 0 and st_["since"] >= 64:
                st_["since"] = 0
                return []
            return [b]
        if r < drop:
            return []
        if r < drop + dup:
            return [b, b]
        return [b]

    return fault


text_lines = st.lists(
    st.text(alphabet="0123456789 LXYZRF+-.", min_size=1, max_size=12), min_size=1, max_size=4
)
text_blocks = st.lists(
    text_lines.map(lambda lines: b"".join(line.encode() + b"\0" for line in lines)),
    min_size=1,
    max_size=25,
)
binary_blocks = st.lists(
    st.one_of(st.binary(max_size=40), st.sampled_from([b"\0" * 16, b"\x10" * 8])),
    min_size=1,
    max_size=25,
)
rates = st.floats(min_value=0.0, max_value=0.04)


def check(out: Outcome, delivered: list[bytes], blocks: list[bytes]) -> None:
    assert out.failure != "horizon", "the exchange did not end"
    assert delivered == blocks[: len(delivered)], "a block was lost, doubled or altered"
    if out.failure is None:
        assert delivered == blocks
    elif out.failure == "answer timeout":
        # the control gave a telegram up (the client turns the silence into an error): both
        # ends idle, nothing stuck
        assert out.control.stats.failures > 0, "stuck link"
        assert out.client.idle
    else:
        assert "serial LSV2 link" in out.failure


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    blocks=st.one_of(text_blocks, binary_blocks),
    seed=st.integers(0, 2**32 - 1),
    mark=st.floats(min_value=0.0, max_value=0.08),
    drop=rates,
    dup=rates,
    retries=st.integers(1, 6),
)
# Without telling an equal answer from a repeat (by the peer's EOT after our DLE 1, and by our
# frames all refused), the control's repeated T_OK confirmed a block it never read: 6 of 7.
@example(
    blocks=[b"%d L X+%d\0" % (i, i) for i in range(7)],
    seed=2592438871,
    mark=0.051184537501481345,
    drop=0.028378654981744064,
    dup=0.02664941691560165,
    retries=4,
)
def test_upload_with_equal_answers_is_exact_or_a_typed_error(
    blocks: list[bytes],
    seed: int,
    mark: float,
    drop: float,
    dup: float,
    retries: int,
) -> None:
    out = exchange(
        blocks,
        up=noisy(seed, mark, drop, dup),
        down=noisy(seed + 1, mark, drop, dup),
        timing=TIMING,
        retries=retries,
        answer_timeout=30.0,
        mnemonic="S_FL",
        answer=lambda _i, _request: T_OK,
    )
    check(out, out.served, blocks)
    assert len(out.answers) <= len(out.served)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    blocks=st.one_of(text_blocks, binary_blocks),
    seed=st.integers(0, 2**32 - 1),
    mark=st.floats(min_value=0.0, max_value=0.08),
    drop=rates,
    dup=rates,
    retries=st.integers(1, 6),
)
# The mirror in a download: the client's repeated T_OK confirmed a block it never read.
@example(
    blocks=[b"%d L X+%d\0" % (i, i) for i in range(15)],
    seed=1543931859,
    mark=0.020831408449508745,
    drop=0.0259118689559944,
    dup=0.002234573256153374,
    retries=4,
)
def test_download_answered_by_equal_t_ok_is_exact_or_a_typed_error(
    blocks: list[bytes],
    seed: int,
    mark: float,
    drop: float,
    dup: float,
    retries: int,
) -> None:
    out = exchange(
        [b""] * len(blocks),  # R_FL, then T_OK after every block: all alike
        up=noisy(seed, mark, drop, dup),
        down=noisy(seed + 1, mark, drop, dup),
        timing=TIMING,
        retries=retries,
        answer_timeout=30.0,
        mnemonic="T_OK",
        answer=lambda i, _request: Frame("S_FL", blocks[i]),
    )
    check(out, out.answers, blocks)
    assert len(out.served) >= len(out.answers)
