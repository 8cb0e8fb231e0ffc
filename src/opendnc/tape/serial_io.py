"""Blocking drivers of the tape engine over a port: send, drip-feed, receive a punch.

The decisions are the engine's: a :class:`~opendnc.haas.dnc_engine.DncRun` over a
:class:`~opendnc.tape.feed.TapeFeed` for a send or a drip-feed (DC1 starts, DC3 pauses,
DC1 resumes; small writes so little follows a DC3), a
:class:`~opendnc.tape.session.PunchReceiver` for a punch. This module only carries out
their steps on a :class:`~opendnc.transport.base.PortStream` from the one dispatcher
(:func:`opendnc.transport.open_stream`: devices, ``socket://``, ``tcp://``, ``rfc2217://``);
the run's steps through :func:`opendnc.haas.dnc_drivers.run_on_port`, which the Haas
drip-feed shares, the punch's waits from :func:`opendnc.tape.session.receive_steps`, which
the asyncio driver (:mod:`opendnc.tape.aio`) shares.

A drip-feed runs the program on the machine: :func:`send_program` refuses it with
:class:`~opendnc.errors.SafetyLockError` unless ``safe_mode=False``. A received program is
written with :mod:`opendnc.atomicfile`: whole or not at all, and the files of an archive all
or none (:func:`write_files`).
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Collection
from dataclasses import dataclass
from pathlib import Path
from typing import TypedDict, Unpack

from opendnc.atomicfile import AtomicWriter
from opendnc.errors import (
    InputError,
    PeerClosed,
    SafetyLockError,
    TransferError,
    TransportTimeout,
    os_reason,
)
from opendnc.haas.dnc_drivers import READ_SIZE, run_on_port
from opendnc.haas.dnc_engine import DncConfig, DncEvent, DncRun, Flow
from opendnc.haas.modal import RestartPlan
from opendnc.nctext import check_program, check_program_file
from opendnc.tape.codes import DC1, DC2, DC3, Codec
from opendnc.tape.feed import HEAD_LINES, TapeFeed, leader_bytes
from opendnc.tape.naming import check_send_name, received_name
from opendnc.tape.profiles import Framing, Profile
from opendnc.tape.reader import ReaderConfig, TapeReader
from opendnc.tape.session import PunchReceiver, Received, receive_steps
from opendnc.transport.base import PortStream
from opendnc.transport.urls import open_stream

POLL = 0.05
WRITE_TIMEOUT = 30.0
# after the last byte, keep the port open until the control's flow bytes have stopped this
# long (closing can discard what an adapter or a serial server still holds; see DncConfig)
LINGER = 0.25
Progress = Callable[[int, int], None]
Clock = Callable[[], float]


@dataclass(frozen=True, slots=True)
class TapeReport:
    """What a send or drip-feed did."""

    path: Path
    profile: str
    bytes_sent: int
    lines: int
    xoffs: int
    xons: int
    paused_seconds: float
    seconds: float
    restart: RestartPlan | None
    warnings: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class ReceiveReport:
    """What a receive wrote."""

    path: Path
    name: str | None
    bytes: int
    lines: int
    ended: str
    seconds: float
    # a Sinumerik archive holds several files, each from its own %_N_..._MPF line: all of
    # them, in order (``path`` is the first)
    paths: tuple[Path, ...] = ()


def open_tape_port(url: str, profile: Profile, *, baud: int | None = None) -> PortStream:
    """Open ``url`` with ``profile``'s line (a 7E line as 8N with parity in the codec)."""
    bits, parity, stop = profile.port_settings
    return open_stream(
        url,
        baud or profile.baud,
        parity=parity,
        bytesize=bits,
        stopbits=stop,
        flow="rtscts" if profile.flow == "rtscts" else "none",
        timeout=POLL,
        write_timeout=WRITE_TIMEOUT,
    )


def default_chunk(profile: Profile) -> int:
    """Bytes per write: fewer than the control accepts after its DC3 (Fanuc: 10)."""
    return max(1, min(16, profile.xoff_slack - 2))


def _head(path: Path) -> list[str]:
    try:
        with path.open("rb") as handle:
            return [handle.readline().decode("latin-1") for _ in range(HEAD_LINES)]
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror or exc}") from exc


