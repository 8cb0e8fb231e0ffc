"""PLC memory as one flat byte image, data-path resolution and the machine-parameter store.

Every view reads the same bytes: ``R_MB`` by address, ``R_DP`` ``\\PLC\\memory\\W\\20`` and the
machine model writing its live values (overrides, spindle speed, tool) into fixed words.
Multi-byte values are little-endian as in the controls' memory (docs/lsv2.md#plc-memory).
"""

from __future__ import annotations

import json
import re
import struct
from pathlib import Path

from opendnc.errors import ControlRefused, InputError
from opendnc.lsv2.constants import DataType
from opendnc.lsv2.constants import ErrorCode as E
from opendnc.lsv2.messages import DataPathReply
from opendnc.lsv2.tables import parse_table
from opendnc.sim.tnc.profiles import PlcLayout, Profile

BAD_MEMADR = E.T_ER_BAD_MEMADR
NOT_FOUND = E.T_ER_NOT_FOUND

# Word-area byte offsets where the machine model publishes live values (our own choice).
W_FEED_OVERRIDE = 0  # u16, 0.01 %
W_SPINDLE_OVERRIDE = 2
W_RAPID_OVERRIDE = 4
D_SPINDLE_SPEED = 8  # i32 rpm
D_TOOL_NUMBER = 12  # i32
D_PART_COUNTER = 16  # i32
D_PROGRAM_STATE = 20  # i32
M_PROGRAM_RUNNING = 0  # marker index
M_SPINDLE_ON = 1
M_ERROR_PENDING = 2

# Where symbols of the (imaginary) full PLC program live, away from the live values above.
SYMBOL_WORDS = 1024
SYMBOL_MARKERS = 1000
SYMBOL_STRINGS = 100
SYMBOLS: dict[str, tuple[str, int]] = {
    # Global PLC symbols of the demo PLC program -> (area letter, byte address / index).
    "NN_GENFEEDOVERRIDE": ("W", W_FEED_OVERRIDE),
    "NN_GENSPINDLEOVERRIDE": ("W", W_SPINDLE_OVERRIDE),
    "NN_GENRAPIDOVERRIDE": ("W", W_RAPID_OVERRIDE),
    "NN_SPINDLESPEED": ("D", D_SPINDLE_SPEED),
    "NN_TOOLNUMBER": ("D", D_TOOL_NUMBER),
    "NN_PARTCOUNTER": ("D", D_PART_COUNTER),
    "NN_PROGRAMRUNNING": ("M", M_PROGRAM_RUNNING),
}


