"""The virtual TNC's side of Heidenhain's blockwise serial protocol (``--serial-mode blockwise``).

The control stores a program pushed to it (H header) in ``TNC:\\<name>`` and answers a request
for a program (K header) from ``TNC:\\<name>`` or ``TNC:\\nc_prog\\<name>`` (NAK when it has
none). The engines are those of :mod:`opendnc.heidenhain.blockwise`; files land complete or
not at all (written beside the target, renamed when the ETX arrived).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from opendnc.atomicfile import atomic_write
from opendnc.heidenhain.blockwise import (
    DEFAULT_SETTINGS,
    SOH,
    BlockReceiver,
    BlockSender,
    BlockwiseSettings,
    FileReceived,
    FileRequested,
    FileSent,
    TransferFailed,
    join_lines,
    split_lines,
)

__all__ = ["BlockwiseService"]


class BlockwiseService:
    """Serves one transfer after another on a line (sans-IO: bytes and time in, bytes out)."""

    def __init__(
        self,
        drive: Path,
        *,
        settings: BlockwiseSettings = DEFAULT_SETTINGS,
        note: Callable[[str], None] | None = None,
    ) -> None:
        self.drive = drive
        """The folder of drive TNC: on the simulator's disk."""
        self.settings = settings
        self.note = note
        self.received: list[str] = []
        self._engine: BlockSender | BlockReceiver | None = None
        self._pending = bytearray()
        self._tx = bytearray()

    @property
    def deadline(self) -> float | None:
        """When :meth:`tick` is due."""
        return None if self._engine is None else self._engine.deadline

    def data_to_send(self) -> bytes:
        """Bytes to write now."""
        if self._engine is not None:
            self._tx += self._engine.data_to_send()
        data = bytes(self._tx)
        self._tx.clear()
        return data

    def receive_data(self, data: bytes, now: float, errors: Sequence[int] = ()) -> None:
        """Feed bytes read from the line (``errors``: characters that failed parity)."""
        if self._engine is None:
            if errors:
                # Before a transfer starts only the header matters, and a header with a NUL
                # in it is refused; the engine gets exact positions once it runs.
                spoilt = bytearray(data)
                for i in errors:
                    spoilt[i] = 0
                data, errors = bytes(spoilt), ()
            self._pending += data
            start = self._pending.find(bytes([SOH]))
            if start < 0 or len(self._pending) < start + 2:
                if start < 0:
                    self._pending.clear()  # idle-line noise
                return
            kind = self._pending[start + 1 : start + 2]
            data = bytes(self._pending[start:])
            self._pending.clear()
            if kind == b"H":
                self._engine = BlockReceiver(settings=self.settings)
            elif kind == b"K":
                self._engine = BlockSender(None, settings=self.settings)
            else:
                return
            self._engine.start(now)
        self._engine.receive_data(data, now, errors)
        self._events(now)

    def tick(self, now: float) -> None:
        """Handle an expired deadline."""
        if self._engine is not None:
            self._engine.tick(now)
            self._events(now)

    def _say(self, text: str) -> None:
        if self.note is not None:
            self.note(text)

    def _events(self, now: float) -> None:
        engine = self._engine
        assert engine is not None
        while (event := engine.next_event()) is not None:
            if isinstance(event, FileRequested):
                assert isinstance(engine, BlockSender)
                engine.serve(self._lookup(event.name), now)
            elif isinstance(event, FileReceived):
                self._store(event)
            elif isinstance(event, FileSent):
                self._say(f"blockwise: sent {event.name} ({event.lines} lines)")
            elif isinstance(event, TransferFailed):
                self._say(f"blockwise: {event.error}")
        if engine.done:
            self._tx += engine.data_to_send()
            self._engine = None

    def _lookup(self, name: str) -> list[bytes] | None:
        base = name.replace("\\", "/").rsplit("/", 1)[-1]
        for folder in (self.drive, self.drive / "nc_prog"):
            path = folder / base
            if base and path.is_file():
                try:
                    return split_lines(path.read_bytes())
                except Exception as exc:  # unreadable or not a text program: refuse (NAK)
                    self._say(f"blockwise: cannot send {name}: {exc}")
                    return None
        self._say(f"blockwise: no file {name}")
        return None

    def _store(self, event: FileReceived) -> None:
        base = event.name.replace("\\", "/").rsplit("/", 1)[-1].rsplit(":", 1)[-1]
        if not base or base in (".", ".."):
            self._say(f"blockwise: refusing file name {event.name!r}")
            return
        try:
            with atomic_write(self.drive / base) as out:
                out.write(join_lines(event.lines))
        except OSError as exc:
            self._say(f"blockwise: cannot store {base}: {exc}")
            return
        self.received.append(base)
        self._say(f"blockwise: received {base} ({len(event.lines)} lines)")
