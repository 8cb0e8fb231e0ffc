"""Program memory of the virtual Haas: O-numbered programs kept as files in ``--root``.

Each program is stored as ``O01234.nc`` holding the tape text (``%`` lines included, LF line
ends). Writes go to a temporary file in the same folder and are renamed only when complete.
"""

from __future__ import annotations

import re
from pathlib import Path

from opendnc.atomicfile import atomic_write
from opendnc.errors import InputError
from opendnc.gcode.program import ProgramHeader, parse_header

_NAME = re.compile(r"^O(\d{1,5})\.nc$", re.IGNORECASE)


class ProgramStore:
    """O-numbered programs in a folder (the control's memory)."""

    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)

    def path(self, number: int) -> Path:
        """File that holds program ``number``."""
        if not 0 < number <= 99999:
            raise InputError(f"program number O{number} is out of range 1..99999")
        return self.root / f"O{number:05d}.nc"

    def numbers(self) -> list[int]:
        """Stored program numbers, ascending."""
        found = []
        for entry in self.root.iterdir():
            match = _NAME.match(entry.name)
            if match and entry.is_file():
                found.append(int(match.group(1)))
        return sorted(found)

    def read(self, number: int) -> str:
        """Tape text of program ``number``."""
        try:
            return self.path(number).read_text(encoding="latin-1")
        except FileNotFoundError:
            raise InputError(f"no program O{number:05d} in memory") from None

    def save(self, text: str) -> ProgramHeader:
        """Store a program (its O number decides the slot); returns its header."""
        header = parse_header(text)
        body = text.replace("\r\n", "\n").replace("\r", "\n").strip("\n\x1a")
        if not body.startswith("%"):
            body = "%\n" + body
        if not body.rstrip().endswith("%"):
            body = body.rstrip("\n") + "\n%"
        self._write_atomic(self.path(header.number), body + "\n")
        return header

    def delete(self, number: int) -> None:
        """Remove program ``number``."""
        try:
            self.path(number).unlink()
        except FileNotFoundError:
            raise InputError(f"no program O{number:05d} in memory") from None

    def _write_atomic(self, target: Path, text: str) -> None:
        # newline="\n" text mode wrote the str unchanged, so encoding it is byte-identical.
        with atomic_write(target) as handle:
            handle.write(text.encode("latin-1"))