class Incoming:
    """Splits the control's bytes: DC1/DC3 (either parity) for the run, the rest kept
    (a punch that starts while a send lingers belongs to the next receive)."""

    def __init__(self) -> None:
        self.kept = bytearray()
        self._punching = False

    def split(self, data: bytes) -> bytes:
        if self._punching:
            self.kept += data
            return b""
        flow = bytearray()
        for index, byte in enumerate(data):
            low = byte & 0x7F
            if low in (DC1, DC3):
                flow.append(low)
            elif low == DC2:
                self._punching = True
                self.kept += data[index:]
                break
            else:
                self.kept.append(byte)
        return bytes(flow)


def _config(
    profile: Profile,
    feed: TapeFeed,
    chunk: int | None,
    xoff_timeout: float,
    wait_dc1: bool | None,
    linger: float,
) -> DncConfig:
    return DncConfig(
        linger=linger,
        flow=Flow(profile.flow),
        chunk=chunk or default_chunk(profile),
        xoff_timeout=xoff_timeout,
        wait_for_xon=profile.wait_dc1 if wait_dc1 is None else wait_dc1,
        text_check=False,
        leader=leader_bytes(profile, profile.leader, feed.codec),
        trailer=leader_bytes(profile, profile.trailer, feed.codec),
    )


class SendOptions(TypedDict, total=False):
    """How to send a program: the keywords :func:`send_program` and
    :func:`~opendnc.tape.aio.send_program_async` pass on to :func:`prepare_send` (which holds
    their defaults)."""

    drip_feed: bool
    from_line: int
    retract: bool
    chunk: int | None
    xoff_timeout: float
    wait_dc1: bool | None
    text_check: bool
    codec: Codec | None
    safe_mode: bool
    linger: float


def prepare_send(
    path: Path,
    profile: Profile,
    *,
    drip_feed: bool = False,
    from_line: int = 1,
    retract: bool = True,
    chunk: int | None = None,
    xoff_timeout: float = 60.0,
    wait_dc1: bool | None = None,
    text_check: bool = True,
    codec: Codec | None = None,
    safe_mode: bool = True,
    linger: float = LINGER,
) -> tuple[TapeFeed, DncConfig]:
    """The checks before a send (safety, NC text, name rules) and its feed and run config:
    what the blocking and the asyncio drivers share (the keywords are :class:`SendOptions`)."""
    if drip_feed and safe_mode:
        raise SafetyLockError(f"drip-feeding {path.name} (it runs on the machine)")
    if from_line != 1 and not drip_feed:
        raise InputError("a restart from a line is a drip-feed (use dnc)")
    if text_check:
        check_program_file(path, action="not sent")
    if not drip_feed:
        check_send_name(profile, _head(path), path)
    feed = TapeFeed(path, profile, from_line=from_line, retract=retract, codec=codec)
    try:
        config = _config(profile, feed, chunk, xoff_timeout, wait_dc1, linger)
    except BaseException:
        feed.close()
        raise
    return feed, config


def check_before_send(path: Path, profile: Profile, *, drip_feed: bool = False) -> None:
    """Every check a send makes, before any port opens: NC text, the name rules and a pass
    over the whole file in the profile's code (a character without a code is named)."""
    check_program_file(path, action="not sent")
    if not drip_feed:
        check_send_name(profile, _head(path), path)
    feed = TapeFeed(path, profile)
    try:
        for _block in feed:
            pass
    finally:
        feed.close()


def tape_report(run: DncRun, feed: TapeFeed) -> TapeReport:
    """The report of a finished run."""
    report = run.report()
    return TapeReport(
        path=feed.path,
        profile=feed.profile.name,
        bytes_sent=report.bytes_sent,
        lines=report.lines,
        xoffs=report.xoffs,
        xons=report.xons,
        paused_seconds=report.paused_seconds,
        seconds=report.seconds,
        restart=report.restart,
        warnings=feed.warnings,
    )


