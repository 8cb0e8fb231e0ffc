"""The virtual Fanuc: a tape-reading control on a serial port, built on the tape engine.

It speaks the same vocabulary as the PC side (:mod:`opendnc.tape`): the profile's codec,
:class:`~opendnc.tape.reader.TapeReader` to read, :class:`~opendnc.tape.feed.TapeFeed` to
punch, the profile's naming rules to store. The operator's choice at the control is the
:class:`Mode`:

``read``
    EDIT + READ: send DC1 (again every ``dc1_interval`` until data comes, since a DC1 sent
    before the PC opened its port is lost), read one record, store it under its name
    (``O0001.nc``), send DC3 at the end; then wait for the next. With ``punch_back`` it
    punches every program it read straight back (an operator checking a load).
``punch:NAME``
    PUNCH: DC2, feed, the record, feed, DC4, once; the PC may pause it with DC3/DC1.
``tape``
    TAPE/DNC mode: blocks run at ``block_rate`` from a buffer of ``buffer_blocks``; DC3 when
    it is full, DC1 at ``resume_blocks``. :attr:`executed` holds the blocks run.
``idle``
    nothing; ``run(name)`` executes a stored program's macro statements, and its
    POPEN / DPRNT / PCLOS go out of the port (DC2, lines, DC4).

Alarms (numbers in :mod:`opendnc.sim.fanuc.params`): 001 on a parity or code error, 002 on
an odd block with TV check on, 087 when more than ``overrun_limit`` characters follow a DC3,
086 when the data stops before the end of the record for ``stall_timeout``. An alarm ends
the job; nothing is stored. The port is served by one thread (blocking pyserial).
"""

from __future__ import annotations

import contextlib
import enum
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

from opendnc.atomicfile import atomic_write
from opendnc.errors import DncError, InputError, PeerClosed, TransportTimeout
from opendnc.gcode import program as gprog
from opendnc.haas import dprnt
from opendnc.sim.fanuc.params import (
    ALARM_NOT_READY,
    ALARM_OVERFLOW,
    ALARM_TH,
    ALARM_TV,
    Alarm,
    FanucParams,
)
from opendnc.tape.codes import DC1, DC2, DC3, DC4, Code, Codec, Eob
from opendnc.tape.errors import TapeWireError, TvCheckError
from opendnc.tape.feed import TapeFeed, leader_bytes
from opendnc.tape.naming import received_name
from opendnc.tape.profiles import Profile, get_profile
from opendnc.tape.reader import End, ReaderConfig, TapeReader
from opendnc.transport.base import PortStream
from opendnc.transport.urls import open_stream

POLL = 0.02
CHUNK = 64


class Mode(enum.Enum):
    """What the operator selected."""

    IDLE = "idle"
    READ = "read"
    PUNCH = "punch"
    TAPE = "tape"


@dataclass(frozen=True, slots=True)
class Selection:
    """A mode and, for a punch, the stored program's file name."""

    mode: Mode
    program: str = ""


def parse_mode(spec: str) -> Selection:
    """``read`` | ``tape`` | ``idle`` | ``punch:O0001`` (the name as stored, ``.nc`` optional)."""
    kind, _, arg = spec.strip().partition(":")
    try:
        mode = Mode(kind.lower())
    except ValueError:
        raise InputError(f"bad mode {spec!r}: use read, tape, idle or punch:NAME") from None
    if mode is Mode.PUNCH and not arg:
        raise InputError("punch needs a program: punch:O0001")
    if mode is not Mode.PUNCH and arg:
        raise InputError(f"bad mode {spec!r}: {kind} takes no argument")
    return Selection(mode, arg)


