"""Typed errors of the tape engine, each under :class:`opendnc.errors.DncError`.

A character with no code in the target code is a local problem (the file cannot be punched
in that code): :class:`NoCodeError`, an :class:`~opendnc.errors.InputError`. What arrives
damaged from the wire is a :class:`~opendnc.errors.RemoteProtocolError`: a character failing
its parity (:class:`TapeParityError`, the Fanuc TH check), a byte that is no character of the
code (:class:`TapeCharacterError`), a block with an odd number of characters while TV check
is on (:class:`TvCheckError`). Every message names the line (block) and column.
"""

from __future__ import annotations

from opendnc.errors import InputError, RemoteProtocolError


def _where(line: int, column: int) -> str:
    return f"line {line}, column {column}"


class NoCodeError(InputError):
    """A character of the program has no code in the target tape code."""

    def __init__(self, char: str, code: str, line: int, column: int) -> None:
        self.char = char
        self.code = code
        self.line = line
        self.column = column
        shown = repr(char) if char.isprintable() else f"0x{ord(char):02X}"
        super().__init__(f"{shown} at {_where(line, column)} has no {code} code")


class TapeWireError(RemoteProtocolError):
    """Bytes from the control that are no valid tape text; ``line``/``column`` say where."""

    kind = "bad tape character"

    def __init__(self, line: int, column: int, detail: str) -> None:
        self.line = line
        self.column = column
        self.detail = detail
        super().__init__(f"{self.kind} at {_where(line, column)}: {detail}")


class TapeParityError(TapeWireError):
    """A character failed its parity check (Fanuc alarm 001, TH)."""

    kind = "parity error (TH)"


class TapeCharacterError(TapeWireError):
    """A byte that is no character of the tape code in use."""

    kind = "no character of the tape code"


class TvCheckError(TapeWireError):
    """A block had an odd number of characters while TV check was on (Fanuc alarm 002)."""

    kind = "odd block length (TV check)"


class TapeNameError(RemoteProtocolError):
    """A received program carries a name the control's naming rules do not allow (too many
    O-number digits, an Okuma, Sinumerik or Fagor name too long): damage, never a file name."""

    def __init__(self, name: str, rule: str) -> None:
        self.name = name
        self.rule = rule
        shown = name if len(name) <= 32 else f"{name[:32]}... ({len(name)} characters)"
        super().__init__(f"the control sent a program named {shown!r}: {rule}")
