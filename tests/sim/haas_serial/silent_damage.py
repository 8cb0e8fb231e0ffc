"""Find a cable seed whose noise lets a checksum-XModem load into the virtual Haas through with
two bit errors that cancel in the 8-bit sum (issue 20, item 6).

The cable's noise depends only on each direction's byte position and the seed
(:mod:`opendnc.sim.cable.noise`), so a transfer can be replayed here without ptys: each frame
the sender would put on the line goes through the same :class:`LineNoise`, and the receiver's
checks decide what happens next. A seed qualifies when, in the load, exactly one block is
accepted with changed data and nothing else is ambiguous (no header hit, the control's answers
and the punch back clean or caught by their checks, for every plausible count of start NAKs),
so the live run repeats the model byte for byte. ``python -m tests.sim.haas_serial.silent_damage``
searches seeds.

The PC is on side B of the cable, the control on side A: the PC's bytes travel ``b>a``.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

from opendnc.sim.cable.noise import LineNoise
from opendnc.sim.haas.serial_xmodem import punch_bytes
from opendnc.xmodem.framing import SMALL, checksum, encode_block
from opendnc.xmodem.haas import Eob

BER = 3e-4
START_NAKS = range(1, 11)  # the control's start requests before the PC's sender answers


def program(lines: int = 300) -> bytes:
    """A milling program of about 8 kB with four-decimal coordinates (deterministic)."""
    out = ["%", "O01000 (PUNCH BACK)", "G20", "T1 M06", "G54", "G43 H01", "S1000 M03"]
    for i in range(1, lines + 1):
        out.append(f"G01 X-{i % 7}.{(i * 37) % 10000:04d} Y{i % 5}.{(i * 91) % 10000:04d} F20.")
    out += ["M30", "%", ""]
    return "\n".join(out).encode()


@dataclass(frozen=True)
class Damage:
    """What the model says the control stores: the program with one block changed."""

    stored: bytes  # the bytes the control accepted (SUB padding stripped)
    offset: int  # first changed byte in the program
    line: int  # its line, 1 = the first line after the opening %


def _frames(data: bytes) -> list[bytes]:
    return [
        encode_block(i // SMALL + 1, data[i : i + SMALL], crc=False)
        for i in range(0, len(data), SMALL)
    ]


def _header_ok(got: bytes, frame: bytes) -> bool:
    return got[:3] == frame[:3]


def _load(seed: int, data: bytes, ber: float) -> tuple[bytes, int, int] | None:
    """Replay the load; (accepted data, b>a bytes used, answers sent) or None if unclear."""
    ba = LineNoise(ber, 0.0, f"{seed}:b>a")
    accepted: list[bytes] = []
    answers = 0
    damaged = 0
    for frame in _frames(data):
        for _attempt in range(10):
            got = ba.apply(frame).data
            answers += 1
            if not _header_ok(got, frame):
                return None  # the receiver's reading of a hit header is timing-dependent
            if checksum(got[3:-1]) == got[-1]:
                if got != frame:
                    damaged += 1
                accepted.append(got[3:-1])
                break
        else:
            return None
    if damaged != 1 or ba.apply(b"\x04").data != b"\x04":  # the EOT must arrive clean
        return None
    return b"".join(accepted).rstrip(bytes((0x1A,))), ba.position, answers


def _answers_clean(seed: int, ber: float, count: int) -> bool:
    """The control's NAKs, ACKs and CAN CAN CAN reach the PC intact for any start count."""
    ab = LineNoise(ber, 0.0, f"{seed}:a>b")
    length = max(START_NAKS) + count + 3 + 64
    return ab.apply(bytes(length)).data == bytes(length)


def _punch_clean(seed: int, stored: bytes, answers: int, pc_used: int, ber: float) -> bool:
    """The punch back of ``stored`` arrives without a silent change, whatever the offset."""
    text = stored.decode("latin-1")
    wire = punch_bytes(text if text.endswith("\n") else text + "\n", Eob.LF)
    for naks in START_NAKS:
        ab = LineNoise(ber, 0.0, f"{seed}:a>b")
        ab.apply(bytes(naks + answers + 3))
        ba = LineNoise(ber, 0.0, f"{seed}:b>a")
        ba.apply(bytes(pc_used))
        for frame in _frames(wire):
            for _attempt in range(10):
                got = ab.apply(frame).data
                if not _header_ok(got, frame):
                    return False
                answer = ba.apply(b"\x06").data  # ACK or NAK: one byte each way
                if answer != b"\x06":
                    return False
                if checksum(got[3:-1]) == got[-1]:
                    if got != frame:
                        return False
                    break
            else:
                return False
    return True


def silent_damage(seed: int, data: bytes | None = None, ber: float = BER) -> Damage | None:
    """The damage this seed causes in a load of ``data`` (None: no clean case of it)."""
    data = program() if data is None else data
    load = _load(seed, data, ber)
    if load is None:
        return None
    stored, pc_used, answers = load
    if not _answers_clean(seed, ber, answers):
        return None
    if not _punch_clean(seed, stored, answers, pc_used + 1, ber):
        return None
    offset = next(i for i, (a, b) in enumerate(zip(stored, data, strict=False)) if a != b)
    if stored[offset] in b"\n%" or data[offset] in b"\n%" or offset < 20:
        return None  # a hit on a line end or the header changes the program's shape
    line = data[:offset].count(b"\n")  # the % line is line 0
    return Damage(stored, offset, line)


def main() -> None:
    """Search seeds: ``python -m tests.sim.haas_serial.silent_damage [FIRST [COUNT]]``."""
    first = int(sys.argv[1]) if len(sys.argv) > 1 else 0
    count = int(sys.argv[2]) if len(sys.argv) > 2 else 2000
    data = program()
    for seed in range(first, first + count):
        found = silent_damage(seed, data)
        if found is not None:
            line = data.split(b"\n")[found.line]
            print(seed, found.offset, found.line, line, found.stored.split(b"\n")[found.line])


if __name__ == "__main__":
    main()