@dataclass(frozen=True, slots=True)
class FanucOptions:
    """The simulator's knobs (the control's own settings are :class:`FanucParams`)."""

    block_rate: float = 200.0  # blocks per second in tape mode
    buffer_blocks: int = 16
    resume_blocks: int = 4
    # Characters accepted after DC3: a real Fanuc takes 10. On the virtual cable the PC's
    # pty holds up to 64 kB and the cable's lane 4 kB that the sender wrote before it could
    # see the DC3 (measured: a 24 kB program was all written in 0.5 s at 9600 baud), so the
    # simulator's default allows that much (docs/tape.md#virtual-fanuc).
    overrun_limit: int = 72 * 1024
    dc1_interval: float = 0.5  # longer than the PC's linger after a send (0.25 s)
    stall_timeout: float = 5.0
    punch_back: bool = False
    punch_delay: float = 0.05
    # READ: characters a second the memory stores (0 = as fast as they come) and the buffer
    # in front of it: DC3 when it holds read_buffer characters, DC1 at a quarter of that
    read_rate: float = 0.0
    read_buffer: int = 256


@dataclass
class _Counters:
    alarms: list[Alarm] = field(default_factory=list)
    messages: list[str] = field(default_factory=list)
    executed: list[str] = field(default_factory=list)
    dprnt: list[str] = field(default_factory=list)


