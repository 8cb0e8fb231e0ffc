"""Sans-IO capture of a program a control punches as plain text (no XModem).

A text punch has no framing of its own: the control sends leader characters, the program
between its ``%`` lines, and a trailer. The capture starts at the *start trigger* (``%`` by
default; empty: at the first character that is not leader) and ends after the *end trigger*
(``%`` by default). The end trigger counts only once some program text followed the start, so a
``%`` leader (``%%%%``) or the opening ``%`` itself does not end an empty capture. With an empty
end trigger the capture ends when the line goes quiet; with one, a line that goes quiet first is
a failed reception (the driver calls :meth:`TextCapture.quiet` after its idle timeout).

Bytes that are never program text are dropped wherever they come: NUL and DEL (tape leader and
rub-outs), DC1 to DC4 (flow control, punch on and off). The program is handed out with LF line
ends (:func:`opendnc.xmodem.haas.from_wire`) and ends with one.
(docs/server.md#serial-profile)
"""

from __future__ import annotations

from opendnc.errors import InputError
from opendnc.xmodem.haas import Eob, from_wire

__all__ = ["MAX_PUNCH", "NOISE", "TextCapture"]

NOISE = frozenset({0x00, 0x7F, 0x11, 0x12, 0x13, 0x14})
"""Bytes a text punch may carry that are no program text."""
MAX_PUNCH = 16 * 1024 * 1024
"""A capture longer than this is no program (a line stuck sending): it fails."""
_BLANK = frozenset(b" \t\r\n")
_NOISE_BYTES = bytes(sorted(NOISE))


class TextCapture:
    """Feed it the line's bytes; it says when a program has started and when it is whole."""

    def __init__(self, start: bytes = b"%", end: bytes = b"%", eob: Eob = Eob.CRLF) -> None:
        if any(b in NOISE for b in start + end):
            raise InputError("a trigger cannot contain NUL, DEL or DC1..DC4 (they are dropped)")
        self.start = start
        self.end = end
        self.eob = eob
        self.started = False
        self.done = False
        self.failed = ""
        self._pending = b""  # before the start: the tail that may begin the trigger
        self._data = bytearray()  # the capture, noise removed, from the start trigger on
        self._body = -1  # index of the first program character after the start trigger
        self._searched = 0  # where the end-trigger search goes on

    @property
    def size(self) -> int:
        """Bytes captured so far."""
        return len(self._data)

    def feed(self, data: bytes) -> None:
        """Bytes from the line, in order."""
        if self.done:
            return  # the trailer after the end trigger
        data = data.translate(None, _NOISE_BYTES)
        if not self.started:
            data = self._find_start(data)
            if not self.started:
                return
        self._data += data
        self._find_end()
        if not self.done and len(self._data) > MAX_PUNCH:
            self.done = True
            self.failed = f"no end of program after {MAX_PUNCH} bytes"

    def _find_start(self, data: bytes) -> bytes:
        if not self.start:
            rest = data.lstrip(b" \t\r\n")
            self.started = bool(rest)
            return rest
        text = self._pending + data
        at = text.find(self.start)
        if at < 0:
            self._pending = text[-(len(self.start) - 1) :] if len(self.start) > 1 else b""
            return b""
        self.started = True
        self._pending = b""
        return text[at:]

    def _find_end(self) -> None:
        data = self._data
        if self._body < 0:
            # The program begins at the first character that is neither blank nor part of
            # a repeated start trigger (a "%%%%" leader).
            i = len(self.start)
            while i < len(data):
                if data[i] in _BLANK:
                    i += 1
                elif self.start and data.startswith(self.start, i):
                    i += len(self.start)
                else:
                    self._body = i
                    self._searched = i
                    break
            if self._body < 0:
                return
        if not self.end:
            return
        at = data.find(self.end, max(self._body, self._searched - len(self.end) + 1))
        if at < 0:
            self._searched = len(data)
            return
        del data[at + len(self.end) :]
        self.done = True

    def quiet(self, seconds: float) -> None:
        """The line was quiet for ``seconds`` after the capture started: without an end
        trigger that ends the program, with one the reception failed."""
        if not self.started or self.done:
            return
        self.done = True
        if self._body < 0:
            self.failed = f"nothing came after the start trigger within {seconds:g} s"
        elif self.end:
            self.failed = (
                f"no end trigger {self.end.decode('latin-1')!r} within {seconds:g} s of the "
                f"last character (the punch stopped after {len(self._data)} bytes)"
            )

    def program(self) -> bytes:
        """What was captured, with LF line ends, ending with one."""
        text = from_wire(bytes(self._data), self.eob).rstrip(b" \t\n")
        return text + b"\n" if text else b""
