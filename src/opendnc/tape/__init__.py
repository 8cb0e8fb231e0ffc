"""Tape code for every CNC with a serial port: ISO/EIA codes, DC codes, profiles, drip-feed.

The engine is sans-IO: :mod:`opendnc.tape.codes` (ISO and EIA characters, parity, end of
block), :mod:`opendnc.tape.reader` (bytes off the wire into blocks, with the checks),
:mod:`opendnc.tape.feed` (a file into framed, coded blocks), :mod:`opendnc.tape.profiles`
(control profiles as data), :mod:`opendnc.tape.dialects` (restart preambles) and
:mod:`opendnc.tape.session` (the punch receiver). The blocking drivers over a port are in
:mod:`opendnc.tape.serial_io`. Facts and choices: docs/tape.md.
"""

from opendnc.tape.codes import EIA_TABLE, Code, Codec, Eob, eia_to_iso, iso_to_eia
from opendnc.tape.errors import (
    NoCodeError,
    TapeCharacterError,
    TapeParityError,
    TapeWireError,
    TvCheckError,
)
from opendnc.tape.profiles import PROFILES, Framing, Naming, Profile, get_profile
from opendnc.tape.reader import End, ReaderConfig, TapeReader

__all__ = [
    "EIA_TABLE",
    "PROFILES",
    "Code",
    "Codec",
    "End",
    "Eob",
    "Framing",
    "Naming",
    "NoCodeError",
    "Profile",
    "ReaderConfig",
    "TapeCharacterError",
    "TapeParityError",
    "TapeReader",
    "TapeWireError",
    "TvCheckError",
    "eia_to_iso",
    "get_profile",
    "iso_to_eia",
]
