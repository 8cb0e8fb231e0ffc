"""File-level XModem transfers: read a program and send it, receive into a temp file + rename.

A receive never leaves a partial file at the destination: the bytes go to a hidden temporary
file in the target folder, which is renamed over the target only after the sender's EOT was
acknowledged, and deleted on any error.

Programs are NC text unless ``binary=True``: checksum-mode XModem cannot see two bit errors
that cancel in its sum, so a received block that breaks the NC text rules
(:mod:`opendnc.nctext`) is NAKed and sent again; a file that still holds a byte no NC program
holds (sent twice the same way, or found by the final check) is refused and not written. A
file to send is checked the same way before the first byte goes out.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from opendnc.atomicfile import AtomicWriter
from opendnc.errors import InputError
from opendnc.nctext import check_program, check_program_file
from opendnc.transport.base import ByteStream
from opendnc.transport.urls import open_stream
from opendnc.xmodem.driver import POLL, EventHandler, Progress, receive, send
from opendnc.xmodem.events import EotAnswer
from opendnc.xmodem.framing import Mode
from opendnc.xmodem.haas import (
    Eob,
    ProgramHeader,
    from_wire,
    program_filename,
    program_header,
    to_wire,
)
from opendnc.xmodem.receiver import ReceiverConfig
from opendnc.xmodem.sender import SenderConfig


@dataclass(frozen=True, slots=True)
class SendReport:
    """What :func:`send_file` did."""

    path: Path
    size: int  # bytes sent (after EOB conversion)
    blocks: int
    eot_answer: EotAnswer
    program: ProgramHeader | None
    seconds: float


@dataclass(frozen=True, slots=True)
class ReceiveReport:
    """What :func:`receive_file` did."""

    path: Path
    size: int  # bytes written (after padding removal and EOB conversion)
    blocks: int
    program: ProgramHeader | None
    seconds: float
    # the program's (ODNC CRC32 ...) line: "ok", "missing", or None for --binary
    # (a mismatch is refused, docs/xmodem.md#end-to-end-checks)
    check_line: str | None = None


def open_port(url: str, baud: int = 9600, parity: str = "N") -> ByteStream:
    """Open a device, ``socket://``/``tcp://`` (plain TCP) or any pyserial URL for XModem."""
    return open_stream(url, baud, parity=parity, bytesize=8, stopbits=1, timeout=POLL)


PendingFile = AtomicWriter
"""A file being written: ``handle`` writes to ``temp``; ``target`` may still be renamed."""


@contextlib.contextmanager
def atomic_output(target: Path) -> Iterator[AtomicWriter]:
    """Yield a temp file next to ``target``; on success it replaces ``target``, else vanishes."""
    folder = target.parent
    if not folder.is_dir():
        raise InputError(f"folder {folder} does not exist")
    with AtomicWriter(target) as pending:
        yield pending


def _folder_target(out: str | os.PathLike[str]) -> bool:
    """True if ``out`` names a folder; a name ending in a separator must exist as one."""
    text = os.fspath(out)
    if Path(text).is_dir():
        return True
    if text.endswith(("/", os.sep)):
        raise InputError(f"folder {text} does not exist")
    return False


def check_output(out: str | os.PathLike[str]) -> None:
    """Raise :class:`InputError` at once if ``out`` cannot take a received file, so a bad
    target is reported before any port is opened."""
    if not _folder_target(out) and not Path(out).parent.is_dir():
        raise InputError(f"folder {Path(out).parent} does not exist")


def _stream(port: str | ByteStream, baud: int, parity: str) -> tuple[ByteStream, bool]:
    if isinstance(port, str):
        return open_port(port, baud, parity), True
    return port, False


def send_file(
    port: str | ByteStream,
    path: str | os.PathLike[str],
    *,
    mode: Mode = Mode.ONE_K,
    baud: int = 9600,
    parity: str = "N",
    eob: Eob | None = None,
    config: SenderConfig | None = None,
    progress: Progress | None = None,
    on_event: EventHandler | None = None,
    binary: bool = False,
) -> SendReport:
    """Send the file at ``path``; ``eob`` converts its line ends to the control's setting 25.

    Unless ``binary``, the file must read as NC program text (:mod:`opendnc.nctext`), else
    :class:`~opendnc.errors.ProgramTextError` is raised before anything is sent.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror or exc}") from exc
    if not data:
        raise InputError(f"{path} is empty; XModem cannot send an empty file")
    if not binary:
        check_program(data, what=path.name, action="not sent (--binary sends any bytes)")
    if eob is not None:
        data = to_wire(data, eob)
    stream, owned = _stream(port, baud, parity)
    started = time.monotonic()
    try:
        done = send(stream, data, mode=mode, config=config, progress=progress, on_event=on_event)
    finally:
        if owned:
            stream.close()
    return SendReport(
        path=path,
        size=done.size,
        blocks=done.blocks,
        eot_answer=done.eot_answer,
        program=program_header(data),
        seconds=time.monotonic() - started,
    )


def receive_file(
    port: str | ByteStream,
    out: str | os.PathLike[str],
    *,
    mode: Mode = Mode.CHECKSUM,
    baud: int = 9600,
    parity: str = "N",
    eob: Eob | None = None,
    config: ReceiverConfig | None = None,
    progress: Progress | None = None,
    on_event: EventHandler | None = None,
    binary: bool = False,
) -> ReceiveReport:
    """Receive one file into ``out`` (temp file + rename).

    If ``out`` is an existing folder, the file is named from the program's O-number
    (``O05555.nc``) or ``program.nc``; an ``out`` that ends with a path separator must be an
    existing folder. ``eob`` converts the control's line ends to LF.
    Unless ``binary``, the file must read as NC program text (:mod:`opendnc.nctext`): else
    :class:`~opendnc.errors.ProgramTextError` names the block and offset, and nothing is
    written.
    """
    folder_target = _folder_target(out)
    out = Path(out)
    stream, owned = _stream(port, baud, parity)
    started = time.monotonic()
    checked: str | None = None
    try:
        with atomic_output(out / "program.nc" if folder_target else out) as pending:
            done = receive(
                stream,
                pending.handle,
                mode=mode,
                # a block that is not NC text is NAKed and sent again: checksum mode's blind spot
                config=dataclasses.replace(config or ReceiverConfig(), text_check=not binary),
                progress=progress,
                on_event=on_event,
            )
            pending.handle.flush()
            size = done.size
            if eob is not None and eob is not Eob.LF:
                converted = from_wire(pending.temp.read_bytes(), eob)
                pending.handle.seek(0)
                pending.handle.truncate()
                pending.handle.write(converted)
                pending.handle.flush()
                size = len(converted)
            if not binary:
                check_program_file(
                    pending.temp,
                    what="received program",
                    action="the file was not written (--binary receives any bytes)",
                )
                checked = _check_line(pending.temp)
            with pending.temp.open("rb") as check:
                head = check.read(4096)
            if folder_target:
                pending.target = out / program_filename(head)
    finally:
        if owned:
            stream.close()
    return ReceiveReport(
        path=pending.target,
        size=size,
        blocks=done.blocks,
        program=program_header(head),
        seconds=time.monotonic() - started,
        check_line=checked,
    )


def _check_line(path: Path) -> str:
    """Check the program's check line, if it has one; a mismatch raises (nothing written)."""
    from opendnc.haas.verify import CheckState, ProgramDamaged, check_line

    result = check_line(path.read_bytes())
    if result.state == CheckState.MISMATCH:
        raise ProgramDamaged(result, "received program")
    return result.state
