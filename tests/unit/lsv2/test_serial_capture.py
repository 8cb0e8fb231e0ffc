"""The serial LSV2 trace of TNCremo and a TNC 320 station, decoded by our serial framer.

The bytes are in docs/captures/lsv2-serial-tnc320.txt (provenance in its header).
"""

from __future__ import annotations

from pathlib import Path

from opendnc.lsv2.framing import Frame, SerialControl, SerialFramer, encode_serial_frame

CAPTURE = Path(__file__).resolve().parents[3] / "docs" / "captures" / "lsv2-serial-tnc320.txt"


def direction(arrow: str) -> bytes:
    """Every byte sent in one direction (">" PC to control, "<" control to PC), in order."""
    out = bytearray()
    for line in CAPTURE.read_text("utf-8").splitlines():
        if line.startswith(arrow + " "):
            out += bytes.fromhex(line[2:])
    return bytes(out)


def decode(data: bytes) -> list[Frame | SerialControl]:
    framer = SerialFramer()
    framer.feed(data)
    items: list[Frame | SerialControl] = []
    while (item := framer.next_frame()) is not None:
        items.append(item)
    return items


C = SerialControl


def test_pc_side_of_the_trace() -> None:
    assert decode(direction(">")) == [
        C.ENQ,
        C.ENQ,
        Frame("A_LG", b"INSPECT\0"),
        C.EOT,
        C.READY,
        C.RECEIVED,
        C.ENQ,
        Frame("R_VR"),
        C.EOT,
        C.READY,
        C.RECEIVED,
        C.ENQ,
        Frame("R_PR"),
        C.EOT,
    ]


def test_control_side_of_the_trace() -> None:
    parts = [b"TNC320", b"771855 18 SP1", b"Basic V18-00", b"No version given", b"0000000100000100"]
    versions = b"".join(part + b"\x00" for part in parts)
    assert decode(direction("<")) == [
        C.READY,
        C.READY,
        C.RECEIVED,
        C.ENQ,
        Frame("T_OK"),
        C.EOT,
        C.READY,
        C.RECEIVED,
        C.ENQ,
        Frame("S_VR", versions),
        C.EOT,
        C.READY,
        C.RECEIVED,
        C.ENQ,
    ]


def test_our_frames_are_the_captured_bytes() -> None:
    pc = direction(">")
    for frame in (Frame("A_LG", b"INSPECT\0"), Frame("R_VR"), Frame("R_PR")):
        assert encode_serial_frame(frame) in pc
