"""PLC operands: notation (``M100``, ``W4``, ``IW2``, ``S3`` ...), element sizes, addresses.

Pure functions shared by the client (to build ``R_MB`` requests and decode ``S_MB`` bytes) and
usable by a simulator. Addresses come from the control's :class:`SystemParameters`
(docs/lsv2.md#system-parameters);
values in PLC memory are little-endian (docs/lsv2.md#plc-memory).

>>> parse_operand("W4")
PlcOperand(memory=<MemoryType.WORD: 7>, index=2)
>>> parse_operand("M100").notation
'M100'
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass

from opendnc.errors import InputError, RemoteProtocolError
from opendnc.lsv2.constants import MemoryType
from opendnc.lsv2.payloads import SystemParameters

__all__ = [
    "MAX_READ",
    "PlcOperand",
    "PlcValue",
    "area_of",
    "decode_values",
    "element_size",
    "parse_operand",
    "plan_reads",
]

MAX_READ = 255
"""Largest ``R_MB`` byte count."""

PlcValue = bool | int | str

# Letters of the notation -> memory type. Byte/word/dword operands are written with their
# byte address (W4 is the third word, index 2); the others with their element number.
_LETTERS: dict[str, MemoryType] = {
    "M": MemoryType.MARKER,
    "I": MemoryType.INPUT,
    "E": MemoryType.INPUT,  # German notation
    "O": MemoryType.OUTPUT,
    "A": MemoryType.OUTPUT,  # German notation
    "C": MemoryType.COUNTER,
    "T": MemoryType.TIMER,
    "B": MemoryType.BYTE,
    "W": MemoryType.WORD,
    "D": MemoryType.DWORD,
    "S": MemoryType.STRING,
    "IW": MemoryType.INPUT_WORD,
    "OW": MemoryType.OUTPUT_WORD,
    "ID": MemoryType.INPUT_DWORD,
    "OD": MemoryType.OUTPUT_DWORD,
}
_BY_ADDRESS = {
    MemoryType.BYTE,
    MemoryType.WORD,
    MemoryType.DWORD,
    MemoryType.INPUT_WORD,
    MemoryType.OUTPUT_WORD,
    MemoryType.INPUT_DWORD,
    MemoryType.OUTPUT_DWORD,
}
_NOTATION = {v: k for k, v in reversed(list(_LETTERS.items()))}
_PATTERN = re.compile(r"^\s*(IW|OW|ID|OD|M|I|E|O|A|C|T|B|W|D|S)\s*(\d+)\s*$", re.IGNORECASE)

# memory type -> (struct code for one element or None for bool/str, element size)
_FORMATS: dict[MemoryType, str] = {
    MemoryType.BYTE: "<b",
    MemoryType.WORD: "<h",
    MemoryType.DWORD: "<i",
    MemoryType.INPUT_WORD: "<H",
    MemoryType.OUTPUT_WORD: "<H",
    MemoryType.INPUT_DWORD: "<i",
    MemoryType.OUTPUT_DWORD: "<i",
}


def element_size(memory: MemoryType, params: SystemParameters | None = None) -> int:
    """Bytes per element (strings: the control's string length)."""
    if memory is MemoryType.STRING:
        if params is None:
            raise InputError("string size needs the system parameters")
        return params.string_length
    fmt = _FORMATS.get(memory)
    return 1 if fmt is None else struct.calcsize(fmt)


@dataclass(frozen=True, slots=True)
class PlcOperand:
    """A PLC memory type and element index."""

    memory: MemoryType
    index: int

    @property
    def notation(self) -> str:
        """Operand notation, e.g. ``W4`` for word index 2."""
        size = element_size(self.memory) if self.memory is not MemoryType.STRING else 1
        number = self.index * size if self.memory in _BY_ADDRESS else self.index
        return f"{_NOTATION[self.memory]}{number}"


def parse_operand(text: str) -> PlcOperand:
    """Parse ``M100``, ``I5``, ``O3``, ``C2``, ``T7``, ``B10``, ``W4``, ``D16``, ``S3``,
    ``IW2``, ``OW4``, ``ID8``, ``OD0`` (case-insensitive; E/A accepted for I/O)."""
    m = _PATTERN.match(text)
    if m is None:
        raise InputError(f"{text!r} is not a PLC operand such as M100, W4, D8, S3, IW2")
    memory = _LETTERS[m.group(1).upper()]
    number = int(m.group(2))
    if memory in _BY_ADDRESS:
        size = element_size(memory)
        if number % size:
            raise InputError(f"{text!r}: {memory.name} addresses are multiples of {size}")
        return PlcOperand(memory, number // size)
    return PlcOperand(memory, number)


def area_of(memory: MemoryType, params: SystemParameters) -> tuple[int, int]:
    """(start address, size in bytes) of the area holding ``memory`` elements."""
    p = params
    areas: dict[MemoryType, tuple[int, int]] = {
        MemoryType.MARKER: (p.markers_start, p.markers),
        MemoryType.INPUT: (p.inputs_start, p.inputs),
        MemoryType.OUTPUT: (p.outputs_start, p.outputs),
        MemoryType.COUNTER: (p.counters_start, p.counters),
        MemoryType.TIMER: (p.timers_start, p.timers),
        MemoryType.BYTE: (p.words_start, p.words),
        MemoryType.WORD: (p.words_start, p.words),
        MemoryType.DWORD: (p.words_start, p.words),
        MemoryType.STRING: (p.strings_start, p.strings * p.string_length),
        MemoryType.INPUT_WORD: (p.input_words_start, p.input_words),
        MemoryType.INPUT_DWORD: (p.input_words_start, p.input_words),
        MemoryType.OUTPUT_WORD: (p.output_words_start, p.output_words),
        MemoryType.OUTPUT_DWORD: (p.output_words_start, p.output_words),
    }
    return areas[memory]


def plan_reads(
    memory: MemoryType, index: int, count: int, params: SystemParameters
) -> list[tuple[int, int]]:
    """``R_MB`` requests (address, byte count) reading ``count`` elements from ``index``.

    Each request holds whole elements and at most 255 bytes; strings longer than 255 bytes
    are read in pieces.
    """
    if count < 1 or index < 0:
        raise InputError(f"read at least one element from a non-negative index, not {count}")
    size = element_size(memory, params)
    start, area = area_of(memory, params)
    if (index + count) * size > area:
        raise InputError(
            f"{memory.name} {index}..{index + count - 1} lies outside the control's area "
            f"of {area // size} elements"
        )
    first = start + index * size
    total = count * size
    step = (MAX_READ // size) * size if size <= MAX_READ else MAX_READ
    return [(first + off, min(step, total - off)) for off in range(0, total, step)]


def decode_values(
    memory: MemoryType, data: bytes, count: int, params: SystemParameters
) -> list[PlcValue]:
    """Turn raw memory bytes into ``count`` values (bools, ints or strings)."""
    size = element_size(memory, params)
    if len(data) != size * count:
        raise RemoteProtocolError(f"S_MB returned {len(data)} bytes, expected {size * count}")
    if memory is MemoryType.STRING:
        return [
            data[i : i + size].split(b"\0", 1)[0].decode("latin-1")
            for i in range(0, len(data), size)
        ]
    fmt = _FORMATS.get(memory)
    if fmt is None:
        return [b != 0 for b in data]
    return [v for (v,) in struct.iter_unpack(fmt, data)]