class PlcMemory:
    """The byte image, sized and laid out as the profile's ``S_PR`` areas."""

    def __init__(self, layout: PlcLayout) -> None:
        self.layout = layout
        self.image = bytearray(layout.image_size)
        self._symbols: dict[str, tuple[str, int]] = {}
        for i in range(layout.strings):
            if i < 4:
                self.set_string(i, f"STRING {i}")

    def symbol(self, name: str, full: str) -> tuple[str, int]:
        """Operand behind a PLC symbol.

        The demo PLC program's live symbols map to fixed operands; any other well-formed
        symbol (a real PLC program declares hundreds) gets its own slot in the symbol region
        of the word area, typed by Heidenhain's prefix convention (M… marker, B/W/D…
        byte/word/dword, S… string), so repeated reads agree with each other and with R_MB.
        """
        known = SYMBOLS.get(name.upper())
        if known is not None:
            return known
        key = full.upper()
        if key not in self._symbols:
            first = name[:1].upper()
            n = len(self._symbols)
            if first == "M":
                self._symbols[key] = ("M", (SYMBOL_MARKERS + n) % self.layout.markers)
            elif first == "S":
                self._symbols[key] = ("S", (SYMBOL_STRINGS + n) % self.layout.strings)
            else:
                letter = first if first in ("B", "W", "D") else "D"
                offset = (SYMBOL_WORDS + 4 * n) % max(4, self.layout.words - 4)
                self._symbols[key] = (letter, offset - offset % 4)
        return self._symbols[key]

    # -- raw access ------------------------------------------------------------------------
    def read(self, address: int, count: int) -> bytes:
        """``R_MB``: ``count`` raw bytes at ``address`` or ControlRefused(52)."""
        if count < 1 or address < 0 or address + count > len(self.image):
            raise ControlRefused(BAD_MEMADR, f"address {address}+{count} outside PLC memory")
        return bytes(self.image[address : address + count])

    def write(self, address: int, data: bytes) -> None:
        """Write raw bytes (used by the machine model and tests)."""
        if address < 0 or address + len(data) > len(self.image):
            raise ControlRefused(BAD_MEMADR, f"address {address}+{len(data)} outside PLC memory")
        self.image[address : address + len(data)] = data

    def _area(self, letter: str) -> tuple[int, int, int]:
        """(start, element count, element size) of a bit/byte area by operand letter."""
        lay = self.layout
        table = {
            "M": (lay.markers_start, lay.markers, 1),
            "I": (lay.inputs_start, lay.inputs, 1),
            "O": (lay.outputs_start, lay.outputs, 1),
            "C": (lay.counters_start, lay.counters, 1),
            "T": (lay.timers_start, lay.timers, 1),
        }
        area = table.get(letter.upper())
        if area is None:
            raise ControlRefused(BAD_MEMADR, f"no bit area {letter!r}")
        return area

    # -- typed helpers ---------------------------------------------------------------------
    def set_bit(self, letter: str, index: int, value: bool) -> None:
        """Set marker/input/output/counter/timer ``index``."""
        start, count, _ = self._area(letter)
        if not 0 <= index < count:
            raise ControlRefused(BAD_MEMADR, f"{letter}{index} out of range")
        self.image[start + index] = 1 if value else 0

    def set_word(self, byte_address: int, value: int) -> None:
        """Store a little-endian u16 at a word-area byte address."""
        self.write(self.layout.words_start + byte_address, struct.pack("<H", value & 0xFFFF))

    def set_dword(self, byte_address: int, value: int) -> None:
        """Store a little-endian i32 at a word-area byte address."""
        self.write(self.layout.words_start + byte_address, struct.pack("<i", value))

    def set_string(self, index: int, text: str) -> None:
        """Store string ``index`` NUL-padded in its fixed slot."""
        lay = self.layout
        raw = text.encode("latin-1", "replace")[: lay.string_length - 1]
        self.write(
            lay.strings_start + index * lay.string_length, raw.ljust(lay.string_length, b"\0")
        )

    # -- data paths ------------------------------------------------------------------------
    def read_operand(self, letter: str, number: int) -> DataPathReply:
        """Value of ``\\PLC\\memory\\<letter>\\<number>`` (B/W/D by byte address)."""
        lay = self.layout
        letter = letter.upper()
        if letter in ("M", "I", "O", "C", "T"):
            start, count, _ = self._area(letter)
            if not 0 <= number < count:
                raise ControlRefused(NOT_FOUND, f"{letter}{number} out of range")
            return DataPathReply(DataType.BOOL, self.image[start + number] != 0)
        if letter in ("B", "W", "D"):
            size = {"B": 1, "W": 2, "D": 4}[letter]
            # Byte addresses; real programming stations also answer unaligned W/D reads.
            if number < 0 or number + size > lay.words:
                raise ControlRefused(NOT_FOUND, f"{letter}{number} not a valid byte address")
            raw = self.read(lay.words_start + number, size)
            if letter == "B":
                return DataPathReply(DataType.INT8, struct.unpack("<b", raw)[0])
            if letter == "W":
                return DataPathReply(DataType.INT16, struct.unpack("<h", raw)[0])
            return DataPathReply(DataType.INT32, struct.unpack("<i", raw)[0])
        if letter == "S":
            if not 0 <= number < lay.strings:
                raise ControlRefused(NOT_FOUND, f"S{number} out of range")
            raw = self.read(lay.strings_start + number * lay.string_length, lay.string_length)
            return DataPathReply(DataType.STRING, raw.split(b"\0", 1)[0].decode("latin-1"))
        if letter == "K":
            # K operands are constants of the PLC program; the demo program defines K n = n.
            return DataPathReply(DataType.INT32, number)
        raise ControlRefused(NOT_FOUND, f"unknown operand {letter}")


_MEMORY_RE = re.compile(r"^\\PLC\\MEMORY\\([A-Z])\\(\d+)$", re.IGNORECASE)
_TOOL_RE = re.compile(r"^\\TABLE\\TOOL\\T\\(\d+)\\([A-Z0-9_]+)$", re.IGNORECASE)
_SYMBOL_RE = re.compile(
    r"^\\PLC\\PROGRAM\\SYMBOL\\(?:GLOBAL|MODULE\\'[^']+')\\\+?"
    r"([A-Z][A-Z0-9_]*)(?:\[\d+\])?(?:\.[A-Z0-9_]+)*$",
    re.IGNORECASE,
)


