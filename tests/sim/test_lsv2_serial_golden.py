"""Golden test: our serial client against the virtual TNC 320 reproduces the real capture.

tests/data/lsv2_serial_tnc320_capture.txt holds the TNCremo <-> TNC 320 exchange (a public
capture, provenance in the file). Our client, logging in and reading the versions over a pty,
must put exactly the PC's bytes on the line, and the virtual TNC exactly the control's, step by
step.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from opendnc.lsv2 import Client
from opendnc.lsv2.framing import Frame, bcc
from opendnc.lsv2.serial_link import LinkRole, SerialLink, TelegramReceived
from opendnc.lsv2.serial_stream import SerialLine
from opendnc.sim.tnc import start_tnc
from opendnc.sim.tnc.serial_front import attach_serial
from tests.unit.lsv2.samples import S_PR_GOLDEN, TNC320_S_VR_PAYLOAD

CAPTURE = Path(__file__).parent.parent / "data" / "lsv2_serial_tnc320_capture.txt"


def capture_steps() -> list[tuple[str, bytes]]:
    steps = []
    for line in CAPTURE.read_text(encoding="ascii").splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        number, who, *hexes = line.split()
        assert int(number) == len(steps) + 1
        steps.append(("send" if who == "pc" else "recv", bytes.fromhex("".join(hexes))))
    return steps


def merged(chunks: list[tuple[str, bytes]]) -> Iterator[tuple[str, bytes]]:
    """Join consecutive chunks of one direction (a read may hold a step in pieces)."""
    current: tuple[str, bytearray] | None = None
    for direction, data in chunks:
        if current is not None and current[0] == direction:
            current[1].extend(data)
            continue
        if current is not None:
            yield current[0], bytes(current[1])
        current = (direction, bytearray(data))
    if current is not None:
        yield current[0], bytes(current[1])


def test_client_and_virtual_tnc320_reproduce_the_capture_byte_for_byte(tmp_path: Path) -> None:
    expected = capture_steps()
    assert len(expected) == 22
    wire: list[tuple[str, bytes]] = []
    with start_tnc("tnc320", root=tmp_path) as tnc:
        front = attach_serial(tnc, "pty")
        client = Client.over_serial(
            SerialLine(front.path), trace_bytes=lambda d, b: wire.append((d, b)), timeout=10
        )
        with client:
            assert client.versions.model == "TNC320"
    observed = list(merged(wire))
    for i, (want, got) in enumerate(zip(expected, observed, strict=False), start=1):
        assert got == want, (
            f"step {i}: expected {want[0]} {want[1].hex(' ')}, got {got[1].hex(' ')}"
        )
    assert len(observed) >= len(expected)


VECTORS = [
    (b"A_LGINSPECT\0", 0x40),
    (b"T_OK", 0x0C),
    (b"R_VR", 0x0A),
    (b"R_PR", 0x0C),
    (b"S_VR" + TNC320_S_VR_PAYLOAD, 0x71),
    (b"TNC 425", 0x49),  # worked example of the LSV2 documentation, via pyLSV2's branch tests
    (b"S_PR" + S_PR_GOLDEN, 0x44),  # payload holds one 0x10: sent stuffed, checked unstuffed
]


@pytest.mark.parametrize(("body", "check"), VECTORS)
def test_bcc_vectors_hold_for_the_link_encoder_and_decoder(body: bytes, check: int) -> None:
    assert bcc(body) == check
    frame = Frame(body[:4].decode("ascii"), body[4:])
    sender = SerialLink(LinkRole.CONTROL, max_body=4096)
    sender.send(frame, 0.0)
    assert sender.data_to_send() == b"\x05"
    sender.receive_data(b"\x10\x30", 0.0)
    wire = sender.data_to_send()
    stuffed = body.replace(b"\x10", b"\x10\x10")
    assert wire == b"\x10\x02" + stuffed + b"\x10\x03" + bytes([check])

    receiver = SerialLink(LinkRole.CLIENT)
    receiver.receive_data(b"\x05", 0.0)
    assert receiver.data_to_send() == b"\x10\x30"
    receiver.receive_data(wire, 0.0)
    assert receiver.data_to_send() == b"\x10\x31"
    assert receiver.next_event() == TelegramReceived(frame)
    # one bit off in the check: refused
    receiver = SerialLink(LinkRole.CLIENT)
    receiver.receive_data(b"\x05", 0.0)
    receiver.data_to_send()
    receiver.receive_data(wire[:-1] + bytes([check ^ 1]), 0.0)
    assert receiver.data_to_send() == b"\x15"
    assert receiver.next_event() is None