def send_program(
    port: str | PortStream,
    path: Path,
    profile: Profile,
    *,
    baud: int | None = None,
    progress: Progress | None = None,
    on_event: Callable[[DncEvent], None] | None = None,
    clock: Clock = time.monotonic,
    keep: bytearray | None = None,
    **options: Unpack[SendOptions],
) -> TapeReport:
    """Send ``path`` to a control reading tape (``drip_feed``: running it in tape/DNC mode).

    Waits for the control's DC1 when the profile says so (``wait_dc1`` overrides), stops on
    DC3 within one write of ``chunk`` bytes, resumes on DC1; :class:`TransportTimeout` when
    a DC3 lasts longer than ``xoff_timeout``. ``keep`` collects what the control sent that
    was not flow control (a punch that follows). ``linger``: seconds of quiet from the
    control after the last byte before the port is let go. The ``options`` are
    :class:`SendOptions`, checked by :func:`prepare_send` before any port opens.
    """
    feed, config = prepare_send(path, profile, **options)
    incoming = Incoming()

    def open_port(url: str) -> PortStream:
        return open_tape_port(url, profile, baud=baud)

    run = run_on_port(
        feed,
        config,
        port,
        open_port,
        split=incoming.split,
        progress=progress,
        on_event=on_event,
        clock=clock,
    )
    if keep is not None:
        keep += incoming.kept
    return tape_report(run, feed)


def receive_record(
    stream: PortStream,
    profile: Profile,
    *,
    timeout: float | None = 60.0,
    quiet: float | None = None,
    quiet_ends: bool = False,
    codec: Codec | None = None,
    already: bytes = b"",
    clock: Clock = time.monotonic,
    leftover: bytearray | None = None,
) -> Received:
    """Read one punched record from ``stream`` (see :class:`PunchReceiver`); ``leftover``
    gets the bytes read after the record's end (the start of a punch that followed at once),
    for the next receive's ``already``."""
    receiver = PunchReceiver(
        profile, codec=codec, start_timeout=timeout, quiet=quiet, quiet_ends=quiet_ends
    )
    receiver.receive_data(already)
    steps = receive_steps(receiver, clock)
    current: float | None = None
    try:
        wait = next(steps)
        while True:
            # a short poll even without a timer: a read never blocks for long
            poll = POLL if wait is None else max(0.001, min(POLL, wait))
            if poll != current:
                current = poll
                stream.set_timeout(poll)
            try:
                data: bytes | None = stream.read(READ_SIZE)
            except TransportTimeout:
                data = None
            except PeerClosed:
                data = b""
            wait = steps.send(data)
    except StopIteration as done:
        record: Received = done.value
    if leftover is not None:
        leftover += receiver.leftover
    return record


def unique_path(folder: Path, name: str, taken: Collection[Path] = ()) -> Path:
    """``folder/name``, or ``name-1``, ``name-2`` ... when taken on disk or in ``taken``
    (names chosen for files not yet written): never overwrite. :class:`InputError` when the
    OS cannot look the path up (a name too long, a folder it may not read)."""
    target = folder / name
    stem, suffix = target.stem, target.suffix
    count = 1
    try:
        while target in taken or target.exists():
            target = folder / f"{stem}-{count}{suffix}"
            count += 1
    except OSError as exc:
        raise InputError(f"cannot use {_short(target)}: {os_reason(exc)}") from exc
    return target


def write_files(files: list[tuple[Path, bytes]]) -> None:
    """Write every file or none: each goes to a temp file beside its target, and the temps
    take their names only once all are written. A failure removes the temps and the files
    already renamed (targets :func:`unique_path` chose, so no earlier file is lost):
    :class:`InputError`."""
    writers: list[AtomicWriter] = []
    renamed: list[Path] = []
    current = files[0][0] if files else Path()
    try:
        for current, data in files:
            writer = AtomicWriter(current)
            writers.append(writer)
            writer.write(data)
        for writer in writers:
            current = writer.target
            writer.commit()
            renamed.append(current)
    except BaseException as exc:
        for writer in writers:
            writer.discard()  # nothing for one already committed
        for path in renamed:
            with contextlib.suppress(OSError):
                path.unlink()
        if isinstance(exc, OSError):
            raise InputError(
                f"cannot write {_short(current)}: {os_reason(exc)}; nothing was written"
            ) from exc
        raise


def _short(path: Path) -> str:
    text = str(path)
    return text if len(text) <= 200 else f"{text[:200]}... ({len(text)} characters)"


