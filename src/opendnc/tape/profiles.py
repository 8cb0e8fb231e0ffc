"""Control profiles as data: line, code, end of block, handshakes, framing, names, dialect.

One :class:`Profile` per control family. Every value the manuals leave open is a choice
written down in docs/tape.md#profiles (marked there as unconfirmed); each can be changed per
machine with :meth:`Profile.with_changes` (the command line's ``--baud``, ``--line``,
``--code``, ``--eob``, ``--flow``, ``--tv-check`` ...).
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

from opendnc.errors import InputError
from opendnc.tape.codes import Code, Codec, Eob
from opendnc.transport.line import check_line


class Framing(enum.Enum):
    """How a program is framed on the tape (docs/tape.md#framing)."""

    PERCENT = "percent"  # % EOB, O-line, blocks, % (Fanuc, Haas, Mitsubishi, Mazak)
    OKUMA = "okuma"  # $NAME.MIN EOB, %, program, %
    SIEMENS = "siemens"  # %_N_NAME_MPF EOB ;$PATH=/_N_MPF_DIR EOB blocks, end-of-file byte
    FAGOR = "fagor"  # %comment,MX, EOB blocks, end-of-file byte


class Naming(enum.Enum):
    """Program-name rules: what a sent program must carry, what a received one is called."""

    O_NUMBER = "o-number"  # O + digits; received as O1234.nc
    FANUC_30I = "fanuc-30i"  # O-number or <NAME> of up to 32 characters
    OKUMA = "okuma"  # $NAME.MIN: letter + up to 15 alphanumerics, extension up to 3
    SIEMENS = "siemens"  # _N_NAME_MPF: up to 24 of 0-9 A-Z a-z _
    FAGOR = "fagor"  # the header's comment names the file


@dataclass(frozen=True, slots=True)
class Profile:
    """Everything opendnc needs to talk tape to one kind of control."""

    name: str
    description: str
    baud: int = 9600
    line: str = "7E2"  # data bits, parity, stop bits of the control's port
    flow: str = "xonxoff"  # xonxoff (DC1/DC3, done by us), rtscts, none
    code: Code = Code.ISO
    eob: Eob = Eob.LF
    tv_check: bool = False  # receive: odd blocks are an error; send: pad them with a space
    leader: int = 0  # feed characters before the program
    trailer: int = 0  # and after it
    feed_byte: int = 0x00  # NUL; Okuma may use space
    wait_dc1: bool = False  # a send waits for the control's DC1 (its READ)
    punch_dc2: bool = False  # a punch is framed DC2 ... DC4
    end_at_percent: bool = True  # a record ends at its closing %
    eof_byte: int | None = None  # sent after the program, ends a receive (Siemens, Fagor)
    framing: Framing = Framing.PERCENT
    naming: Naming = Naming.O_NUMBER
    o_digits: int = 4  # most digits an O-number may have
    dialect: str = "fanuc"  # restart preamble dialect (opendnc.tape.dialects)
    strip_comments: bool = False  # send without ( ... ) comments
    xoff_slack: int = 10  # characters the control accepts after its DC3
    quiet: float = 5.0  # seconds of silence that end a receive
    path: str = "/_N_MPF_DIR"  # Siemens ;$PATH= of a main program
    unconfirmed: tuple[str, ...] = ()  # which settings are our choice

    def __post_init__(self) -> None:
        bits, parity, stop = self.line_settings
        check_line(parity, bits, stop, self.flow)
        if self.code is Code.EIA and (bits, parity) != (8, "N"):
            raise InputError(
                f"{self.name}: an EIA line is 8 bits without UART parity ({self.line})"
            )

    @property
    def line_settings(self) -> tuple[int, str, float]:
        """(data bits, parity, stop bits) of :attr:`line`, e.g. ``(7, "E", 2)``."""
        text = self.line.strip().upper()
        try:
            bits, parity, stop = int(text[0]), text[1], float(text[2:])
        except (ValueError, IndexError):
            raise InputError(f"bad line {self.line!r}: use e.g. 7E2, 8N2, 8N1") from None
        return bits, parity, stop

    @property
    def port_settings(self) -> tuple[int, str, float]:
        """What the PC port is opened with: a 7E line is opened 8N with the parity done by
        the codec (the same bits on the wire, and we can check parity ourselves)."""
        bits, parity, stop = self.line_settings
        if self.software_parity:
            return 8, "N", stop
        return bits, parity, stop

    @property
    def software_parity(self) -> bool:
        """ISO with even parity in bit 8, set and checked by the codec."""
        bits, parity, _ = self.line_settings
        return self.code is Code.ISO and bits == 7 and parity == "E"

    @property
    def bits_per_char(self) -> int:
        """Start + data + parity + stop bits: one character's time on the line."""
        bits, parity, stop = self.line_settings
        return 1 + bits + (parity != "N") + int(stop + 0.5)

    @property
    def chars_per_second(self) -> float:
        """The line's character ceiling."""
        return self.baud / self.bits_per_char

    def codec(self) -> Codec:
        """The codec of this profile's line."""
        return Codec(self.code, parity=self.software_parity, eob=self.eob)

    def with_changes(self, **changes: Any) -> Profile:
        """A copy with some settings changed (``None`` values are ignored)."""
        real = {key: value for key, value in changes.items() if value is not None}
        return dataclasses.replace(self, **real) if real else self


_FANUC_UNCONF = ("leader/trailer count", "DC2...DC4 punch framing")

PROFILES: Mapping[str, Profile] = MappingProxyType(
    {
        p.name: p
        for p in (
            Profile(
                "fanuc-0i",
                "Fanuc 0i / 16i / 18i / 21i: ISO 7E2, DC codes, O-numbers of 4 digits",
                leader=20,
                trailer=20,
                wait_dc1=True,
                punch_dc2=True,
                unconfirmed=_FANUC_UNCONF,
            ),
            Profile(
                "fanuc-30i",
                "Fanuc 30i / 31i / 32i / 0i-F: ISO 7E2, DC codes, O-numbers or <NAME>",
                baud=19200,
                leader=20,
                trailer=20,
                wait_dc1=True,
                punch_dc2=True,
                naming=Naming.FANUC_30I,
                o_digits=8,
                unconfirmed=(*_FANUC_UNCONF, "8-digit O-numbers (an option)"),
            ),
            Profile(
                "mitsubishi-m80",
                "Mitsubishi M70 / M80 / M800: ISO, LF, feed from #9114, O-numbers",
                leader=30,
                trailer=30,
                punch_dc2=True,
                o_digits=8,
                unconfirmed=("line 7E2", "DC2/DC4 output on", "feed count 30", "no DC1 wait"),
            ),
            Profile(
                "mazak-smooth",
                "Mazak Smooth / Matrix EIA/ISO programs: 8N2, ISO without parity",
                line="8N2",
                o_digits=8,
                unconfirmed=("everything but 8N2 (from Mazatrol M PLUS / M32)",),
            ),
            Profile(
                "okuma-osp",
                "Okuma OSP: ISO 7E2, CR LF, $NAME.MIN header, DC codes, 600 feed characters",
                eob=Eob.CRLF,
                leader=600,
                trailer=600,
                wait_dc1=True,
                punch_dc2=True,
                framing=Framing.OKUMA,
                naming=Naming.OKUMA,
                dialect="okuma",
                xoff_slack=100,
                unconfirmed=("line 7E2 (a parameter)", "P200/P300 as U100"),
            ),
            Profile(
                "siemens-828d",
                "Siemens Sinumerik 828D: punch-tape format %_N_NAME_MPF, LF, end on SUB",
                baud=19200,
                line="8N1",
                end_at_percent=False,
                eof_byte=0x1A,
                framing=Framing.SIEMENS,
                naming=Naming.SIEMENS,
                dialect="siemens",
                unconfirmed=("line 19200 8N1", "end-of-file byte 0x1A", "XON/XOFF"),
            ),
            Profile(
                "siemens-840d",
                "Siemens Sinumerik 840D: punch-tape format %_N_NAME_MPF, LF, end on SUB",
                line="8N1",
                end_at_percent=False,
                eof_byte=0x1A,
                framing=Framing.SIEMENS,
                naming=Naming.SIEMENS,
                dialect="siemens",
                unconfirmed=("line 9600 8N1", "end-of-file byte 0x1A", "XON/XOFF"),
            ),
            Profile(
                "fagor",
                "Fagor 8055 / 8040: %comment,MX, header, LF, end on EOT (EOFCHR)",
                line="8N1",
                end_at_percent=False,
                eof_byte=0x04,
                framing=Framing.FAGOR,
                naming=Naming.FAGOR,
                dialect="fagor",
                unconfirmed=("line 9600 8N1", "EOFCHR = EOT", "no restart retract"),
            ),
            Profile(
                "haas",
                "Haas (plain text, Setting 25 CR LF): 8N1, O-numbers of 5 digits",
                line="8N1",
                eob=Eob.CRLF,
                o_digits=5,
                dialect="haas",
                unconfirmed=(),
            ),
        )
    }
)


def get_profile(name: str) -> Profile:
    """The profile called ``name``; :class:`InputError` lists the names otherwise."""
    try:
        return PROFILES[name.lower()]
    except KeyError:
        raise InputError(f"unknown profile {name!r}: use one of {', '.join(PROFILES)}") from None