class VirtualFanuc:
    """A virtual control on serial port ``port`` (see the module doc)."""

    def __init__(
        self,
        port: str,
        root: Path,
        *,
        profile: Profile | None = None,
        params: FanucParams | None = None,
        options: FanucOptions | None = None,
        mode: Selection | None = None,
        on_message: Callable[[str], None] | None = None,
    ) -> None:
        base = profile or get_profile("fanuc-0i")
        self.params = params or FanucParams(
            baud=base.baud,
            code=base.code,
            stop_bits=int(base.line_settings[2]),
            tv_check=base.tv_check,
            eob=base.eob,
        )
        p = self.params
        line = base.line if p.code is Code.ISO else "8N" + str(p.stop_bits)
        if p.code is Code.ISO and base.line[:2] in ("7E", "8N"):
            line = base.line[:2] + str(p.stop_bits)
        self.profile = replace(
            base,
            baud=p.baud,
            code=p.code,
            line=line,
            tv_check=p.tv_check,
            eob=p.eob if p.code is Code.ISO else Eob.LF,
            leader=base.leader if p.feed else 0,
            trailer=base.trailer if p.feed else 0,
        )
        self.options = options or FanucOptions()
        self.root = root
        root.mkdir(parents=True, exist_ok=True)
        self.port_name = port
        self.on_message = on_message
        self.state = _Counters()
        self._lock = threading.Lock()
        self._selection = mode or Selection(Mode.READ)
        self._changed = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._stream: PortStream | None = None
        self.busy = False  # a job is under way

    # -- public API -----------------------------------------------------------------------

    @property
    def codec(self) -> Codec:
        """The codec of the control's port."""
        return self.profile.codec()

    @property
    def alarms(self) -> list[Alarm]:
        """Alarms raised so far."""
        with self._lock:
            return list(self.state.alarms)

    @property
    def messages(self) -> list[str]:
        """One line per finished job or alarm."""
        with self._lock:
            return list(self.state.messages)

    @property
    def executed(self) -> list[str]:
        """Blocks run in tape mode."""
        with self._lock:
            return list(self.state.executed)

    @property
    def dprnt_lines(self) -> list[str]:
        """Lines DPRNT printed."""
        with self._lock:
            return list(self.state.dprnt)

    def programs(self) -> list[str]:
        """Names of the stored programs."""
        return sorted(
            p.name for p in self.root.iterdir() if p.is_file() and not p.name.startswith(".")
        )

    def select(self, selection: Selection) -> None:
        """Switch what the port does (the job under way ends first)."""
        with self._lock:
            self._selection = selection
        self._changed.set()

    def start(self) -> VirtualFanuc:
        """Open the port and serve it in a thread."""
        bits, parity, stop = self.profile.port_settings
        self._stream = open_stream(
            self.port_name,
            self.profile.baud,
            parity=parity,
            bytesize=bits,
            stopbits=stop,
            timeout=POLL,
        )
        self._thread = threading.Thread(target=self._serve, name="virtual-fanuc", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop the thread and close the port."""
        self._stop.set()
        self._changed.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        if self._stream is not None:
            self._stream.close()

    def __enter__(self) -> VirtualFanuc:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def run(self, name: str) -> None:
        """Execute stored program ``name``'s macro statements now (POPEN/DPRNT/PCLOS go out)."""
        self._run_macro(name)

    # -- the port thread ----------------------------------------------------------------------

    def _note(self, text: str, alarm: Alarm | None = None) -> None:
        with self._lock:
            if alarm is not None:
                self.state.alarms.append(alarm)
            self.state.messages.append(text)
        if self.on_message is not None:
            self.on_message(text)

    def _serve(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                selection = self._selection
            self._changed.clear()
            try:
                if selection.mode is Mode.READ:
                    self._read_job()
                elif selection.mode is Mode.TAPE:
                    self._tape_job()
                elif selection.mode is Mode.PUNCH:
                    self._punch(selection.program)
                    with self._lock:
                        if self._selection == selection:
                            self._selection = Selection(Mode.IDLE)
                else:
                    self._changed.wait(POLL)
                    self._discard()
            except PeerClosed:
                time.sleep(POLL)
            except DncError as exc:  # a port failure: report it, keep serving
                self._note(f"ERROR {exc}")
                time.sleep(POLL)
            finally:
                self.busy = False

    def _stream_(self) -> PortStream:
        assert self._stream is not None
        return self._stream

    def _read(self) -> bytes:
        try:
            return self._stream_().read(4096)
        except TransportTimeout:
            return b""

    def _discard(self) -> None:
        with contextlib.suppress(TransportTimeout, PeerClosed):
            self._stream_().read_nowait(4096)

    def _send(self, *codes: int) -> None:
        self._stream_().write(self.codec.encode_text("".join(chr(c) for c in codes), 0))

    def _reader(self) -> TapeReader:
        profile = self.profile
        return TapeReader(
            ReaderConfig(
                codec=self.codec,
                tv_check=profile.tv_check,
                end_at_percent=profile.end_at_percent,
                eof_char=None if profile.eof_byte is None else chr(profile.eof_byte),
            )
        )

    def _interrupted(self) -> bool:
        return self._stop.is_set() or self._changed.is_set()

    def _alarm_for(self, exc: TapeWireError) -> Alarm:
        return ALARM_TV if isinstance(exc, TvCheckError) else ALARM_TH

    def _abort(self, alarm: Alarm, detail: str) -> None:
        """Stop reading (DC3), raise the alarm, and let the rest of the stream go by."""
        with contextlib.suppress(DncError):
            self._send(DC3)
        self._note(f"{alarm}: {detail}", alarm)
        deadline = time.monotonic() + 10.0
        quiet_since = time.monotonic()
        while time.monotonic() < deadline and not self._interrupted():
            if self._read():
                quiet_since = time.monotonic()
            elif time.monotonic() - quiet_since > 0.3:
                break

    def _read_job(self) -> None:
        options = self.options
        reader = self._reader()
        pending = bytearray()  # read off the line, not yet stored (read_rate > 0)
        xoff = False
        after_xoff = 0
        stream = self._stream_()
        self._send(DC1)
        asked = heard = stored_at = time.monotonic()
        while not self._interrupted():
            stream.set_timeout(0.002 if pending else POLL)
            data = self._read()
            now = time.monotonic()
            if data:
                heard = now
                self.busy = True
                if xoff:
                    after_xoff += len(data)
                    if after_xoff > options.overrun_limit:
                        self._abort(ALARM_OVERFLOW, f"{after_xoff} characters after DC3")
                        break
                pending += data
            elif not reader.started and not pending and now - asked >= options.dc1_interval:
                self._send(DC1)
                asked = now
            elif reader.started and not xoff and now - heard > options.stall_timeout:
                self._abort(ALARM_NOT_READY, f"no data for {options.stall_timeout:g} s")
                break
            # store what the memory takes: all of it, or read_rate characters a second
            take = len(pending)
            if options.read_rate > 0:
                take = min(take, int((now - stored_at) * options.read_rate))
            if take or not pending:
                stored_at = now
            chunk, pending[:take] = bytes(pending[:take]), b""
            try:
                reader.feed(chunk)
            except TapeWireError as exc:
                self._abort(self._alarm_for(exc), str(exc))
                break
            if reader.ended is not None:  # its %, DC4 or end-of-file byte
                self._send(DC3)
                name = self._store(reader)
                if name is not None and options.punch_back:
                    time.sleep(options.punch_delay)
                    self._punch(name)
                break
            if not xoff and len(pending) >= options.read_buffer:
                self._send(DC3)
                xoff, after_xoff = True, 0
            elif xoff and len(pending) <= options.read_buffer // 4:
                self._send(DC1)
                xoff = False
        stream.set_timeout(POLL)

    def _store(self, reader: TapeReader) -> str | None:
        try:
            name = received_name(self.profile, reader.label, reader.program) or "O0000.nc"
        except DncError as exc:  # a name the control's rules do not allow
            self._note(f"ERROR cannot store the program: {exc}")
            return None
        try:
            with atomic_write(self.root / name) as handle:
                handle.write(reader.text().encode("latin-1"))
        except OSError as exc:
            self._note(f"ERROR cannot store {name}: {exc}")
            return None
        self._note(f"READ {name} {len(reader.program)} blocks")
        return name

    def _punch(self, name: str) -> None:
        path = self.root / name
        if not path.is_file() and not name.endswith(".nc"):
            path = self.root / f"{name}.nc"
        if not path.is_file():
            self._note(f"ERROR no program {name} to punch")
            return
        profile = self.profile
        codec = self.codec
        feed = TapeFeed(path, profile, codec=codec)
        try:
            body = b"".join(feed)
        except DncError as exc:
            self._note(f"ERROR cannot punch {name}: {exc}")
            return
        finally:
            feed.close()
        data = (
            leader_bytes(profile, profile.leader, codec)
            + body
            + leader_bytes(profile, profile.trailer, codec)
        )
        self.busy = True
        if profile.punch_dc2:
            self._send(DC2)
        stream = self._stream_()
        for start in range(0, len(data), CHUNK):
            self._wait_for_dc1_if_paused()
            stream.write(data[start : start + CHUNK])
            stream.drain()
        if profile.punch_dc2:
            self._send(DC4)
        self._note(f"PUNCH {path.name} {len(data)} bytes")

    def _wait_for_dc1_if_paused(self) -> None:
        stream = self._stream_()
        got = stream.read_nowait(64)
        if DC3 not in (b & 0x7F for b in got):
            return
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline and not self._stop.is_set():
            if DC1 in (b & 0x7F for b in self._read()):
                return

    # -- tape mode ----------------------------------------------------------------------------

    def _tape_job(self) -> None:
        options = self.options
        reader = self._reader()
        executed = 0  # blocks of reader.blocks run so far
        period = 1.0 / options.block_rate if options.block_rate > 0 else 0.0
        next_run = time.monotonic()
        xoff = False
        after_xoff = 0
        self._send(DC1)
        asked = heard = time.monotonic()
        stream = self._stream_()
        while not self._interrupted():
            backlog = len(reader.blocks) - executed
            now = time.monotonic()
            wait = POLL if backlog == 0 else max(0.0, min(POLL, next_run - now))
            stream.set_timeout(max(wait, 0.0005))
            data = self._read()
            now = time.monotonic()
            if data:
                heard = now
                self.busy = True
                if xoff:
                    after_xoff += len(data)
                    if after_xoff > options.overrun_limit:
                        self._abort(ALARM_OVERFLOW, f"{after_xoff} characters after DC3")
                        break
                try:
                    reader.feed(data)
                except TapeWireError as exc:
                    self._abort(self._alarm_for(exc), str(exc))
                    break
            elif not reader.started and now - asked >= options.dc1_interval:
                self._send(DC1)
                asked = now
            elif (
                reader.started
                and reader.ended is None
                and not xoff
                and now - heard > options.stall_timeout
            ):
                self._abort(ALARM_NOT_READY, f"no data for {options.stall_timeout:g} s")
                break
            # run blocks that are due
            while len(reader.blocks) > executed and time.monotonic() >= next_run:
                block = reader.blocks[executed]
                executed += 1
                if not block.strip():
                    continue  # an EOB alone: nothing to run (where a line break split, it lands)
                with self._lock:
                    self.state.executed.append(block)
                next_run = max(next_run + period, time.monotonic())  # no catching up
            backlog = len(reader.blocks) - executed
            if not xoff and backlog >= options.buffer_blocks and reader.ended is None:
                self._send(DC3)
                xoff, after_xoff = True, 0
            elif xoff and backlog <= options.resume_blocks:
                self._send(DC1)
                xoff = False
            if reader.ended is not None and backlog == 0:
                if reader.ended is not End.QUIET:
                    self._send(DC3)
                    self._note(f"TAPE DONE {executed} blocks")
                else:
                    self._abort(ALARM_NOT_READY, "the tape ended before its %")
                break
        stream.set_timeout(POLL)

    # -- macro output: POPEN / DPRNT / PCLOS ------------------------------------------------------

    def _run_macro(self, name: str) -> None:
        path = self.root / name
        if not path.is_file():
            path = self.root / f"{name}.nc"
        try:
            lines = path.read_text(encoding="latin-1").splitlines()
        except OSError as exc:
            raise InputError(f"no program {name}: {exc.strerror or exc}") from exc
        blocks = [gprog.parse_block(line) for line in lines if line.strip() not in ("", "%")]
        variables: dict[int, float] = {}

        def lookup(number: int) -> float | None:
            return variables.get(number)

        stream = self._stream_()
        pc = 0
        steps = 0
        while pc < len(blocks) and steps < 100_000:
            steps += 1
            statement = blocks[pc].statement
            pc += 1
            if isinstance(statement, gprog.Assign):
                target = gprog.variable_number(statement.target, lookup)
                value = gprog.evaluate(statement.value, lookup)
                if value is not None:
                    variables[target] = value
            elif isinstance(statement, gprog.PortControl):
                stream.write(self.codec.encode_text(chr(DC2 if statement.open else DC4), 0))
            elif isinstance(statement, gprog.Dprnt):
                text = dprnt.render(statement.items, lookup)
                with self._lock:
                    self.state.dprnt.append(text)
                stream.write(self.codec.encode_block(text))
            elif isinstance(statement, gprog.While):
                if not gprog.evaluate(statement.condition, lookup):
                    pc = _after_end(blocks, pc, statement.loop)
            elif isinstance(statement, gprog.EndLoop):
                pc = _back_to_while(blocks, pc - 1, statement.loop)
        stream.drain()
        self._note(f"RUN {path.name} done")


def _after_end(blocks: list[gprog.Block], pc: int, loop: int) -> int:
    for index in range(pc, len(blocks)):
        statement = blocks[index].statement
        if isinstance(statement, gprog.EndLoop) and statement.loop == loop:
            return index + 1
    return len(blocks)


def _back_to_while(blocks: list[gprog.Block], pc: int, loop: int) -> int:
    for index in range(pc, -1, -1):
        statement = blocks[index].statement
        if isinstance(statement, gprog.While) and statement.loop == loop:
            return index
    return pc + 1