def receive_program(
    port: str | PortStream,
    out: Path,
    profile: Profile,
    *,
    baud: int | None = None,
    timeout: float | None = 60.0,
    quiet: float | None = None,
    quiet_ends: bool = False,
    codec: Codec | None = None,
    clock: Clock = time.monotonic,
) -> ReceiveReport:
    """Receive one punched program into ``out`` (a folder: named by the program, never
    overwriting; or a file name). Nothing is written unless the record is whole."""
    started = clock()
    try:
        folder = out if out.is_dir() else None
        if folder is None and not out.parent.is_dir():
            raise InputError(f"no folder {out.parent} for {out.name}")
    except OSError as exc:
        raise InputError(f"cannot use {_short(out)}: {os_reason(exc)}") from exc
    stream = open_tape_port(port, profile, baud=baud) if isinstance(port, str) else port
    try:
        record = receive_record(
            stream,
            profile,
            timeout=timeout,
            quiet=quiet,
            quiet_ends=quiet_ends,
            codec=codec,
            clock=clock,
        )
    finally:
        if isinstance(port, str):
            stream.close()
    parts = split_archive(record.text) if profile.framing is Framing.SIEMENS else [record.text]
    if len(parts) > 1 and folder is None:
        raise InputError(f"the control sent {len(parts)} files: receive them into a folder")
    # every name and every check before the first byte is written: an archive whose third
    # part is damaged must not leave the first two on disk
    files: list[tuple[Path, bytes]] = []
    for index, text in enumerate(parts):
        name = record.name if index == 0 else received_name(profile, [], text.splitlines())
        taken = [path for path, _ in files]
        target = out if folder is None else unique_path(folder, name or "received.nc", taken)
        data = text.encode("latin-1")
        if profile.framing in (Framing.PERCENT, Framing.OKUMA):
            # the NC-text guard: on a line without parity a bit error can still make a valid
            # character of the code (G -> g); Siemens and Fagor text may hold lower case
            check_program(data, what=target.name, action="not written")
        files.append((target, data))
    write_files(files)
    written = [path for path, _ in files]
    return ReceiveReport(
        path=written[0],
        name=record.name,
        bytes=sum(len(data) for _, data in files),
        lines=record.text.count("\n"),
        ended=record.ended.value,
        seconds=clock() - started,
        paths=tuple(written),
    )


def split_archive(text: str) -> list[str]:
    """A Sinumerik punch-tape archive cut into its files, each starting at a ``%`` in
    column 1 (docs/tape.md#framing); text before the first ``%`` stays with the first."""
    parts: list[str] = []
    for line in text.splitlines(keepends=True):
        if line.startswith("%") and parts and parts[-1].strip():
            parts.append(line)
        elif parts:
            parts[-1] += line
        else:
            parts.append(line)
    return parts or [text]


def expected_text(path: Path, profile: Profile, codec: Codec | None = None) -> str:
    """What a control stores of ``path`` sent with ``profile`` (read back from our bytes)."""
    from opendnc.tape.feed import program_wire

    used = codec or profile.codec()
    reader = TapeReader(
        ReaderConfig(
            codec=used,
            end_at_percent=profile.end_at_percent,
            eof_char=None if profile.eof_byte is None else chr(profile.eof_byte),
        )
    )
    reader.feed(program_wire(path, profile, codec=used))
    reader.quiet()
    return reader.text()


def first_difference(expected: str, got: str) -> str | None:
    """``None`` when equal (line ends aside), else which line differs and how."""
    want, have = expected.splitlines(), got.splitlines()
    for number, (a, b) in enumerate(zip(want, have, strict=False), start=1):
        if a.rstrip() != b.rstrip():
            return f"line {number}: sent {a!r}, punched {b!r}"
    if len(want) != len(have):
        return f"sent {len(want)} lines, punched {len(have)}"
    return None


def verify_punch(
    stream: PortStream,
    path: Path,
    profile: Profile,
    *,
    already: bytes = b"",
    timeout: float = 60.0,
    codec: Codec | None = None,
) -> Received:
    """Wait for the control to punch ``path`` back and compare; :class:`TransferError`
    names the first line that differs."""
    record = receive_record(stream, profile, timeout=timeout, codec=codec, already=already)
    problem = first_difference(expected_text(path, profile, codec), record.text)
    if problem is not None:
        raise TransferError(f"verify of {path.name} failed: {problem}")
    return record