def resolve_data_path(
    path: str, plc: PlcMemory, tool_rows: dict[int, dict[str, str]]
) -> DataPathReply:
    """Resolve an ``R_DP`` path; ControlRefused(63) when it names nothing."""
    path = path.replace("/", "\\").strip()
    if m := _MEMORY_RE.match(path):
        return plc.read_operand(m.group(1), int(m.group(2)))
    if m := _TOOL_RE.match(path):
        row = tool_rows.get(int(m.group(1)))
        if row is None:
            raise ControlRefused(NOT_FOUND, f"no tool {m.group(1)}")
        column = m.group(2).upper()
        if column not in row:
            raise ControlRefused(NOT_FOUND, f"no column {column}")
        text = row[column]
        if column == "T":
            return DataPathReply(DataType.INT32, int(text or 0))
        try:
            return DataPathReply(DataType.FLOAT64, float(text))
        except ValueError:
            return DataPathReply(DataType.STRING, text)
    if m := _SYMBOL_RE.match(path):
        return plc.read_operand(*plc.symbol(m.group(1), m.group(0)))
    raise ControlRefused(NOT_FOUND, f"unknown data path {path!r}")


def table_rows(text: str) -> list[dict[str, str]]:
    """Rows of a control table (the client's parser); none when the file is not a table."""
    try:
        return parse_table(text).rows
    except InputError:
        return []


NUMERIC_MP = {
    "7230.0": "0",  # conversational language (0 = English)
    "7230.1": "0",
    "7210": "0",  # programming station
    "7212": "0",
    "7280": "0",  # decimal character
    "7285": "0",
    "7290.0": "4",  # position display step
    "1010.0": "10000",  # rapid traverse X
    "1010.1": "10000",
    "1010.2": "10000",
    "1040": "7",
}
CONFIG_MP = {
    "CfgDisplayLanguage.ncLanguage": "ENGLISH",
    "CfgDisplayLanguage.plcDialogLanguage": "ENGLISH",
    "CfgDisplayData.axisDisplay": "X_Y_Z",
    "CfgProgramMode.unitOfMeasure": "MM",
    "CfgAxisPropKin.X.presetToAlignAxis": "FALSE",
    "CfgPositionLimits.X.upperLimit": "+500",
    "CfgPositionLimits.X.lowerLimit": "-500",
    "CfgPositionLimits.Y.upperLimit": "+400",
    "CfgPositionLimits.Y.lowerLimit": "-400",
    "CfgPositionLimits.Z.upperLimit": "+500",
    "CfgPositionLimits.Z.lowerLimit": "-100",
}


class MachineParameters:
    """Named parameters; permanent writes persist as JSON in the root's state folder."""

    def __init__(self, state_dir: Path, profile: Profile) -> None:
        self._file = state_dir / "machine_parameters.json"
        defaults = NUMERIC_MP if profile.numeric_machine_parameters else CONFIG_MP
        self._permanent: dict[str, str] = dict(defaults)
        if self._file.exists():
            try:
                stored = json.loads(self._file.read_text("utf-8"))
            except (OSError, ValueError):
                stored = {}
            if isinstance(stored, dict):
                self._permanent.update({str(k): str(v) for k, v in stored.items()})
        self._temporary: dict[str, str] = {}

    def _key(self, name: str) -> str | None:
        low = name.lower()
        for k in self._permanent:
            if k.lower() == low:
                return k
        return None

    def read(self, name: str) -> str | None:
        """Current value (temporary override first) or None if unknown."""
        key = self._key(name)
        if key is None:
            return None
        return self._temporary.get(key, self._permanent[key])

    def write(self, name: str, value: str, temporary: bool) -> bool:
        """Write a known parameter; False if the name is unknown."""
        key = self._key(name)
        if key is None:
            return False
        if temporary:
            self._temporary[key] = value
            return True
        self._temporary.pop(key, None)
        self._permanent[key] = value
        tmp = self._file.with_suffix(".tmp")
        tmp.write_text(json.dumps(self._permanent, indent=1), "utf-8")
        tmp.replace(self._file)
        return True
