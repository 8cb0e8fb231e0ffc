"""The virtual Fanuc's I/O parameters and alarms, with the numbers docs/tape.md gives.

Parameter numbers are those commonly cited for Fanuc 0i/16i (docs/tape.md#fanuc-parameters;
several are unconfirmed, which the doc says): 0000 bit 0 TVC (TV check), bit 1 ISO (punch
code ISO, else EIA); 0101 bit 0 SB2 (two stop bits), bit 7 NFD (no feed before and after a
punch); 0103 the baud code 1..12 (10 = 4800, 11 = 9600, 12 = 19200; higher rates, which the
series with the newer I/O boards offer, are our own codes 13..15).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from opendnc.errors import InputError
from opendnc.tape.codes import Code, Eob

BAUD_CODES: Mapping[int, int] = {
    1: 50, 2: 100, 3: 110, 4: 150, 5: 200, 6: 300, 7: 600, 8: 1200,
    9: 2400, 10: 4800, 11: 9600, 12: 19200, 13: 38400, 14: 57600, 15: 115200,
}  # fmt: skip


@dataclass(frozen=True, slots=True)
class Alarm:
    """An alarm of the virtual Fanuc: its number and text."""

    number: int
    text: str

    def __str__(self) -> str:
        return f"ALARM {self.number:03d} {self.text}"


ALARM_TH = Alarm(1, "TH ALARM: parity or illegal character")
ALARM_TV = Alarm(2, "TV ALARM: odd number of characters in a block")
ALARM_OVERRUN = Alarm(85, "COMMUNICATION ERROR: overrun, parity or framing")
ALARM_NOT_READY = Alarm(86, "DR SIGNAL OFF: the device stopped before the end of the tape")
ALARM_OVERFLOW = Alarm(87, "BUFFER OVERFLOW: characters kept coming after DC3")


@dataclass(frozen=True, slots=True)
class FanucParams:
    """The settings a Fanuc keeps in its I/O parameters."""

    baud: int = 9600
    code: Code = Code.ISO  # what it punches; a read takes either
    stop_bits: int = 2
    tv_check: bool = False
    feed: bool = True  # feed (NUL) before and after a punch
    eob: Eob = Eob.LF  # ISO punch EOB (EIA: CR)

    def numbers(self) -> dict[str, int]:
        """The parameters by number, as the control's screen shows them."""
        codes = {baud: code for code, baud in BAUD_CODES.items()}
        return {
            "0000": int(self.tv_check) | (int(self.code is Code.ISO) << 1),
            "0101": int(self.stop_bits == 2) | (int(not self.feed) << 7),
            "0103": codes[self.baud],
        }

    @classmethod
    def from_numbers(
        cls, values: Mapping[str, int], base: FanucParams | None = None
    ) -> FanucParams:
        """Parameters from ``{"0000": 3, "0103": 11}`` (others as in ``base``)."""
        start = base or cls()
        tv, code, stop, feed, baud = (
            start.tv_check,
            start.code,
            start.stop_bits,
            start.feed,
            start.baud,
        )
        for number, value in values.items():
            key = number.zfill(4)
            if key == "0000":
                tv, code = bool(value & 1), Code.ISO if value & 2 else Code.EIA
            elif key == "0101":
                stop, feed = 2 if value & 1 else 1, not value & 0x80
            elif key == "0103":
                if value not in BAUD_CODES:
                    raise InputError(f"parameter 0103: no baud code {value} (use 1..15)")
                baud = BAUD_CODES[value]
            else:
                raise InputError(f"parameter {key} is not modelled (0000, 0101, 0103 are)")
        return cls(baud=baud, code=code, stop_bits=stop, tv_check=tv, feed=feed, eob=start.eob)
